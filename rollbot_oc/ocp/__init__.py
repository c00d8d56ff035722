"""rollbot_oc's optimal-control layer: write an OCP once, solve it by any route.

``OCP`` describes the problem (``problem``) on a model (``OCPModel``: the dynamics and the names of the
states, controls and parameters, ``model``), ``Transcription`` turns it into one NLP (direct multiple
shooting), and ``routes`` solve that NLP (IPOPT, Gauss-Newton SQP, RTI, fatrop), each returning an
``OCPSolution`` with a named status.  The layer knows no particular system: Rollbot's model and named limits
are in ``rollbot_oc.planning.rollbot`` (``rollbot_model``, ``rollbot_ocp``).

``rollbot_oc.ocp.rollbot_model`` and ``rollbot_oc.ocp.constraints`` still import, as names and a module that
moved (``rollbot_oc.MOVED_NAMES``, ``rollbot_oc.MOVED``).
"""

import rollbot_oc
from rollbot_oc.ocp.model import OCPModel
from rollbot_oc.ocp.problem import OCP, Constraint, FreeTime, bounded
from rollbot_oc.ocp.routes import ROUTES, make_route
from rollbot_oc.ocp.solution import OCPSolution
from rollbot_oc.ocp.transcription import Layout, Transcription

__all__ = ["OCP", "Constraint", "FreeTime", "bounded", "OCPModel", "OCPSolution", "Transcription", "Layout",
           "ROUTES", "make_route"]


def __getattr__(name: str):
    return rollbot_oc.moved_name(__name__, name)
