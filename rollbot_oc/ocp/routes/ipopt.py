"""The IPOPT route: interior point to convergence."""

from __future__ import annotations

import time

import casadi as ca
import numpy as np

from rollbot_oc.core.errors import ConfigError, interruptible
from rollbot_oc.ocp.solution import OCPSolution

__all__ = ["NLPRoute", "IpoptRoute", "nlp_solution", "call_nlp"]

def nlp_solution(route: str, solver: ca.Function, transcription, sol, par, elapsed: float) -> OCPSolution:
    """An ``OCPSolution`` from an ``nlpsol`` result and its stats."""
    stats = solver.stats()
    status = str(stats.get("return_status", "unknown"))
    w = np.array(sol["x"]).ravel()
    success = bool(stats.get("success", False)) and bool(np.all(np.isfinite(w)))
    return OCPSolution(route, status, success, int(stats.get("iter_count", 0)), elapsed, float(sol["f"]), w,
                       np.array(sol["lam_x"]).ravel(), np.array(sol["lam_g"]).ravel(), par, transcription)


def call_nlp(solver, args: dict):
    """Call an ``nlpsol`` Function; a Ctrl-C inside the solver becomes ``Interrupted``, not a failed solve."""
    with interruptible("optimal-control solve"):
        return solver(**args)


class NLPRoute:
    """A route through a CasADi ``nlpsol`` built on the transcription (subclasses set ``solver``)."""

    name = "nlp"
    transcription = None
    solver: ca.Function = None

    def solve(self, guess=None, warm: OCPSolution | None = None, **parameters) -> OCPSolution:
        """Solve to convergence; raises ``NotConverged`` (with the failed solution) if it does not."""
        return self.attempt(guess, warm, **parameters).check()

    def attempt(self, guess=None, warm: OCPSolution | None = None, multipliers=None, **parameters) -> OCPSolution:
        """Solve and return the solution whatever its status (check ``success``).

        ``guess``: a decision vector to start from, with ``multipliers = (lam_w, lam_g)`` if given;
        ``warm``: a solution to start from (its multipliers too); ``parameters``: by name.
        """
        tr = self.transcription
        par = tr.parameter_vector(parameters)
        lbw, ubw = tr.bounds(par)
        args = dict(p=par, lbx=lbw, ubx=ubw, lbg=tr.lbg, ubg=tr.ubg)
        if warm is not None:
            args.update(x0=warm.w, lam_x0=warm.lam_w, lam_g0=warm.lam_g)
        else:
            args["x0"] = tr.default_guess() if guess is None else np.asarray(guess, float)
            if multipliers is not None and multipliers[0] is not None:
                args.update(lam_x0=multipliers[0], lam_g0=multipliers[1])
        start = time.perf_counter()
        sol = call_nlp(self.solver, args)
        return nlp_solution(self.name, self.solver, tr, sol, par, time.perf_counter() - start)

    def to_function(self) -> ca.Function:
        """``(w_guess, par) -> w``: the solve as a CasADi Function."""
        tr = self.transcription
        w0, par = ca.MX.sym("w0", tr.w.numel()), ca.MX.sym("par", tr.par.numel())
        lbw, ubw = tr.bounds_symbolic(par)
        sol = self.solver(x0=w0, p=par, lbx=lbw, ubx=ubw, lbg=tr.lbg, ubg=tr.ubg)
        return ca.Function(f"ocp_{self.name}_solve", [w0, par], [sol["x"]], ["w0", "par"], ["w"])


class IpoptRoute(NLPRoute):
    """IPOPT on the transcription (see ``rollbot_oc.ocp.routes``).

    Parameters
    ----------
    transcription : Transcription
    hessian : {"exact", "limited-memory"}
        The Hessian of the Lagrangian: exact by AD, or quasi-Newton.
    max_iter : int
    tol : float
        IPOPT's convergence tolerance.
    options : dict, optional
        Further IPOPT options.
    compiled : bool
        Evaluate the stages and their Jacobians as compiled C
        (``Transcription.nlp``); needs the limited-memory Hessian.
    expand : bool
        Expand the NLP into scalar expressions (slower to build, faster to solve).
    """

    name = "ipopt"

    def __init__(self, transcription, hessian: str = "exact", max_iter: int = 500, tol: float = 1e-8,
                 options: dict | None = None, compiled: bool = False, expand: bool = False):
        if hessian not in ("exact", "limited-memory"):
            raise ConfigError(f"ipopt hessian = {hessian!r}; valid are 'exact', 'limited-memory'")
        if compiled and hessian == "exact":
            raise ConfigError("ipopt compiled = True gives first derivatives only: use hessian = 'limited-memory'")
        self.transcription = tr = transcription
        ipopt = {"print_level": 0, "sb": "yes", "max_iter": max_iter, "tol": tol, "acceptable_tol": 1e-6,
                 "hessian_approximation": hessian, **(options or {})}
        f, g = (tr.nlp(compiled=True)[:2]) if compiled else (tr.f, tr.g)
        nlp = {"x": tr.w, "p": tr.par, "f": f, "g": g}
        self.solver = ca.nlpsol("ocp_ipopt", "ipopt", nlp, {"ipopt": ipopt, "print_time": False,
                                                            "expand": expand and not compiled})
