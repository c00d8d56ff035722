"""What a controller is asked to do: revolve on a circle, or stop at (or pass) waypoints.

Missions are plain data shared by every controller (the paper's PID baseline
and the NMPC), by the scenario files (``rollbot_oc.problems``) and by the
metrics.  Positions are floor-frame metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Circle", "Waypoint", "Waypoints", "Mission", "centre_of_curvature"]


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
    """

    points: tuple
    tolerance: float = 0.07

    def __post_init__(self):
        pts = tuple(p if isinstance(p, Waypoint) else Waypoint(p) for p in self.points)
        if not pts:
            raise ValueError("waypoints: give at least one point")
        object.__setattr__(self, "points", pts)
        if not (math.isfinite(self.tolerance) and self.tolerance > 0):
            raise ValueError(f"waypoint tolerance = {self.tolerance!r} must be > 0 m")

    @property
    def stops(self) -> list[np.ndarray]:
        """The points to stop at, m."""
        return [w.point for w in self.points if w.stop]


Mission = Circle | Waypoints
