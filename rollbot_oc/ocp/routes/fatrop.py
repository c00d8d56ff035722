"""The fatrop route: a structure-exploiting interior point for stage-wise problems."""

from __future__ import annotations

import time

import casadi as ca
import numpy as np

from rollbot_oc.errors import ConfigError
from rollbot_oc.ocp.routes.ipopt import call_nlp, nlp_solution

__all__ = ["FatropRoute"]


class FatropRoute:
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

    def solve(self, guess=None, warm=None, **parameters):
        """Solve to convergence; raises ``NotConverged`` if it does not."""
        return self.attempt(guess, warm, **parameters).check()

    def attempt(self, guess=None, warm=None, **parameters):
        """Solve and return the solution whatever its status."""
        tr = self.transcription
        par = tr.parameter_vector(parameters)
        x0 = warm.w if warm is not None else (tr.default_guess() if guess is None else np.asarray(guess, float))
        start = time.perf_counter()
        sol = call_nlp(self.solver, dict(x0=x0, p=par, lbx=tr.lbw, ubx=tr.ubw, lbg=tr.lbg, ubg=tr.ubg))
        return nlp_solution(self.name, self.solver, tr, sol, par, time.perf_counter() - start)

    def to_function(self) -> ca.Function:
        """``(w_guess, par) -> w``."""
        tr = self.transcription
        w0, par = ca.MX.sym("w0", tr.w.numel()), ca.MX.sym("par", tr.par.numel())
        sol = self.solver(x0=w0, p=par, lbx=tr.lbw, ubx=tr.ubw, lbg=tr.lbg, ubg=tr.ubg)
        return ca.Function("ocp_fatrop_solve", [w0, par], [sol["x"]], ["w0", "par"], ["w"])
