"""Solver routes: one ``Transcription``, several ways to solve it, behind one small protocol.

* ``"ipopt"``: interior point to convergence (exact or limited-memory Hessian);
* ``"sqp"``: Gauss-Newton SQP to convergence, its Hessian ``J_r^T J_r`` and
  gradients from the AD Jacobians of the least-squares residuals, QPs by a
  CasADi conic solver (``qrqp`` by default);
* ``"rti"``: the same SQP, one iteration per call from a warm start (the
  real-time iteration of NMPC);
* ``"fatrop"``: fatrop's structure-exploiting interior point, where the
  problem is stage-wise (fixed durations, no global variables or node slacks).

Every route returns an ``OCPSolution`` with a named status, its iterations and
its solve time, and ``to_function()`` gives a CasADi Function for repeated
solves (or code generation).
"""

from __future__ import annotations

from typing import Protocol

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.ocp.routes.fatrop import FatropRoute
from rollbot_oc.ocp.routes.ipopt import IpoptRoute
from rollbot_oc.ocp.routes.sqp import RTIRoute, SQPRoute

__all__ = ["Route", "ROUTES", "make_route"]


class Route(Protocol):
    """What every solver route offers."""

    name: str

    def solve(self, guess=None, warm=None, **parameters):
        """Solve for the named parameters from a guess (decision vector) or a warm start (a solution)."""

    def to_function(self):
        """A CasADi Function ``(w_guess, parameters) -> w`` for repeated solves."""


def _routes() -> dict:
    return {"ipopt": IpoptRoute, "sqp": SQPRoute, "rti": RTIRoute, "fatrop": FatropRoute}


ROUTES = ("ipopt", "sqp", "rti", "fatrop")


def make_route(name: str, transcription, **options):
    """The route ``name`` built (once) for ``transcription``."""
    routes = _routes()
    if name not in routes:
        raise ConfigError(f"solver route = {name!r}; valid are {', '.join(ROUTES)}")
    return routes[name](transcription, **options)
