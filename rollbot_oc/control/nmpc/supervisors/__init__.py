"""The NMPC's supervisors, one per mission kind: each an explicit machine of modes (``nmpc.modes``)."""

from rollbot_oc.control.nmpc.supervisors.base import Context, Supervisor
from rollbot_oc.control.nmpc.supervisors.gates import GATE_REPLANS, GatesSupervisor
from rollbot_oc.control.nmpc.supervisors.orbit import OrbitSupervisor
from rollbot_oc.control.nmpc.supervisors.stops import LegKind, StopsSupervisor

__all__ = ["Context", "Supervisor", "StopsSupervisor", "OrbitSupervisor", "GatesSupervisor", "LegKind",
           "GATE_REPLANS", "supervisor_for"]


def supervisor_for(mission) -> type[Supervisor]:
    """The supervisor class of ``mission``'s kind: stops, an orbit or gates."""
    if mission.gates:
        return GatesSupervisor
    if mission.orbit is not None:
        return OrbitSupervisor
    return StopsSupervisor
