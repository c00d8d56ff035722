"""The embedded controller's reference: the mission's minimum-time legs, planned offline, as one table.

The NMPC plans its legs online with IPOPT, which does not run on a microcontroller.  The exported
controller follows the same kind of legs planned once, before the run, from the mission's start: each
leg from rest at the previous stop (the first from the start state) to rest at its stop, the fastest of
``planner.starts`` minimum-time plans on the level floor (the NMPC's own leg planner and settings).  Each
leg is sampled on the grid of the NMPC's interval ``h``: column ``l`` of a leg is its reference at local
time ``l h`` (``control.nmpc.Reference.sample``: the plan's state and acceleration, the rest state at the
stop from the plan's end on, which its last column holds).  The controller follows a leg from the solve
instant it starts on and leaves its stop, at a solve instant, once the stop is reached (``export.step``).

What this does not do (the NMPC does): no leg is planned again, neither from where the robot is after a
push or a failed plan nor on the floor tilt estimated by then (the tilt is estimated for the tracking, not
for the plans), and there are no stepping stones or cautious plans after recoveries.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rollbot_oc.control.nmpc.supervisors.stops import _rest_to_rest
from rollbot_oc.control.nmpc.reference import Reference
from rollbot_oc.control.nmpc.settings import NMPCSettings
from rollbot_oc.planning.min_time import SolveFailed
from rollbot_oc.model.dynamics import NZ, REDUCED, to_reduced
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.export.step import EMBEDDED_SETTINGS
from rollbot_oc.model.params import RollbotParams

__all__ = ["EmbeddedReference", "plan_reference"]



@dataclass
class EmbeddedReference:
    """The legs of a mission as one table (module doc).

    Attributes
    ----------
    Z : numpy.ndarray (10, M)
        Reference reduced states, leg after leg, at local times ``l h``.
    U : numpy.ndarray (M,)
        Reference motor accelerations on the intervals from those times, rad/s^2.
    starts : numpy.ndarray (legs,) of int
        First column of each leg; a leg's columns run to the next one's first.
    stops : numpy.ndarray (legs, 2)
        Each leg's stop, m.
    durations : numpy.ndarray (legs,)
        Each leg's planned duration, s.
    h : float
        Time between columns (the NMPC's interval), s.
    legs : list of dict
        Per leg: ``stop`` (m), ``duration`` (s) and the planner's ``status``.
    """

    Z: np.ndarray
    U: np.ndarray
    starts: np.ndarray
    stops: np.ndarray
    durations: np.ndarray
    h: float
    legs: list

    @property
    def columns(self) -> int:
        return self.U.size

    def _leg_window(self, leg: int, local: int, N: int) -> np.ndarray:
        """Leg ``leg`` from its column ``local`` on (its last column repeated): states (10, N+1) by
        column, accelerations (N,), the stop (2), the leg's duration (s) and 1 if it is the last leg."""
        legs = self.starts.size
        leg = min(leg, legs - 1)
        first = int(self.starts[leg])
        end = int(self.starts[leg + 1]) if leg + 1 < legs else self.columns
        nodes = first + np.minimum(local + np.arange(N + 1), end - first - 1)
        U = np.where(local + np.arange(N) < end - first, self.U[nodes[:N]], 0.0)
        return np.concatenate([self.Z[:, nodes].ravel(order="F"), U, self.stops[leg],
                               [self.durations[leg], float(leg == legs - 1)]])

    def window(self, leg: int, local: int, N: int) -> np.ndarray:
        """The ``ref`` input of the control step: leg ``leg`` from its column ``local``, then the next leg
        from its start (the last leg again after the last)."""
        return np.concatenate([self._leg_window(leg, local, N), self._leg_window(leg + 1, 0, N)])


def plan_reference(stops, x0, params: RollbotParams, settings: NMPCSettings | None = None) -> EmbeddedReference:
    """Plan every leg of a course of ``stops`` from the full state ``x0`` (11,) (module doc).

    Parameters
    ----------
    stops : sequence of (2,)
        The stops, m.
    x0 : array_like (11,)
        The start state.
    params : RollbotParams
        The controller's model (planned on its level floor).
    settings : NMPCSettings, optional
        The NMPC's settings (``planner.legs``, ``planner.starts``, ``limits.constraints``, ``horizon.h``;
        ``EMBEDDED_SETTINGS`` by default).

    Raises
    ------
    ConfigError
        If there are no stops, or a leg cannot be planned.
    """
    s = settings or EMBEDDED_SETTINGS
    if not len(stops):
        raise ConfigError("the exported controller follows a course of stops; this mission has none")
    planner = _rest_to_rest(params.replace(slope=0.0), s.planner.legs, tuple(s.limits.constraints))
    z = to_reduced(x0)
    h = s.horizon.h
    plans, legs = [], []
    for i, stop in enumerate(stops):
        try:
            plan = planner.fastest(z, np.asarray(stop, float), s.planner.starts, tilt=np.zeros(2),
                                   resumes=s.planner.resumes,
                                   quick=s.planner.quick)
        except SolveFailed as exc:
            raise ConfigError(f"leg {i + 1} to stop {list(map(float, stop))} cannot be planned: {exc.status}") \
                from None
        plans.append((plan, {"stop": stop}))
        legs.append({"stop": [float(v) for v in stop], "duration": float(plan.T), "status": plan.status})
        z = plan.z[:, -1].copy()
        z[REDUCED.velocity] = 0.0
    reference = Reference(plans)
    Z, U, counts = [], [], []
    for i, (plan, _info) in enumerate(plans):
        count = int(math.ceil(plan.T / h - 1e-9)) + 1  # the last column at or after the plan's end: at rest
        Zi, Ui = reference.sample(i, 0.0, h, count)
        Z.append(Zi[:, :count])
        U.append(Ui)
        counts.append(count)
    Z = np.hstack(Z)
    if Z.shape[0] != NZ:
        raise RuntimeError("reference table: unexpected state size")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int)
    return EmbeddedReference(Z, np.concatenate(U), starts, np.asarray(stops, float).reshape(-1, 2),
                             np.array([plan.T for plan, _ in plans]), h, legs)
