"""The missions, re-exported from ``rollbot_oc.missions`` (where each kind lives) for older imports."""

from rollbot_oc.missions import (  # noqa: F401
    STOP_TOLERANCE, Circle, Mission, StopMonitor, StopRule, Waypoint, Waypoints, centre_of_curvature, reached_stops,
)

__all__ = ["Circle", "Waypoint", "Waypoints", "Mission", "centre_of_curvature", "StopRule", "StopMonitor",
           "reached_stops", "STOP_TOLERANCE"]
