"""Kind ``gates``: pass through points in order without stopping (the paper's waypoint layer, "move across
a certain point s_g at velocity v_g").

Table::

    [gates]
    points    = [[0.0, 1.0], [1.0, 1.0], [1.0, 0.0]]   # m, passed in order, no stop
    tolerance = 0.05                                   # m, largest allowed miss distance

Metrics (``Gates.metrics``, on the true trajectory): ``gate_misses`` (closest
approach to each gate, m), ``gate_times`` (when each gate was passed, s),
``completion_time`` (when the last was passed, s), ``avg_speed`` and
``completed`` (every miss within ``tolerance``; a contact event fails the run).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.missions.base import Mission, check_point, path_length, register
from rollbot_oc.missions.schema import number, points
from rollbot_oc.missions.stops import STOP_TOLERANCE
from rollbot_oc.missions.waypoints import Waypoint
from rollbot_oc.core.reproducible import norm
from rollbot_oc.view.text import number as shown  # a value with its unit, as the summaries print it

__all__ = ["Gates", "gate_passes", "PassMonitor", "PASS_SPEED"]

PASS_SPEED = 0.3  # m/s, the PID's speed through a gate (its quasi-stable revolving speed there)


def gate_passes(t, positions, gates, tolerance: float) -> list[dict]:
    """When, and how closely, a trajectory passes each gate in order.

    Gate i is measured on the trajectory from the instant gate i-1 was passed
    (from the start for the first gate).  A *visit* of gate i is a maximal run
    of consecutive samples within ``tolerance`` of it; gate i is *passed* at the
    sample of closest approach of its first visit, and that distance is its
    miss.  A gate the trajectory never comes within ``tolerance`` of is not
    passed: its miss is its closest approach over the rest of the trajectory,
    and the next gate is measured from that instant.

    Parameters
    ----------
    t : array_like (K,)
        Times, s.
    positions : array_like (2, K)
        Shell-centre positions, m.
    gates : sequence of (2,) points, m
    tolerance : float
        Largest allowed miss, m.

    Returns
    -------
    list of dict
        For each gate in order: ``miss`` (m), ``time`` (of the closest approach counted, s) and ``passed``.
    """
    t, positions = np.asarray(t, float), np.asarray(positions, float)
    records, start = [], 0
    for gate in gates:
        distance = np.hypot(positions[0, start:] - gate[0], positions[1, start:] - gate[1])
        inside = np.flatnonzero(distance <= tolerance)
        if inside.size:
            first = inside[0]
            left = np.flatnonzero(distance[first:] > tolerance)
            end = first + (left[0] if left.size else distance.size - first)
            k = first + int(np.argmin(distance[first:end]))
        else:
            k = int(np.argmin(distance))
        records.append({"miss": float(distance[k]), "time": float(t[start + k]), "passed": bool(inside.size)})
        start += k
    return records


class PassMonitor:
    """Watches the approach of one point sample by sample (a controller on its measurements): passed at
    the closest approach within ``tolerance`` (m), once the distance grows again.

    Parameters
    ----------
    point : array_like (2,)
        The point, m.
    tolerance : float
        Largest miss, m.
    """

    def __init__(self, point, tolerance: float):
        self.point, self.tolerance = np.asarray(point, float), tolerance
        self.miss = math.inf  # distance at the previous sample, m

    def update(self, position) -> bool:
        """Feed one position (m); True once the point is passed (the previous sample was its closest)."""
        miss = float(np.hypot(*(np.asarray(position, float) - self.point)))
        passed = self.miss < self.tolerance and miss > self.miss
        self.miss = miss
        return passed


@register
@dataclass(frozen=True)
class Gates(Mission):
    """Pass through ``points`` in order, each within ``tolerance``, without stopping.

    Attributes
    ----------
    points : tuple of numpy.ndarray (2,)
        The gates s_g, m.
    tolerance : float
        Largest allowed miss distance, m.
    speed : float
        The PID's speed through each gate, m/s (``waypoints``).
    """

    kind = "gates"
    keys = frozenset({"points", "tolerance"})

    points: tuple
    tolerance: float = STOP_TOLERANCE
    speed: float = PASS_SPEED

    def __post_init__(self):
        pts = tuple(check_point(p, "gate") for p in self.points)
        if not pts:
            raise ValueError("gates: give at least one point")
        object.__setattr__(self, "points", pts)
        for name in ("tolerance", "speed"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"gate {name} = {value!r} must be > 0")
        for i, (a, b) in enumerate(zip(pts[:-1], pts[1:])):
            if norm(b - a) <= 2 * self.tolerance:
                raise ValueError(f"gates {i + 1} and {i + 2} are {norm(b - a):.4g} m apart: they must be "
                                 f"more than twice the tolerance ({2 * self.tolerance:g} m) apart")

    @classmethod
    def from_table(cls, table, where, params, duration):
        tolerance = number(table, "tolerance", where, 1e-3, 1.0, default=STOP_TOLERANCE)
        gates = points(table, "points", where)
        try:
            return cls(tuple(gates), tolerance)
        except ValueError as exc:
            raise ConfigError(f"{where}: key 'points': {exc}") from None

    def to_table(self) -> dict:
        return {"points": [p.tolist() for p in self.points], "tolerance": float(self.tolerance)}

    @property
    def gates(self) -> list[np.ndarray]:
        return list(self.points)

    @property
    def pass_tolerance(self) -> float:
        return self.tolerance

    def verdict(self, metrics: dict) -> list[str]:
        """Completed and when, or how many gates were passed; the worst miss."""

        misses = metrics["gate_misses"]
        head = (f"completed in {shown(metrics['completion_time'], '.1f', 's')}" if metrics["completed"] else
                f"NOT completed: {metrics['gates_passed']} of {len(self.points)} gates passed in "
                f"{shown(metrics['duration'], '.1f', 's')}")
        return [head, f"worst gate miss {shown(max(misses), '.1f', 'cm', 100)}" if misses else ""]

    def leg(self, index: int) -> "Gates":
        """The gates from ``index`` on (the last gate if all are passed)."""
        return Gates(self.points[min(index, len(self.points) - 1):], self.tolerance, self.speed)

    def directions(self) -> list[np.ndarray]:
        """Unit direction of travel through each gate: towards the next gate (the last keeps the direction
        it was reached in, from the gate before; a single gate points along +x)."""
        out = []
        for i, p in enumerate(self.points):
            if i + 1 < len(self.points):
                d = self.points[i + 1] - p
            elif i > 0:
                d = p - self.points[i - 1]
            else:
                d = np.array([1.0, 0.0])
            out.append(d / norm(d))
        return out

    @property
    def waypoints(self) -> tuple:
        """Pass-through waypoints at ``speed`` along ``directions`` (the paper's waypoint layer)."""
        return tuple(Waypoint(p, stop=False, velocity=self.speed * d) for p, d in zip(self.points, self.directions()))

    def metrics(self, result) -> dict:
        """``gate_misses`` (m) and ``gate_times`` (s) by ``gate_passes``; once every gate is passed,
        ``completion_time`` (the last gate's, s) and ``avg_speed`` (the straight path's length over it, m/s)."""
        passes = gate_passes(result.t, result.position, self.points, self.tolerance)
        out = {"gate_misses": [p["miss"] for p in passes], "gate_times": [p["time"] for p in passes],
               "gates_passed": sum(p["passed"] for p in passes)}
        if all(p["passed"] for p in passes):
            out["completion_time"] = passes[-1]["time"]
            out["avg_speed"] = path_length(result.position[:, 0], self.points) / max(passes[-1]["time"], 1e-9)
            out["completed"] = True
        return out
