"""The NMPC's control step: the work of one control period, given what the supervisor wants followed.

Each period: the tilt and model filter's update (``TiltEstimator``), delay compensation (a measurement
``L`` periods old predicted forward over the commands issued since), and the command.  At a solve instant
(every ``h``, or when there is no solution to follow) one solve of the tracking problem on the window the
supervisor gives (``Window``: reference states and accelerations, node weights, the mission's weights), warm
started from the previous solution shifted by one interval; a failed warm-started solve is solved once more
from the reference.  The step's mode (``StepMode``) says what commands the motor:

* ``SOLVE``: the solution's acceleration for the current interval;
* ``SHIFTED``: a solve failed or was late (judged by the compute-time model): the previous solution, for up
  to ``max_failures - 1`` solves;
* ``RAMP``: the motor's speed ramped to zero at ``brake_accel`` and held there until the fallback's time is
  over: the fallback of a course of stops (``recovery.fallback = "brake"``), or a supervisor stopping the
  motor (gates);
* ``PID``: the paper's PID on the current goal for ``pid_time``: the fallback of circles, gates and stops with
  ``recovery.fallback = "pid"``;
* ``OFF``: the mission is done.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rollbot_oc.control.nmpc.estimation import TiltEstimator
from rollbot_oc.control.nmpc.modes import ModeMachine, StepMode
from rollbot_oc.control.nmpc.settings import NMPCSettings
from rollbot_oc.control.nmpc.telemetry import Telemetry
from rollbot_oc.control.nmpc.tracking import RTISolver, TrackingSolver
from rollbot_oc.control.pid import QuasiStablePID
from rollbot_oc.model.dynamics import REDUCED, to_reduced
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.core.reproducible import dot
from rollbot_oc.control.protocol import Command, Observation

__all__ = ["Window", "TrackingStep", "HISTORY"]

HISTORY = 50  # commands remembered for the filter and the delay compensation, control periods


@dataclass
class Window:
    """What one solve follows: the supervisor's reference over the horizon and its weights.

    Attributes
    ----------
    Zr : numpy.ndarray (10, N+1)
        Reference reduced states at the nodes.
    Ur : numpy.ndarray (N,)
        Reference motor accelerations, rad/s^2.
    diag : numpy.ndarray or None
        Weights of every decision variable (``TrackingWeights.diagonal``); None: the mission's default.
    mission_weights : numpy.ndarray or None
        Weights of the mission's residuals at the nodes (a circle's distance from it); None: none.
    """

    Zr: np.ndarray
    Ur: np.ndarray
    diag: np.ndarray | None = None
    mission_weights: np.ndarray | None = None


class TrackingStep:
    """The control step of the NMPC (module doc).

    Parameters
    ----------
    params : RollbotParams
        The robot the controller believes in.
    settings : NMPCSettings
    weights : TrackingWeights
        The mission's default tracking weights.
    mission : Mission
        For the tracking problem's mission terms.
    dt : float
        Control period, s.
    telemetry : Telemetry
    """

    def __init__(self, params: RollbotParams, settings: NMPCSettings, weights, mission, dt: float,
                 telemetry: Telemetry):
        s = self.settings = settings
        self.params, self.dt, self.mission = params, dt, mission
        self.every = max(1, int(round(s.horizon.h / dt)))
        if abs(self.every * dt - s.horizon.h) > 1e-9:
            raise ValueError(f"NMPC h = {s.horizon.h} s must be a whole number of control periods dt = {dt} s")
        solver = TrackingSolver if s.horizon.solver == "ipopt" else RTISolver
        self.solver = solver(params, s, weights, mission=mission)
        f = s.filter
        self.estimator = TiltEstimator(params, dt, f.process_noise, f.gyro_sigma, f.model_error,
                                       f.learn if f.enabled else (), f.learn_sigma, f.attitude_gain)
        self.telemetry = telemetry
        self.radius_map = None  # the PID fallback's (set by the NMPC with its plans)
        self._pid = None
        self.reset(telemetry)

    def reset(self, telemetry: Telemetry) -> None:
        """Forget the run."""
        self.telemetry = telemetry
        self.modes = ModeMachine(StepMode.SOLVE)
        self.warm = None  # (x, lam_w, lam_g): the next solve's warm start
        self.current = None  # (U, tick of the solve): the solution followed
        self.prediction = None  # (Z (10, N+1), solve instant, s): the states the last solve predicts
        self.commands: dict[int, float] = {}
        self.previous = None
        self.failures = 0
        self.until = -1.0  # RAMP and PID: when the fallback's time is over, s
        self._ramp = None  # RAMP's data: (start, s; driving speed, rad/s) of the speed ramp
        self._pid_fresh = True
        self._pid_goal = None
        self.estimator.reset()

    # -- what the supervisor asks ------------------------------------------------------------------
    def restart(self) -> None:
        """A new reference: its first solve starts from it (the warm start solved the one replaced), and
        nothing of the previous solution is followed."""
        self.warm, self.current = None, None

    def cold(self) -> None:
        """The next solve starts from its reference (a new plan takes over; what is followed stays)."""
        self.warm = None

    def stop_motor(self, k: int, speed: float, until: float) -> None:
        """Ramp the motor's speed from ``speed`` (rad/s) to zero and hold it there until ``until`` (s)."""
        self._ramp, self.until = (k * self.dt, speed), until
        self.restart()
        self.modes.go(StepMode.RAMP, k, "the supervisor stops the motor")

    def hold_until(self, k: int, until: float) -> None:
        """Keep the motor held by the last fallback (its speed ramp, or the PID) until ``until``, s."""
        self.until = until
        if self.modes.mode not in (StepMode.RAMP, StepMode.PID):
            target = StepMode.RAMP if self._ramp is not None else StepMode.PID
            self.modes.go(target, k, "the supervisor holds the motor until its plan starts")

    def finish(self, k: int) -> None:
        """The mission is done: the motor's acceleration is zero from now on."""
        if self.modes.mode is not StepMode.OFF:
            self.modes.go(StepMode.OFF, k, "the mission is done")

    # -- every period ------------------------------------------------------------------------------
    def measure(self, obs: Observation, k: int):
        """The filter's update and the delay compensation: the reduced state (10,) at tick ``k``."""
        z_meas = to_reduced(obs.state)
        seen = int(round(obs.t / self.dt))
        if self.settings.filter.enabled and self.previous is not None and seen == self.previous[0] + 1:
            self.estimator.update(self.previous[1], self.commands.get(self.previous[0], 0.0), z_meas)
        else:
            self.estimator.lose_track()
        self.previous = (seen, z_meas)
        if seen >= k:
            return z_meas
        p = self.estimator.params()
        predicted = z_meas
        for j in range(seen, k):
            predicted = self.estimator.step(predicted, self.commands.get(j, 0.0), p)[0].copy()
        return predicted if np.all(np.isfinite(predicted)) else z_meas  # never act on a broken prediction

    def in_fallback(self, t_now: float) -> bool:
        """Whether a fallback (RAMP or PID) commands the motor now."""
        return t_now < self.until

    def needs_solve(self, k: int) -> bool:
        """A solve instant, or nothing to follow."""
        return k % self.every == 0 or self.current is None

    def solve(self, window: Window, z, k: int, fallback: str, on_give_up) -> None:
        """One solve on ``window`` from the state ``z`` at tick ``k``; on failure the previous solution, and
        after ``max_failures`` (or with nothing to follow) the ``fallback`` (``"brake"``: RAMP, else PID),
        ``on_give_up(z, k)`` called first."""
        s, log = self.settings, self.telemetry
        t_now = k * self.dt
        Zr = window.Zr
        # q and -q are the same attitude: give the (continuous) reference the measurement's sign
        if dot(Zr[REDUCED.quaternion, 0], z[REDUCED.quaternion]) < 0:
            Zr[REDUCED.quaternion] *= -1.0
        p = self.estimator.params()
        x, lam, status, ok, seconds = self.solver.solve(z, Zr, window.Ur, p, self.warm, window.mission_weights,
                                                        window.diag)
        compute = seconds if s.timing.realtime else self.solver.modelled_time()
        if not ok and self.warm is not None:
            # a warm start gone bad (an iterate that diverged linearises to a QP no solver can solve): once
            # more from the reference, in the same interval, its compute time added
            log.cold_retries += 1
            first = status
            x, lam, status, ok, again = self.solver.solve(z, Zr, window.Ur, p, None, window.mission_weights,
                                                          window.diag)
            seconds += again
            compute += again if s.timing.realtime else self.solver.modelled_time()
            status = f"cold after {first}: {status}"
            if not ok:
                self.warm = None  # no use starting from it again
        late = compute > (s.horizon.h if s.timing.max_solve_time is None else s.timing.max_solve_time)
        log.solve_times.append(seconds)
        log.statuses.append(status)
        log.tilt.append(self.estimator.tilt.tolist())
        if ok and not late:
            Z, U = self.solver.split(x)
            self.current = (U, k)
            self.prediction = (Z, t_now)
            self.warm = (self.solver.shift(x), *lam)  # duals unshifted: the structure repeats every interval
            self.failures = 0
            if self.modes.mode is StepMode.SHIFTED:
                self.modes.go(StepMode.SOLVE, k, "a solve succeeded in time")
            elif self.modes.mode in (StepMode.RAMP, StepMode.PID):
                self.modes.go(StepMode.SOLVE, k, "the fallback's time is over")
            return
        if ok:
            log.late += 1
        else:
            log.failed += 1
        self.failures += 1
        if self.current is not None and self.failures < s.recovery.max_failures:
            log.fallback_shifted += 1  # keep following the previous solution (its index moves on)
            self.modes.go(StepMode.SHIFTED, k, "a solve failed or was late")
            return
        self.warm, self.current, self.failures = None, None, 0
        self.prediction = None  # no solution acts now: a refinement starts from the guess's own state
        if fallback == "brake":
            log.fallback_brake += 1
            on_give_up(z, k)
            speed = float(z[REDUCED.theta_dot])
            self._ramp = (t_now, speed)
            self.until = t_now + abs(speed) / s.recovery.brake_accel + s.horizon.h
            self.modes.go(StepMode.RAMP, k,
                          "failed or late with nothing to follow (none, or max_failures in a row): brake")
            return
        log.fallback_pid += 1
        self._ramp = None
        self.until = t_now + s.recovery.pid_time
        self._pid_fresh = True
        self.modes.go(StepMode.PID, k, "failed or late with nothing to follow (none, or max_failures in a row): PID")

    def command(self, k: int) -> Command:
        """The followed solution's acceleration for the current interval (``SOLVE`` and ``SHIFTED``)."""
        U, k_solved = self.current
        return self.issue(k, float(U[min((k - k_solved) // self.every, len(U) - 1)]))

    def issue(self, k: int, accel: float) -> Command:
        """Command ``accel`` (rad/s^2) at tick ``k`` and remember it."""
        self._remember(k, accel)
        return Command(accel=accel)

    def fallback_command(self, k: int, obs: Observation, z, goal: int) -> Command:
        """RAMP: the motor's speed on its ramp to zero; PID: the paper's PID towards the mission's target
        ``goal`` (``Mission.leg``); both as a speed command, remembered as the acceleration the predicted
        driving speed needs."""
        if self.modes.mode is StepMode.PID:
            speed = self._pid_speed(obs, z, goal)
        else:
            t0, speed0 = self._ramp
            speed = math.copysign(max(0.0, abs(speed0) - self.settings.recovery.brake_accel * (k * self.dt - t0)),
                                  speed0)
        limit = self.params.max_accel  # the plant's motor cannot follow faster either
        self._remember(k, float(np.clip((speed - float(z[REDUCED.theta_dot])) / self.dt, -limit, limit)))
        return Command(speed=speed)

    def _remember(self, k: int, accel: float) -> None:
        """The acceleration commanded at tick ``k``, rad/s^2, for the filter and the delay compensation (the last
        ``HISTORY`` periods kept)."""
        self.commands[k] = accel
        self.commands.pop(k - HISTORY, None)

    def _pid_speed(self, obs: Observation, z, goal: int) -> float:
        """The paper's PID on the mission's target ``goal``, taking over smoothly from the current driving speed."""
        if self._pid is None or self._pid_goal != goal:
            self._pid, self._pid_goal, self._pid_fresh = QuasiStablePID(
                self.mission.leg(goal), self.params, dt=self.dt, radius_map=self.radius_map), goal, True
        if self._pid_fresh:
            self._pid.reset()
            self._pid.omega_cmd = max(float(z[REDUCED.theta_dot]), 0.0)
            self._pid_fresh = False
        return self._pid(obs).speed
