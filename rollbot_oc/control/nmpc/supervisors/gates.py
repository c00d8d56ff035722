"""The supervisor of a course of gates: plans through the gates left, then the motor stopped (``GatesMode``).

The robot follows the minimum-time plan through the gates not yet passed (``nmpc.gates``), from the solve
instant its compute time has passed, with the position weighed more at the two horizon nodes around each
planned passage (``TRACK``).  After the last gate, or ``arrival.hold_time`` past the plan's end with a gate
missed, the motor's speed is ramped to zero (``STOP_MOTOR``); once the robot is at rest (or after
``recovery.brake_wait``) it is done, or, with gates left, gets a new plan through them from there (at most
``GATE_REPLANS``).
"""

from __future__ import annotations

import math

import numpy as np

from rollbot_oc.planning.gates import plan_gates
from rollbot_oc.control.nmpc.modes import GatesMode
from rollbot_oc.control.nmpc.reference import Reference
from rollbot_oc.control.nmpc.step import Window
from rollbot_oc.control.nmpc.supervisors.base import Supervisor
from rollbot_oc.planning.min_time import SolveFailed
from rollbot_oc.model.dynamics import NZ, REDUCED, to_reduced
from rollbot_oc.missions import PassMonitor
from rollbot_oc.core.reproducible import norm

__all__ = ["GatesSupervisor", "GATE_REPLANS"]

GATE_REPLANS = 3  # plans through the gates left after the first, when the robot missed one

M = GatesMode


class GatesSupervisor(Supervisor):
    """Gates (module doc)."""

    initial = M.TRACK

    def __init__(self, context):
        super().__init__(context)
        self._track_diag = context.settings.weights.legs.diagonal(context.settings.horizon.N)
        self._brake_diag = context.settings.weights.brake.diagonal(context.settings.horizon.N)
        self.reset()

    def reset(self) -> None:
        super().reset()
        self.passed = 0  # gates passed
        self._gate = None  # watches the next gate
        self._plans = []  # every plan through the gates, for the report

    @property
    def done(self) -> bool:
        return self.mode is M.DONE

    @property
    def goal(self) -> int:
        return self.passed

    def prepare(self, x0, radius_map) -> Reference:
        self._follow(to_reduced(x0), 0)
        return self.reference

    def watch(self, obs, k: int) -> bool:
        """Feed the next gate's ``PassMonitor`` with the measured position; count it once passed."""
        gates = self.c.mission.gates
        if self.passed < len(gates):
            if self._gate is None:
                self._gate = PassMonitor(gates[self.passed], self.c.mission.pass_tolerance)
            if self._gate.update(obs.position):
                self.passed += 1
                self._gate = None
        return False

    def advance(self, k: int, obs, reached: bool, z) -> None:
        s, log = self.c.settings, self.c.telemetry
        t_now = k * self.c.dt
        left = self.passed < len(self.c.mission.gates)
        if self.mode is M.DONE:
            return
        if self.mode is M.TRACK:
            if not left:
                self._stop_motor(k, z, "every gate passed")
            elif t_now - self.segment_start >= self.reference.segments[0][0].T + s.arrival.hold_time - 1e-9:
                self._stop_motor(k, z, "the plan has ended hold_time ago with a gate missed")
            return
        at_rest = (self.c.params.R * float(norm(z[REDUCED.omega])) < s.recovery.recover_speed
                   and abs(float(z[REDUCED.theta_dot])) < s.recovery.recover_drive)
        settled = at_rest or t_now - self.modes.since * self.c.dt >= s.recovery.brake_wait - 1e-9
        if not left or log.replans >= GATE_REPLANS:
            if settled:
                self.modes.go(M.DONE, k, "at rest, or brake_wait has passed, with every gate passed or no replan left")
        elif settled:
            log.replans += 1
            try:
                start = self._follow(z, k)
            except SolveFailed as exc:  # reported; the robot stays at rest, and tries again
                log.plan_failed(exc.status)
                self.modes.go(M.STOP_MOTOR, k, "the plan through the gates left failed: at rest, tried again")
                return
            self.c.step.hold_until(k, start)  # the motor held still until the plan starts
            self.modes.go(M.TRACK, k, "at rest, or brake_wait has passed: a new plan through the gates left")

    def window(self, z, k: int) -> Window:
        """The plan, the position weighed ``weights.gate`` more at the two horizon nodes around each planned
        gate passage; while the motor is stopped, rest where the robot is (``weights.brake``)."""
        s = self.c.settings
        t_now = k * self.c.dt
        if self.mode is M.STOP_MOTOR:  # (solved only once the motor's ramp is over) rest where the robot is
            rest = self._rest(z)
            return Window(np.tile(rest[:, None], (1, s.horizon.N + 1)), np.zeros(s.horizon.N), self._brake_diag)
        window = self._sample(z, t_now)
        local = t_now - self.segment_start
        diag = self._track_diag.copy()
        for t_gate in self.reference.segments[0][0].extra["gate_times"]:
            j = int(math.floor((t_gate - local) / s.horizon.h))
            for node in (j, j + 1):
                if 0 <= node <= s.horizon.N:
                    diag[node * NZ:node * NZ + 2] += s.weights.gate
        window.diag = diag
        return window

    def plans(self) -> list:
        return list(self._plans)

    def _follow(self, z, k: int) -> float:
        """Plan from ``z`` through the gates not yet passed (on the estimated floor) and follow the plan from
        the solve instant its compute time has passed; returns that instant, s.  Raises ``SolveFailed``."""
        s = self.c.settings
        gates = self.c.mission.gates[self.passed:]
        plan = plan_gates(z, gates, self.c.params.replace(slope=0.0), s.planner.gates,
                          tilt=self.c.step.estimator.tilt.copy(), constraints=tuple(s.limits.constraints))
        self._plans.append(plan.to_dict())
        start = self.c.planner.schedule(k * self.c.dt, plan.solve_time, plan.iterations * s.timing.plan_iteration)
        self.reference = Reference([(plan, {"gates": gates})])
        self.segment, self.segment_start = 0, start
        self.c.step.restart()
        return start

    def _stop_motor(self, k: int, z, reason: str) -> None:
        """Ramp the motor's speed to zero (``brake_accel``) and hold it there: a robot passing gates comes to
        rest this way (the braking weights, from the speed a minimum-time plan ends at, chatter between the
        motor's limits)."""
        s = self.c.settings
        t_now = k * self.c.dt
        self.c.step.stop_motor(k, float(z[REDUCED.theta_dot]), t_now + s.recovery.brake_wait + s.horizon.h)
        self.modes.go(M.STOP_MOTOR, k, reason)

