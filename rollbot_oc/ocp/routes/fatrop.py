"""The fatrop route: a structure-exploiting interior point for stage-wise problems."""

from __future__ import annotations

import casadi as ca

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.ocp.routes.ipopt import NLPRoute

__all__ = ["FatropRoute", "fatrop_status"]

# fatrop's IpSolverReturnFlag, in its order (fatrop 1.x); CasADi reports its index as stats()["fatrop"]["return_flag"]
# (its own "return_status" is only 0 or 1)
_FLAGS = ("Success", "MaxIterExceeded", "StopAtTinyStep", "StopAtAcceptablePoint", "LocalInfeasibility",
          "FeasiblePointFound", "DivergingIterates", "ErrorInStepComputation", "InvalidOption", "InternalError",
          "Unknown")


def fatrop_status(stats: dict) -> str:
    """fatrop's named return status from an ``nlpsol``'s stats (``"fatrop flag N"`` for a flag it does not name)."""
    flag = stats.get("fatrop", {}).get("return_flag")
    if isinstance(flag, int) and 0 <= flag < len(_FLAGS):
        return _FLAGS[flag]
    return f"fatrop flag {flag}"


class FatropRoute(NLPRoute):
    """fatrop on the transcription, where it applies: fixed durations, no global variables, no node slacks.

    The transcription orders ``w`` stage by stage and writes every continuity
    gap as ``x_{k+1} - F(x_k, u_k)``, which is what fatrop's structure
    detection needs; global entries (free durations, variables, node slacks)
    would couple all stages, so those problems are refused with a clear error.
    """

    name = "fatrop"

    def __init__(self, transcription, max_iter: int = 500, tol: float = 1e-8, options: dict | None = None):
        L = transcription.layout
        if L.nt or L.variables or L.node_slacks.stop > L.node_slacks.start:
            raise ConfigError("the fatrop route applies to stage-wise problems: fixed durations, no global "
                              "variables and no soft node constraints; use 'ipopt' or 'sqp'")
        if not ca.has_nlpsol("fatrop"):
            raise ConfigError("the fatrop route needs CasADi's fatrop plugin, which this CasADi lacks")
        self.transcription = tr = transcription
        nlp = {"x": tr.w, "p": tr.par, "f": tr.f, "g": tr.g}
        opts = {"structure_detection": "auto", "equality": (tr.lbg == tr.ubg).tolist(), "expand": True,
                "print_time": False, "debug": False,
                "fatrop": {"print_level": 0, "max_iter": max_iter, "tol": tol, **(options or {})}}
        self.solver = ca.nlpsol("ocp_fatrop", "fatrop", nlp, opts)

    def attempt(self, guess=None, warm=None, **parameters):
        """Solve and return the solution whatever its status, named from fatrop's return flag."""
        solution = super().attempt(guess, warm, **parameters)
        solution.status = fatrop_status(self.solver.stats())
        return solution
