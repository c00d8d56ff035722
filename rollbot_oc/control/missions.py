"""What a controller is asked to do: revolve on a circle, or stop at (or pass) waypoints.

Missions are plain data shared by every controller (the paper's PID baseline
and the NMPC), by the scenario files (``rollbot_oc.problems``) and by the
metrics.  Positions are floor-frame metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Circle", "Waypoint", "Waypoints", "Mission", "centre_of_curvature", "StopRule", "StopMonitor",
           "reached_stops", "STOP_TOLERANCE"]

STOP_TOLERANCE = 0.07  # m, the paper's stop accuracy with motion capture


def _point(value, name: str) -> np.ndarray:
    arr = np.asarray(value, float).ravel()
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} = {value!r} must be two finite numbers (x, y) in m")
    return arr


def centre_of_curvature(position, heading: float, radius: float) -> np.ndarray:
    """The paper's eqn "ofunc": ``o = s - R0 (cos gamma, sin gamma)``.

    Parameters
    ----------
    position : array_like (2,) or (2, n)
        Shell-centre position s, m.
    heading : float or array_like (n,)
        gamma, the azimuth of the motor axis' horizontal projection, rad.
    radius : float or array_like (n,)
        Quasi-stable revolving radius R0 at the current driving speed, m.
    """
    return np.asarray(position, float) - radius * np.array([np.cos(heading), np.sin(heading)])


@dataclass(frozen=True)
class Circle:
    """Revolve about ``centre`` at ``radius`` (the paper's "Stable Circular Motion").

    Attributes
    ----------
    centre : numpy.ndarray (2,)
        Centre of the target circle, m.
    radius : float
        Target revolving radius R_g, m.
    """

    centre: np.ndarray
    radius: float

    def __post_init__(self):
        object.__setattr__(self, "centre", _point(self.centre, "circle centre"))
        if not (math.isfinite(self.radius) and self.radius > 0):
            raise ValueError(f"circle radius = {self.radius!r} must be a finite length > 0 m")

    def deviation(self, positions) -> np.ndarray:
        """Distance (m) of each position (2, n) from the target circle."""
        p = np.asarray(positions, float)
        return np.abs(np.hypot(p[0] - self.centre[0], p[1] - self.centre[1]) - self.radius)


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
        object.__setattr__(self, "point", _point(self.point, "waypoint"))
        if self.stop and self.velocity is not None:
            raise ValueError(f"waypoint {self.point.tolist()}: a stop has no velocity")
        if not self.stop:
            if self.velocity is None:
                raise ValueError(f"waypoint {self.point.tolist()}: a pass-through needs a velocity (m/s)")
            v = _point(self.velocity, "waypoint velocity")
            if np.linalg.norm(v) <= 0:
                raise ValueError(f"waypoint {self.point.tolist()}: velocity must be non-zero")
            object.__setattr__(self, "velocity", v)


@dataclass(frozen=True)
class Waypoints:
    """Visit waypoints in order (the paper's "Moving between Waypoints").

    Attributes
    ----------
    points : tuple of Waypoint
    tolerance : float
        Distance within which a pass-through counts as reached, m.
    stop_tolerance : float
        Distance within which a stop counts as reached (with the robot at rest, ``StopRule``), m.
    """

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

    @property
    def stop_rule(self) -> "StopRule":
        """When a stop counts as reached (within ``stop_tolerance``, at rest for 0.5 s)."""
        return StopRule(tolerance=self.stop_tolerance)

    @property
    def stops(self) -> list[np.ndarray]:
        """The points to stop at, m."""
        return [w.point for w in self.points if w.stop]


Mission = Circle | Waypoints


@dataclass(frozen=True)
class StopRule:
    """When a stop counts as reached: near the waypoint and at rest, for a while.

    Attributes
    ----------
    tolerance : float
        Largest distance of the shell centre from the waypoint, m.
    rest_speed : float
        Largest shell-centre speed at rest, m/s.
    rest_drive : float
        Largest driving speed at rest, rad/s.
    hold : float
        How long both must hold, s.
    """

    tolerance: float = STOP_TOLERANCE
    rest_speed: float = 0.005
    rest_drive: float = 0.05
    hold: float = 0.5

    def holds(self, position, point, centre_speed: float, driving_speed: float) -> bool:
        """True if the robot is near ``point`` (m) and at rest at this instant."""
        return (float(np.hypot(*(np.asarray(position, float) - point))) <= self.tolerance
                and centre_speed < self.rest_speed and abs(driving_speed) < self.rest_drive)


class StopMonitor:
    """Watches one stop with a ``StopRule``, sample by sample (controllers on measurements, metrics on the truth).

    Parameters
    ----------
    point : array_like (2,)
        The waypoint, m.
    rule : StopRule
    """

    def __init__(self, point, rule: StopRule):
        self.point, self.rule = np.asarray(point, float), rule
        self.since = None  # time the current stretch at rest near the point began, s
        self.rest_since = None  # time the current stretch at rest (anywhere) began, s
        self.settled_away = False  # at rest for the hold time, but away from the point

    def update(self, t: float, position, centre_speed: float, driving_speed: float) -> bool:
        """Feed one sample at time ``t`` (s); True once the rule has held for ``rule.hold`` seconds.

        ``settled_away`` turns True when the robot has been at rest for the hold
        time away from the point (a rocking robot passing through rest does not count).
        """
        rule = self.rule
        at_rest = centre_speed < rule.rest_speed and abs(driving_speed) < rule.rest_drive
        self.rest_since = (self.rest_since if self.rest_since is not None else t) if at_rest else None
        if not rule.holds(position, self.point, centre_speed, driving_speed):
            self.since = None
            self.settled_away = at_rest and t - self.rest_since >= rule.hold - 1e-9
            return False
        self.settled_away = False
        if self.since is None:
            self.since = t
        return t - self.since >= rule.hold - 1e-9

    def record(self, position) -> dict:
        """The stop's record: point, time it came to rest there (s) and its distance then (m)."""
        return {"point": self.point.tolist(), "time": float(self.since),
                "error": float(np.hypot(*(np.asarray(position, float) - self.point)))}


def reached_stops(t, positions, centre_speeds, driving_speeds, stops, rule: StopRule) -> list[dict]:
    """The stops reached in order along a trajectory, by ``rule`` (one ``StopMonitor`` after the other).

    Parameters
    ----------
    t : array_like (K,)
        Times, s.
    positions : array_like (2, K)
        Shell-centre positions, m.
    centre_speeds, driving_speeds : array_like (K,)
        Shell-centre speed (m/s) and driving speed (rad/s).
    stops : sequence of (2,) points, m
    rule : StopRule

    Returns
    -------
    list of dict
        ``StopMonitor.record`` of each stop reached, in order; a stop not reached ends the list.
    """
    records, index = [], 0
    positions = np.asarray(positions, float)
    for point in stops:
        monitor = StopMonitor(point, rule)
        while index < len(t) and not monitor.update(t[index], positions[:, index], centre_speeds[index],
                                                     driving_speeds[index]):
            index += 1
        if index >= len(t):
            break
        records.append(monitor.record(positions[:, index]))
        index += 1
    return records
