"""What the NMPC tracks: a chain of planned legs with holds at the stops, or an entry onto an orbit."""

from __future__ import annotations

import functools
import math

import casadi as ca
import numpy as np

from rollbot_oc.planning.min_time import orbit_state
from rollbot_oc.model.dynamics import NZ

__all__ = ["Reference"]


@functools.lru_cache(maxsize=None)
def _orbit_function(n: int) -> ca.Function:
    """``ocp.orbit_state`` mapped over ``n`` phases: ``(qs (10,), centre (2,), phases (1, n)) -> states (10, n)``."""
    qs, centre, phase = ca.SX.sym("qs", NZ), ca.SX.sym("centre", 2), ca.SX.sym("phase")
    one = ca.Function("orbit_state", [qs, centre, phase], [orbit_state(qs, centre, phase)])
    return one.map(n)  # qs and centre are broadcast


def _orbit_states(qs, centre, phases) -> np.ndarray:
    """The reduced states (10, n) on the orbit at ``phases`` (rad): ``ocp.orbit_state``, batched."""
    phases = np.atleast_1d(np.asarray(phases, float))
    return np.array(_orbit_function(phases.size)(qs, centre, phases[None, :]))


def _wrap(angle: float) -> float:
    """Angle wrapped to (-pi, pi], rad."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


class Reference:
    """What the NMPC tracks: a chain of planned legs with holds at the stops, or an entry onto an orbit.

    Parameters
    ----------
    segments : list of (Plan, dict)
        Plans in order with a description (``{"stop": point}`` for a stop).
    orbit : dict, optional
        After the last segment, the quasi-stable orbit to follow (``qs``,
        ``centre``, ``phase``, ``Omega``).
    """

    def __init__(self, segments, orbit=None):
        self.segments, self.orbit = segments, orbit

    def sample(self, index: int, t_local, h: float, N: int, position=None):
        """Reference states (10, N+1) and accelerations (N,) for segment ``index`` from local time ``t_local``.

        On the orbit, ``position`` (m) re-phases the reference to the robot's own angle about the centre:
        only the distance from the circle is the mission, not being at a particular point of it.
        """
        times = t_local + h * np.arange(N + 1)
        plan = self.segments[index][0]
        Z = plan.state(times)
        U = np.array([plan.accel(t) for t in times[:-1]])
        after = self.ended(index, t_local, h, N)
        if self.orbit is not None and index == len(self.segments) - 1:
            if np.any(after):
                o = self.orbit
                phases = o["phase"] + o["Omega"] * (times[after] - plan.T)
                if position is not None and after[0]:
                    rel = np.asarray(position) - o["centre"]
                    own = math.atan2(rel[1], rel[0]) - math.atan2(o["qs"][1], o["qs"][0])
                    phases = phases + _wrap(own - phases[0])
                Z[:, after] = _orbit_states(o["qs"], o["centre"], phases)
        elif np.any(after):
            Z[6:10, after] = 0.0  # hold the rest state at the stop
        return Z, U

    def ended(self, index: int, t_local: float, h: float, N: int) -> np.ndarray:
        """Which of the N+1 horizon nodes from ``t_local`` (s on segment ``index``, nodes ``h`` s apart) lie
        past the end of its plan (bool (N+1,)): where ``sample`` holds rest (or follows the orbit)."""
        return t_local + h * np.arange(N + 1) > self.segments[index][0].T
