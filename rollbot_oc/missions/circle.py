"""Kind ``circle``: revolve about a set point at a set radius (the paper's "Stable Circular Motion").

Table::

    [circle]
    centre      = [0.0, 0.0]     # m
    radius      = 0.35           # m, within the robot's quasi-stable range [R tan(phi), R0(max_speed)]
    settle_time = 120.0          # s: deviations are measured after this (and after reaching)
    reach_tolerance = 0.05       # m: "reached" = within this of the circle for REACH_HOLD s
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.missions.base import Mission, check_point, register
from rollbot_oc.missions.schema import POSITION_LIMIT, number, point
from rollbot_oc.analysis.quasi_stable import RadiusMap
from rollbot_oc.view.text import number as shown  # a value with its unit, as the summaries print it

__all__ = ["Circle", "REACH_HOLD"]

REACH_HOLD = 10.0  # s the robot must stay within reach_tolerance of the circle to count as arrived


@functools.lru_cache(maxsize=32)
def _radius_range(params) -> tuple[float, float]:
    """The robot's quasi-stable radii ``[R_min, R_max]`` (slow branch, level floor), m."""

    radius_map = RadiusMap(params.replace(slope=0.0))
    return radius_map.R_min, radius_map.R_max


def _check_radius(table: dict, params, where: str) -> float:
    """The circle's radius, m: within the quasi-stable range of this robot, where it can revolve steadily."""
    radius = number(table, "radius", where, 0.0, POSITION_LIMIT, required=True)
    low, high = _radius_range(params)
    if not low <= radius <= high:
        raise ConfigError(f"{where}: key 'radius' = {radius!r} m is out of range: valid for this robot is "
                          f"[{low:.4f}, {high:.4f}] m (its quasi-stable radii, driving speeds 0 to "
                          f"{params.max_speed:.4g} rad/s)")
    return radius


@register
@dataclass(frozen=True)
class Circle(Mission):
    """Revolve about ``centre`` at ``radius`` (the paper's "Stable Circular Motion").

    Attributes
    ----------
    centre : numpy.ndarray (2,)
        Centre of the target circle, m.
    radius : float
        Target revolving radius R_g, m.
    settle_time : float
        Deviations are measured after this time (and after reaching), s.
    reach_tolerance : float
        Distance from the circle that counts as arrived (held for ``REACH_HOLD`` s), m.
    """

    kind = "circle"
    keys = frozenset({"centre", "radius", "settle_time", "reach_tolerance"})

    centre: np.ndarray
    radius: float
    settle_time: float = 0.0
    reach_tolerance: float = 0.05

    def __post_init__(self):
        object.__setattr__(self, "centre", check_point(self.centre, "circle centre"))
        if not (math.isfinite(self.radius) and self.radius > 0):
            raise ValueError(f"circle radius = {self.radius!r} must be a finite length > 0 m")

    @classmethod
    def from_table(cls, table, where, params, duration):
        centre = point(table, "centre", where, label="c")
        radius = _check_radius(table, params, where)
        settle = number(table, "settle_time", where, 0.0, duration, default=0.0)
        tol = number(table, "reach_tolerance", where, 1e-3, 10.0, default=0.05)
        return cls(centre, radius, settle, tol)

    def to_table(self) -> dict:
        return {"centre": self.centre.tolist(), "radius": float(self.radius), "settle_time": float(self.settle_time),
                "reach_tolerance": float(self.reach_tolerance)}

    @property
    def orbit(self) -> "Circle":
        """The circle itself."""
        return self

    @classmethod
    def tracking_terms(cls, ocp) -> list:
        """The distance from the circle (m): on the orbit only that is the mission, not the point on it."""
        circle = ocp.parameter("circle", 3)  # centre x, y and radius, m
        return [ca.sqrt(ca.sumsqr(ocp.state.position - circle[0:2]) + 1e-9) - circle[2]]

    def tracking_values(self) -> dict:
        return {"circle": np.concatenate([self.centre, [self.radius]])}

    def verdict(self, metrics: dict) -> list[str]:
        """On the circle and when, the deviations; or why not completed."""

        m = metrics
        if m["completed"]:
            return [f"on the circle after {shown(m['reach_time'], '.1f', 's')}",
                    f"deviation {shown(m['avg_deviation'], '.2f', 'cm', 100)} average, "
                    f"{shown(m['max_deviation'], '.2f', 'cm', 100)} largest"]
        if m.get("reach_time") is None:
            return [f"NOT completed: not on the circle within {shown(m['duration'], '.1f', 's')}"]
        return [f"NOT completed: on the circle after {shown(m['reach_time'], '.1f', 's')}, but the run ended at "
                f"{shown(m['duration'], '.1f', 's')}, before the deviations could be measured (from "
                f"{shown(m.get('settle_time'), '.0f', 's')} on)"]

    def deviation(self, positions) -> np.ndarray:
        """Distance (m) of each position (2, n) from the target circle."""
        p = np.asarray(positions, float)
        return np.abs(np.hypot(p[0] - self.centre[0], p[1] - self.centre[1]) - self.radius)

    def metrics(self, result) -> dict:
        """``reach_time`` (first time within ``reach_tolerance`` for ``REACH_HOLD`` s, s), the deviations
        from the circle after ``settle_time`` and reaching (mean and largest, m), ``avg_speed`` (m/s)."""
        t, s = result.t, result.position
        deviation = self.deviation(s)
        inside = deviation < self.reach_tolerance
        hold = int(round(REACH_HOLD / result.dt))
        # first index from which the robot stays within tolerance for REACH_HOLD seconds
        run = np.convolve(inside.astype(int), np.ones(hold, int), mode="valid") if len(inside) >= hold \
            else np.array([])
        reached = np.flatnonzero(run == hold)
        reach_time = float(t[reached[0]]) if reached.size else None
        start_distance = float(self.deviation(s[:, :1])[0])
        measure_from = max(self.settle_time, reach_time if reach_time is not None else self.settle_time)
        window = t >= measure_from
        out = {"reach_time": reach_time, "completion_time": reach_time, "settle_time": measure_from,
               "avg_deviation": None, "max_deviation": None}
        if reach_time is not None and reach_time > 0:
            out["avg_speed"] = max(start_distance - self.reach_tolerance, 0.0) / reach_time
        if window.any() and t[-1] - measure_from >= REACH_HOLD:
            out["avg_deviation"] = float(deviation[window].mean())
            out["max_deviation"] = float(deviation[window].max())
        out["completed"] = reach_time is not None and out["avg_deviation"] is not None
        return out
