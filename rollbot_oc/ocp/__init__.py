"""rollbot_oc's optimal-control layer: write an OCP once, solve it by any route.

``OCP`` describes the problem (``problem``), ``constraints`` holds Rollbot's
named limits, ``Transcription`` turns it into one NLP (direct multiple
shooting), and ``routes`` solve that NLP (IPOPT, Gauss-Newton SQP, RTI,
fatrop), each returning an ``OCPSolution`` with a named status.
"""

from rollbot_oc.ocp.model import OCPModel, rollbot_model
from rollbot_oc.ocp.problem import OCP, Constraint, FreeTime, bounded
from rollbot_oc.ocp.routes import ROUTES, make_route
from rollbot_oc.ocp.solution import OCPSolution
from rollbot_oc.ocp.transcription import Layout, Transcription

__all__ = ["OCP", "Constraint", "FreeTime", "bounded", "OCPModel", "rollbot_model", "OCPSolution",
           "Transcription", "Layout", "ROUTES", "make_route"]
