"""A planned trajectory (``Plan``), the orbit's states (``orbit_state``), and the failure of a plan."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from rollbot_oc.model.dynamics import REDUCED
from rollbot_oc.core.errors import NotConverged
from rollbot_oc.model.rotations import quat_multiply

__all__ = ["Plan", "SolveFailed", "orbit_state"]


class SolveFailed(NotConverged):
    """An optimisation did not converge; carries its solver status and the failed plan."""

    def __init__(self, what: str, status: str, plan=None):
        super().__init__(what, status, plan)
        self.plan = plan


def orbit_state(qs_reduced, centre, phase):
    """The reduced quasi-stable state ``qs_reduced`` (revolving about the origin) turned by ``phase`` about ``centre``.

    Works on CasADi symbols and on numbers.
    """
    c, s = ca.cos(phase), ca.sin(phase)
    rot = ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))
    R = REDUCED
    pos = ca.mtimes(rot[0:2, 0:2], qs_reduced[R.position]) + centre
    quat = quat_multiply(ca.vertcat(ca.cos(phase / 2), 0, 0, ca.sin(phase / 2)), qs_reduced[R.quaternion])
    return ca.vertcat(pos, quat, ca.mtimes(rot, qs_reduced[R.omega]), qs_reduced[R.theta_dot])


@dataclass
class Plan:
    """A solved trajectory (SI units): node times, reduced states and the motor-acceleration profile.

    Attributes
    ----------
    t : numpy.ndarray (N+1,)
        Node times, s (from 0).
    z : numpy.ndarray (10, N+1)
        Reduced states at the nodes.
    u : numpy.ndarray (N,)
        Motor acceleration on each interval, rad/s^2.
    T : float
        Duration, s.
    status : str
        Solver status.
    success : bool
    iterations : int
    solve_time : float
        Wall-clock time of the solve, s.
    extra : dict
        Problem-specific results (for example the orbit phase).
    """

    t: np.ndarray
    z: np.ndarray
    u: np.ndarray
    T: float
    status: str
    success: bool
    iterations: int
    solve_time: float
    extra: dict = field(default_factory=dict)

    def accel(self, t: float) -> float:
        """Planned motor acceleration at time ``t`` (s), rad/s^2; 0 after the end."""
        if t >= self.T or t < 0:
            return 0.0
        # a time on a node belongs to the interval it starts (guard against 0.3 / 0.1 = 2.999...)
        return float(self.u[min(int(math.floor(t / (self.T / len(self.u)) + 1e-9)), len(self.u) - 1)])

    def state(self, t) -> np.ndarray:
        """Planned reduced state at time(s) ``t`` (s), linear between nodes (quaternions renormalised)."""
        t = np.clip(np.asarray(t, float), 0.0, self.T)
        out = np.array([np.interp(t, self.t, row) for row in self.z])
        q = out[REDUCED.quaternion]
        out[REDUCED.quaternion] = q / np.linalg.norm(q, axis=0)
        return out

    def resample(self, N: int) -> "Plan":
        """The same trajectory on ``N`` equal intervals (states interpolated, accelerations at interval midpoints)."""
        return self.tail(0.0, N)

    def tail(self, t0: float, N: int, duration: float | None = None) -> "Plan":
        """The rest of the trajectory from time ``t0`` (s) on (at most ``duration`` s of it), on ``N`` equal
        intervals, its time from 0."""
        t0 = min(max(float(t0), 0.0), self.T)
        T = max(self.T - t0 if duration is None else min(float(duration), self.T - t0), 1e-3)
        t = np.linspace(0.0, T, N + 1)
        u = np.array([self.accel(t0 + tm) for tm in 0.5 * (t[1:] + t[:-1])])
        return Plan(t, self.state(t0 + t), u, T, self.status, self.success, self.iterations, self.solve_time,
                    dict(self.extra))

    @property
    def driving_speed(self) -> np.ndarray:
        """Planned driving speed at the nodes, rad/s."""
        return self.z[REDUCED.theta_dot]

    def to_dict(self) -> dict:
        """Summary for JSON."""
        return {"T": self.T, "status": self.status, "success": self.success, "iterations": self.iterations,
                "solve_time": self.solve_time, "end": self.z[:2, -1].tolist(), **self.extra}
