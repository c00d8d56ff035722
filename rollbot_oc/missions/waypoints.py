"""Kind ``waypoints``: stop at each point in turn (the paper's "Moving between Waypoints").

Table::

    [waypoints]
    stops = [[0.0, 0.0], [0.0, 1.2]]     # m
    stop_tolerance = 0.07                # m: a stop is reached within this, at rest (speed < 5 mm/s,
                                         # driving speed < 0.05 rad/s) for 0.5 s (``StopRule``)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from rollbot_oc.model.dynamics import OMEGA
from rollbot_oc.missions.base import Mission, check_point, path_length, register
from rollbot_oc.missions.schema import number, points
from rollbot_oc.missions.stops import STOP_TOLERANCE, StopRule, reached_stops
from rollbot_oc.core.reproducible import norm
from rollbot_oc.view.text import number as shown  # a value with its unit, as the summaries print it

__all__ = ["Waypoint", "Waypoints"]


@dataclass(frozen=True)
class Waypoint:
    """A point to stop at, or to pass through with a given velocity.

    Attributes
    ----------
    point : numpy.ndarray (2,)
        Target position s_g, m.
    stop : bool
        Stop there (come to rest), or pass through it.
    velocity : numpy.ndarray (2,) or None
        Velocity to pass with, m/s (only when ``stop`` is False).
    """

    point: np.ndarray
    stop: bool = True
    velocity: np.ndarray | None = None

    def __post_init__(self):
        object.__setattr__(self, "point", check_point(self.point, "waypoint"))
        if self.stop and self.velocity is not None:
            raise ValueError(f"waypoint {self.point.tolist()}: a stop has no velocity")
        if not self.stop:
            if self.velocity is None:
                raise ValueError(f"waypoint {self.point.tolist()}: a pass-through needs a velocity (m/s)")
            v = check_point(self.velocity, "waypoint velocity")
            if norm(v) <= 0:
                raise ValueError(f"waypoint {self.point.tolist()}: velocity must be non-zero")
            object.__setattr__(self, "velocity", v)


@register
@dataclass(frozen=True)
class Waypoints(Mission):
    """Visit waypoints in order (the paper's "Moving between Waypoints").

    Attributes
    ----------
    points : tuple of Waypoint
    tolerance : float
        Distance within which a pass-through counts as reached, m.
    stop_tolerance : float
        Distance within which a stop counts as reached (with the robot at rest, ``StopRule``), m.
    """

    kind = "waypoints"
    keys = frozenset({"stops", "stop_tolerance"})

    points: tuple
    tolerance: float = 0.07
    stop_tolerance: float = STOP_TOLERANCE

    def __post_init__(self):
        pts = tuple(p if isinstance(p, Waypoint) else Waypoint(p) for p in self.points)
        if not pts:
            raise ValueError("waypoints: give at least one point")
        object.__setattr__(self, "points", pts)
        for name in ("tolerance", "stop_tolerance"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"waypoint {name} = {value!r} must be > 0 m")

    @classmethod
    def from_table(cls, table, where, params, duration):
        tolerance = number(table, "stop_tolerance", where, 1e-3, 1.0, default=STOP_TOLERANCE)
        return cls(tuple(points(table, "stops", where)), stop_tolerance=tolerance)

    def to_table(self) -> dict:
        return {"stops": [p.tolist() for p in self.stops], "stop_tolerance": float(self.stop_tolerance)}

    @property
    def stop_rule(self) -> StopRule:
        """When a stop counts as reached (within ``stop_tolerance``, at rest for 0.5 s)."""
        return StopRule(tolerance=self.stop_tolerance)

    @property
    def stops(self) -> list[np.ndarray]:
        """The points to stop at, m."""
        return [w.point for w in self.points if w.stop]

    @property
    def waypoints(self) -> tuple:
        return self.points

    @property
    def pass_tolerance(self) -> float:
        return self.tolerance

    def verdict(self, metrics: dict) -> list[str]:
        """Completed and when, or how many stops were reached; the worst stop error."""

        errors = metrics["stop_errors"]
        worst = f"worst stop error {shown(max(errors), '.1f', 'cm', 100)}" if errors else ""
        head = (f"completed in {shown(metrics['completion_time'], '.1f', 's')}" if metrics["completed"] else
                f"NOT completed: {len(errors)} of {len(self.stops)} stops in {shown(metrics['duration'], '.1f', 's')}")
        return [head, worst]

    def first(self, count: int) -> "Waypoints":
        """The first ``count`` waypoints (>= 1), with the same tolerances: a shorter course."""
        if not (isinstance(count, int) and 1 <= count <= len(self.points)):
            raise ValueError(f"waypoints: first {count!r} of {len(self.points)} (give 1 to {len(self.points)})")
        return replace(self, points=self.points[:count])

    def leg(self, index: int) -> "Waypoints":
        """The stop ``index`` alone."""
        return Waypoints((self.stops[index],), stop_tolerance=self.stop_tolerance)

    def metrics(self, result) -> dict:
        """Stops reached by the true trajectory (``StopRule``: near the waypoint and at rest for 0.5 s), in
        order: ``stop_errors`` (m), ``stop_times`` (s); once all are reached ``completion_time`` (s) and
        ``avg_speed`` (the straight path's length over it, m/s)."""
        centre_speed = result.params.R * np.hypot(result.x[OMEGA][0], result.x[OMEGA][1])
        stops = reached_stops(result.t, result.position, centre_speed, result.driving_speed, self.stops,
                              self.stop_rule)
        errors = [float(stop["error"]) for stop in stops]
        out = {"stop_errors": errors, "stop_times": [float(stop["time"]) for stop in stops]}
        if result.estimation is not None:  # the robot's belief is no measurement: the true position counts
            out.update(_onboard_stop_metrics(stops, result))
        if len(stops) == len(self.stops):
            out["completion_time"] = float(stops[-1]["time"])
            out["avg_speed"] = path_length(result.position[:, 0], self.stops) / out["completion_time"]
            out["completed"] = True
        return out


def _onboard_stop_metrics(stops: list, result) -> dict:
    """Stop errors of the true position, and how far the estimate was off at each stop (onboard sensing)."""
    record = result.estimation
    steps = [min(int(round(stop["time"] / result.dt)), len(record) - 1) for stop in stops]
    truth = [result.position[:, k] for k in steps]
    estimated = [record.estimate[0:2, k] for k in steps]
    return {
        "stop_errors": [float(norm(s - np.asarray(stop["point"]))) for s, stop in zip(truth, stops)],
        "estimated_stop_errors": [float(norm(e - np.asarray(stop["point"])))
                                  for e, stop in zip(estimated, stops)],
        "estimation_errors": [float(norm(s - e)) for s, e in zip(truth, estimated)],
        "max_estimation_error": max((float(norm(s - e)) for s, e in zip(truth, estimated)), default=None),
        "stop_position_std": [float(np.sqrt(np.trace(record.position_covariance[k]))) for k in steps],
    }
