"""The embedded controller's reference: the mission's minimum-time legs, planned offline, as one table.

The NMPC plans its legs online with IPOPT, which does not run on a microcontroller.  The exported
controller follows the same kind of legs planned once, before the run, from the mission's start: each
leg from rest at the previous stop (the first from the start state) to rest at its stop, the fastest of
``plan_starts`` minimum-time plans on the level floor (the NMPC's own leg planner and settings), then
``dwell`` seconds at rest at the stop.  The legs are laid end to end on the grid of the NMPC's interval
``h``: column ``j`` of the table is the reference at time ``j h`` (``control.nmpc.Reference.sample``:
the plan's state and acceleration, the rest state at the stop once the plan has ended).  A solve instant
tracks the window of ``N + 1`` columns from its own; after the last column the robot holds at the last
stop.

What this does not do (the NMPC does): no leg is planned again from where the robot is (after a push,
or on a slope the plan did not know), a leg starts at its time whether or not the stop before was
reached, and the floor's tilt is estimated for tracking, not for planning.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rollbot_oc.control.nmpc.loop import _rest_to_rest
from rollbot_oc.control.nmpc.reference import Reference
from rollbot_oc.control.nmpc.settings import NMPCSettings
from rollbot_oc.control.ocp import SolveFailed
from rollbot_oc.dynamics import NZ, REDUCED, to_reduced
from rollbot_oc.errors import ConfigError
from rollbot_oc.params import RollbotParams

__all__ = ["EmbeddedReference", "plan_reference", "DWELL"]

HOLD = 0.0
DWELL = 1.5  # s at rest at each stop before the next leg starts (a stop counts as reached after 0.5 s)


@dataclass
class EmbeddedReference:
    """The reference table of a mission (module doc).

    Attributes
    ----------
    Z : numpy.ndarray (10, M)
        Reference reduced states at times ``j h``.
    U : numpy.ndarray (M,)
        Reference motor accelerations on the intervals from those times, rad/s^2.
    hold : numpy.ndarray (M,)
        1 where the robot holds at a stop (its leg has ended), else 0.
    h : float
        Time between columns (the NMPC's interval), s.
    legs : list of dict
        Per leg: ``stop`` (m), ``start`` (s), ``duration`` (s) and the planner's ``status``.
    """

    Z: np.ndarray
    U: np.ndarray
    hold: np.ndarray
    h: float
    legs: list

    @property
    def columns(self) -> int:
        return self.U.size

    @property
    def duration(self) -> float:
        """Time covered by the table, s."""
        return self.columns * self.h

    def window(self, j: int, N: int) -> np.ndarray:
        """The ``ref`` input of the control step at column ``j``: states (10, N+1) by column, accelerations
        (N,) and hold flags (N+1), columns past the end repeating the last (at rest at the last stop)."""
        nodes = np.minimum(np.arange(j, j + N + 1), self.columns - 1)
        U = np.where(np.arange(j, j + N) < self.columns, self.U[nodes[:N]], 0.0)
        return np.concatenate([self.Z[:, nodes].ravel(order="F"), U, self.hold[nodes]])


def plan_reference(stops, x0, params: RollbotParams, settings: NMPCSettings | None = None,
                   dwell: float = DWELL) -> EmbeddedReference:
    """Plan every leg of a course of ``stops`` from the full state ``x0`` (11,) and lay them out (module doc).

    Parameters
    ----------
    stops : sequence of (2,)
        The stops, m.
    x0 : array_like (11,)
        The start state.
    params : RollbotParams
        The controller's model (planned on its level floor).
    settings : NMPCSettings, optional
        The NMPC's settings (``plan``, ``plan_starts``, ``constraints``, ``h``).
    dwell : float
        Time at rest at each stop, s.

    Raises
    ------
    ConfigError
        If there are no stops, or a leg cannot be planned.
    """
    s = settings or NMPCSettings()
    if not len(stops):
        raise ConfigError("the exported controller follows a course of stops; this mission has none")
    if not (math.isfinite(dwell) and dwell >= 0):
        raise ConfigError(f"dwell = {dwell!r} s must be a finite time >= 0")
    planner = _rest_to_rest(params.replace(slope=0.0), s.plan, tuple(s.constraints))
    z = to_reduced(x0)
    h = s.h
    plans, legs, start = [], [], 0
    for i, stop in enumerate(stops):
        try:
            plan = planner.fastest(z, np.asarray(stop, float), s.plan_starts, tilt=np.zeros(2))
        except SolveFailed as exc:
            raise ConfigError(f"leg {i + 1} to stop {list(map(float, stop))} cannot be planned: {exc.status}") \
                from None
        count = int(math.ceil((plan.T + dwell) / h - 1e-9))
        plans.append((plan, {"stop": stop}, count))
        legs.append({"stop": [float(v) for v in stop], "start": start * h, "duration": float(plan.T),
                     "status": plan.status})
        start += count
        z = plan.z[:, -1].copy()
        z[REDUCED.velocity] = 0.0
    reference = Reference([(plan, info) for plan, info, _ in plans])
    Z, U, hold = [], [], []
    for i, (plan, _info, count) in enumerate(plans):
        Zi, Ui = reference.sample(i, 0.0, h, count)
        Z.append(Zi[:, :count])
        U.append(Ui)
        hold.append((h * np.arange(count) >= plan.T - 1e-9).astype(float) * HOLD)
    Z = np.hstack(Z)
    if Z.shape[0] != NZ:
        raise RuntimeError("reference table: unexpected state size")
    return EmbeddedReference(Z, np.concatenate(U), np.concatenate(hold), h, legs)
