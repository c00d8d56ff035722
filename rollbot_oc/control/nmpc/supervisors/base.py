"""What every supervisor of the NMPC shares: its context, its mode machine and the questions the loop asks."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np

from rollbot_oc.model.dynamics import REDUCED, rest_attitude
from rollbot_oc.core.reproducible import dot, norm

from rollbot_oc.control.nmpc.modes import ModeMachine
from rollbot_oc.control.nmpc.planner import Planner
from rollbot_oc.control.nmpc.reference import Reference
from rollbot_oc.control.nmpc.settings import NMPCSettings
from rollbot_oc.control.nmpc.step import TrackingStep, Window
from rollbot_oc.control.nmpc.telemetry import Telemetry
from rollbot_oc.missions.base import Mission
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.control.protocol import Observation

__all__ = ["Context", "Supervisor"]


@dataclass
class Context:
    """What a supervisor works with: the mission, the robot believed in, the settings, the control period
    (s), and the NMPC's step, planner and telemetry."""

    mission: Mission
    params: RollbotParams
    settings: NMPCSettings
    dt: float
    step: TrackingStep
    planner: Planner
    telemetry: Telemetry


class Supervisor:
    """Decides, for one mission kind, what the tracking step follows (a mode machine; ``modes``).

    A subclass sets ``initial`` (its first mode) and writes ``prepare``, ``advance`` and ``window``.  The
    loop calls, every period, ``watch``; at each solve instant, ``advance``; and for each solve, ``window``.
    """

    initial: Enum = None
    fallback = "pid"  # what the step falls back to when it gives up: "brake" (RAMP) or "pid"
    stops: tuple = ()  # what the stop monitors recorded at each stop reached (courses of stops)

    @staticmethod
    def tracking_weights(settings: NMPCSettings):
        """The tracking cost's default weights for this mission kind (``weights.legs``)."""
        return settings.weights.legs

    def __init__(self, context: Context):
        self.c = context
        self.reference: Reference | None = None
        self.segment, self.segment_start = 0, 0.0
        self.modes = ModeMachine(self.initial)

    @property
    def mode(self) -> Enum:
        """The current mode."""
        return self.modes.mode

    def reset(self) -> None:
        """Forget the run (a prepared reference too)."""
        self.reference = None
        self.segment, self.segment_start = 0, 0.0
        self.modes = ModeMachine(self.initial)

    @property
    def done(self) -> bool:
        """Whether the mission is done (the run may end)."""
        return False

    @property
    def goal(self) -> int:
        """The mission's target in progress (for the PID fallback: ``Mission.leg``)."""
        return 0

    def prepare(self, x0, radius_map) -> Reference:
        """The reference to follow first, from the full state ``x0`` (11,)."""
        raise NotImplementedError

    def watch(self, obs: Observation, k: int) -> bool:
        """Feed the monitors with the measurement of tick ``k``; True once the stop in progress is reached."""
        return False

    def advance(self, k: int, obs: Observation, reached: bool, z) -> None:
        """At a solve instant ``k``: change mode along the table as the conditions say."""

    def window(self, z, k: int) -> Window:
        """What the solve at tick ``k`` follows, from the (delay-compensated) reduced state ``z``."""
        raise NotImplementedError

    def on_give_up(self, z, k: int) -> None:
        """The step gave up (``max_failures`` failed solves) and falls back to ``fallback``."""

    def plans(self) -> list:
        """The plans of the run, for the report."""
        return []

    def report(self) -> dict:
        """The supervisor's part of the run's metrics: its plans and their total duration (s)."""
        legs = [seg for seg in self.reference.segments if seg is not None] if self.reference else []
        return {"plans": self.plans(), "plan_duration": float(sum(seg[0].T for seg in legs)) if legs else None}

    def _sample(self, z, t_now: float) -> Window:
        """The current segment's reference from ``t_now`` over the horizon (re-phased on an orbit)."""
        s = self.c.settings.horizon
        Zr, Ur = self.reference.sample(self.segment, t_now - self.segment_start, s.h, s.N, position=z[REDUCED.position])
        return Window(np.asarray(Zr), np.asarray(Ur))

    def _predicted(self, t: float):
        """The reduced state (10,) the tracking step's last successful solve predicts for the time ``t`` (s),
        or None if that is beyond its horizon (or there is none)."""
        if self.c.step.prediction is None:
            return None
        Z, solved = self.c.step.prediction
        node = int(round((t - solved) / self.c.settings.horizon.h))
        return Z[:, node].copy() if 0 <= node < Z.shape[1] else None

    def _rest(self, z) -> np.ndarray:
        """The rest state for the reduced state ``z``: where it is, still; with its attitude if that is within
        ``swung_angle`` of the balanced rest with its motor axis' heading, else (the mass swung up: no state to
        rest in) that rest, on the estimated floor (``dynamics.rest_attitude``)."""
        rest = np.array(z, float)
        rest[REDUCED.velocity] = 0.0
        q = rest[REDUCED.quaternion]
        try:
            balanced = rest_attitude(q, self.c.step.estimator.params())
        except ValueError:  # no balance on the floor estimated so far: the level floor's
            balanced = rest_attitude(q, self.c.params.replace(slope=0.0))
        if _turned(balanced, q) > self.c.settings.recovery.swung_angle:
            rest[REDUCED.quaternion] = balanced
        return rest


def _turned(a, b) -> float:
    """The angle between the attitudes of the quaternions ``a`` and ``b`` (either sign), rad."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return 2.0 * math.acos(min(abs(dot(a, b)) / (norm(a) * norm(b)), 1.0))
