"""Missions: what a controller is asked to do and how a run of it is measured, one kind per module.

Each kind (``circle``, ``waypoints``, ``open_loop``, ``gates``) is a
``Mission`` class registered by name (``register``, ``KINDS``,
``mission_kind``); see ``rollbot_oc.missions.base``.  Stops are judged by
the shared ``StopRule`` (``rollbot_oc.missions.stops``).
"""

from rollbot_oc.missions.base import KINDS, Mission, centre_of_curvature, mission_kind, register
from rollbot_oc.missions.stops import STOP_TOLERANCE, StopMonitor, StopRule, reached_stops
from rollbot_oc.missions.circle import REACH_HOLD, Circle
from rollbot_oc.missions.waypoints import Waypoint, Waypoints
from rollbot_oc.missions.open_loop import OpenLoop
from rollbot_oc.missions.gates import Gates, PassMonitor, gate_passes

__all__ = ["Mission", "register", "mission_kind", "KINDS", "Circle", "Waypoint", "Waypoints", "OpenLoop", "Gates",
           "gate_passes", "PassMonitor", "centre_of_curvature", "StopRule", "StopMonitor", "reached_stops", "STOP_TOLERANCE",
           "REACH_HOLD"]
