"""Stops: when one counts as reached (``StopRule``), watching one sample by sample (``StopMonitor``), and
the stops reached along a trajectory (``reached_stops``); shared by the controllers and the metrics.

Positions are floor-frame metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["StopRule", "StopMonitor", "reached_stops", "STOP_TOLERANCE"]

STOP_TOLERANCE = 0.07  # m, the paper's stop accuracy with motion capture


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
