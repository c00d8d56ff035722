"""Gauss-Newton SQP and the real-time iteration: QPs from the AD Jacobians of one transcription.

Each iteration evaluates, in one CasADi Function (``linearisation``, built
once, optionally compiled to C): the constraints ``g`` and their Jacobian
``J``, the gradient of the cost and the Gauss-Newton Hessian

    H = J_r^T J_r + hessian(general cost) + regularisation * I,

with ``J_r`` the Jacobian of the least-squares residuals; every derivative and
every sparsity pattern comes from CasADi's AD of the transcription, none is
written by hand.  The QP

    min 0.5 d^T H d + grad^T d   s.t.  lbg - g <= J d <= ubg - g,  lbw - w <= d <= ubw - w

is solved by a CasADi conic solver, warm-started from the previous active
set (and once more cold if that fails).  A QP that no step can satisfy may
be solved once more without the constraints named in ``relax`` (an NMPC
whose measured state no command keeps within a torque or contact limit
still gets a command; the status says ``relaxed (...)``).  ``SQPRoute`` iterates to convergence with a backtracking line search on
the L1 merit function; ``RTIRoute`` takes one full step per call from a warm
start, as real-time NMPC does.
"""

from __future__ import annotations

import threading
import time

import casadi as ca
import numpy as np

from rollbot_oc.core.errors import ConfigError, interruptible
from rollbot_oc.ocp.linearisation import StructuredLinearisation
from rollbot_oc.ocp.solution import OCPSolution
from rollbot_oc.core.reproducible import dot
from rollbot_oc.model.codegen import compiler

__all__ = ["SQPRoute", "RTIRoute"]

INTERIOR_POINT = ("ipopt", "fatrop")  # routes whose multipliers are not an active set


# HPIPM's return flags (hpipm_common.h), which CasADi passes on as numbers
_HPIPM_STATUS = {"0": "success", "1": "maximum iterations", "2": "minimum step length", "3": "NaN in solution",
                 "4": "inconsistent equality constraints"}


def _qp_options(name: str, extra: dict | None) -> dict:
    """Quiet, failure-tolerant options of a CasADi conic plugin, with ``extra`` on top."""
    opts = {"error_on_fail": False}
    if name == "qrqp":
        opts.update(print_iter=False, print_header=False, max_iter=1000)
    elif name == "osqp":
        opts.update(osqp={"verbose": False, "eps_abs": 1e-9, "eps_rel": 1e-9, "max_iter": 20000, "polish": True})
    elif name == "qpoases":
        opts.update(printLevel="none")
    elif name == "hpipm":
        opts.update(hpipm={"iter_max": 100, "mode": "robust"})
    opts.update(extra or {})
    return opts


class _BufferedQP:
    """A CasADi conic solver called through numpy buffers (``Function.buffer``, as ``FastFunction``): the
    Hessian and the constraint Jacobian go in as their nonzeros (``StructuredLinearisation.nonzeros``), so
    no DM is built per call; an input not given takes the solver's default, as in a call by name.  Each call
    binds fresh arrays to a fresh buffer (about 0.05 ms; no state shared between calls or threads): with
    arrays bound once and refilled in place, HPIPM's steps drifted further off with every QP (CasADi 3.8;
    ``tests/test_ocp_layer.py`` compares buffered and named calls)."""

    def __init__(self, conic: ca.Function):
        self.conic = conic
        self._inputs = [(conic.name_in(i), conic.nnz_in(i), conic.default_in(i)) for i in range(conic.n_in())]
        self._outputs = [(conic.name_out(i), conic.nnz_out(i)) for i in range(conic.n_out())]
        self._last = threading.local()

    def __call__(self, **args) -> dict:
        unknown = set(args) - {name for name, _size, _default in self._inputs}
        if unknown:
            raise ValueError(f"QP input(s) {', '.join(sorted(unknown))} unknown to {self.conic.name()}")
        buffer, evaluate = self.conic.buffer()
        arrays = []  # kept alive while the buffer points into them
        for i, (name, size, default) in enumerate(self._inputs):
            value = args.get(name)
            array = np.full(size, default) if value is None else np.array(value, float).ravel()
            if array.size != size:  # a failed QP (as a named call's error), not a crash
                raise RuntimeError(f"QP input {name} has {array.size} values, {self.conic.name()} takes {size}")
            arrays.append(array)
            buffer.set_arg(i, memoryview(array))
        out = {name: np.zeros(size) for name, size in self._outputs}
        for i, array in enumerate(out.values()):
            buffer.set_res(i, memoryview(array))
        evaluate()
        self._last.buffer = buffer
        return out

    def stats(self) -> dict:
        """The statistics of this thread's last call."""
        buffer = getattr(self._last, "buffer", None)
        return buffer.stats() if buffer is not None else {}


class SQPRoute:
    """Gauss-Newton SQP to convergence (see module doc).

    Parameters
    ----------
    transcription : Transcription
    qp_solver : str or tuple of str
        A CasADi conic plugin (``"qrqp"``, ``"osqp"``, ``"hpipm"``, ...), or
        several tried in order on each QP until one solves it.
    max_iter : int
        SQP iterations.
    tol : float
        Converged when the step and the constraint violation are below it.
    regularisation : float
        Multiple of the identity added to the Hessian.
    line_search : bool
        Backtracking on the L1 merit function (off: full steps).
    compiled : bool or None
        Evaluate the linearisation as compiled C (``rollbot_oc.model.codegen``);
        None compiles when a C compiler exists.
    qp_options : dict, optional
        Options of the conic solver.
    """

    name = "sqp"
    single_step = False  # one iteration is a result of its own (RTI), not an unconverged SQP

    def __init__(self, transcription, qp_solver="qrqp", max_iter: int = 100, tol: float = 1e-8,
                 regularisation: float = 1e-8, line_search: bool = True, compiled: bool | None = False,
                 qp_options: dict | None = None):
        names = (qp_solver,) if isinstance(qp_solver, str) else tuple(qp_solver)
        for name in names:
            if not (isinstance(name, str) and ca.has_conic(name)):
                raise ConfigError(f"qp_solver = {name!r} is not a CasADi conic plugin available here")
        if not (isinstance(max_iter, int) and max_iter >= 1):
            raise ConfigError(f"max_iter = {max_iter!r} must be a whole number >= 1")
        self.transcription = tr = transcription
        self.max_iter, self.tol, self.line_search = max_iter, tol, line_search
        if compiled is None:
            compiled = compiler() is not None
        self.linearisation = StructuredLinearisation(tr, regularisation, compiled)
        self.merit = self.linearisation.cost_and_constraints
        self.qp_solver = names[0] if len(names) == 1 else names
        self.qp_feasibility = 1e-6  # largest violation of a QP's constraints that counts as solved
        pattern = {"h": self.linearisation.H_sparsity, "a": self.linearisation.J_sparsity}
        self.qps = [ca.conic(f"ocp_qp_{name}", name, pattern, _qp_options(name, qp_options if i == 0 else None))
                    for i, name in enumerate(names)]
        self.qp = self.qps[0]  # symbolic calls (``to_function``); numeric ones go through buffers
        self._buffered = [_BufferedQP(qp) for qp in self.qps]

    # -- one QP ---------------------------------------------------------------------------------
    def _qp_step(self, w, lam_w, lam_g, par, relax, bounds):
        """The QP at ``w``: returns ``(d, lam_w, lam_g, ok, status, f, g, grad)``; ``relax``: ``(rows of g,
        entries of w)`` whose constraints and bounds are dropped if the QP fails with them; ``bounds``: ``(lbw,
        ubw)`` for ``par`` (``Transcription.bounds``)."""
        tr = self.transcription
        H, grad, g, J, f = self.linearisation.nonzeros(w, par)
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(grad)) and np.all(np.isfinite(J))):
            return None, lam_w, lam_g, False, "non-finite linearisation", float(f), g, None
        lbw, ubw = bounds
        args = dict(h=H, g=grad, a=J, lba=tr.lbg - g, uba=tr.ubg - g, lbx=lbw - w, ubx=ubw - w)
        sol, ok, status = self._solve_qp(args, lam_w, lam_g)
        if not ok and relax is not None and (relax[0].size or relax[1].size):
            rows, columns = relax
            for key, index in (("lba", rows), ("uba", rows), ("lbx", columns), ("ubx", columns)):
                args[key] = np.array(args[key], float)
                args[key][index] = -np.inf if key.startswith("lb") else np.inf
            sol, ok, relaxed = self._solve_qp(args, None, None)
            status = f"relaxed ({status})" if ok else relaxed
        if sol is None:
            return None, lam_w, lam_g, False, status, float(f), g, None
        return (np.array(sol["x"]).ravel(), np.array(sol["lam_x"]).ravel(), np.array(sol["lam_a"]).ravel(), ok,
                status, float(f), g, np.array(grad).ravel())

    def _solve_qp(self, args, lam_w, lam_g):
        """``(solution, ok, status)`` of one QP: by each QP solver in turn, warm-started from ``lam_w, lam_g``
        if given and once more cold if that fails; the first solver's status if none solves it."""
        first = None
        for i, qp in enumerate(self._buffered):
            # the multipliers come from the first solver's previous solution: another solver starts cold (an
            # interior point's small multipliers would read as an active set to an active-set solver)
            sol, ok, status = self._solve_qp_by(qp, args, lam_w if i == 0 else None, lam_g if i == 0 else None)
            if ok:
                return sol, ok, status
            first = first or (sol, ok, status)
        return first

    def _solve_qp_by(self, qp, args, lam_w, lam_g):
        sol, ok, status = None, False, "QP not solved"
        for warm in ((lam_w, lam_g), None) if lam_w is not None else (None,):
            extra = dict(lam_x0=warm[0], lam_a0=warm[1]) if warm is not None else {}
            try:
                with interruptible("QP solve"):
                    sol = qp(**args, **extra)
            except RuntimeError as exc:  # an ill-posed QP is a failed step, not a crash
                sol, ok, status = None, False, f"QP error: {str(exc).splitlines()[-1][:80]}"
                continue
            stats = qp.stats()
            d = np.array(sol["x"]).ravel()
            ok = bool(stats.get("success", False)) and bool(np.all(np.isfinite(d)))
            status = _HPIPM_STATUS.get(str(stats.get("return_status")), str(stats.get("return_status",
                                                                                     "success" if ok else "failed")))
            if ok and self._violation_of(args, d) > self.qp_feasibility:
                # an active-set solver may stop on an infeasible QP and call it a success: checked here
                ok, status = False, "infeasible QP"
            if ok:
                break
        return sol, ok, status

    def _violation_of(self, args, d) -> float:
        """Largest violation of a QP's constraints and bounds by its step ``d``."""
        rows = self.linearisation.J_times(args["a"], d)
        return float(max(np.max(args["lba"] - rows, initial=0.0), np.max(rows - args["uba"], initial=0.0),
                         np.max(args["lbx"] - d, initial=0.0), np.max(d - args["ubx"], initial=0.0)))

    def _violation(self, g) -> float:
        tr = self.transcription
        return float(np.sum(np.maximum(tr.lbg - g, 0.0)) + np.sum(np.maximum(g - tr.ubg, 0.0)))

    # -- iterations -----------------------------------------------------------------------------
    def iterate(self, w, lam_w, lam_g, par, max_iter: int, relax=None, bounds=None):
        """Up to ``max_iter`` SQP iterations from ``w``; returns ``(w, lam_w, lam_g, status, ok, iterations,
        cost)``: ``cost`` at the returned ``w`` where it was evaluated on the way (a converged or failed
        step), at the point the last step was linearised from (real-time iterations), or None (the
        iteration limit reached: ``attempt`` evaluates it then)."""
        bounds = bounds if bounds is not None else self.transcription.bounds(par)
        status, ok, it, f = "max iterations", False, 0, None
        for it in range(1, max_iter + 1):
            d, lw, lg, qp_ok, qp_status, f, g, grad = self._qp_step(w, lam_w, lam_g, par, relax, bounds)
            if not qp_ok:
                return w, lam_w, lam_g, f"QP failed: {qp_status}", False, it, f
            alpha = self._step_length(w, d, grad, lg, f, g, par) if self.line_search else 1.0
            w = np.clip(w + alpha * d, *bounds)  # a QP may overstep a bound a little
            lam_w = lw if lam_w is None else (1 - alpha) * lam_w + alpha * lw
            lam_g = lg if lam_g is None else (1 - alpha) * lam_g + alpha * lg
            if self.single_step and it == max_iter:
                return w, lam_w, lam_g, qp_status, True, it, f  # real time: the last QP's own status
            if np.abs(alpha * d).max(initial=0.0) < self.tol:
                f_new, g_new = self.merit(w, par)
                if self._violation(g_new) < self.tol * max(1, g.size):
                    return w, lam_w, lam_g, "converged", True, it, f_new
        return w, lam_w, lam_g, status, ok, it, None

    def _step_length(self, w, d, grad, lam_g, f, g, par) -> float:
        """Backtracking (Armijo, halving) on the L1 merit ``f + nu * violation``."""
        nu = 1.1 * np.abs(lam_g).max(initial=0.0) + 1e-6
        violation = self._violation(g)
        phi0 = f + nu * violation
        slope = min(dot(grad, d) - nu * violation, 0.0)  # merit's derivative along d
        alpha = 1.0
        for _ in range(16):
            f_new, g_new = self.merit(w + alpha * d, par)
            if f_new + nu * self._violation(g_new) <= phi0 + 1e-4 * alpha * slope:
                return alpha
            alpha *= 0.5
        return alpha

    def _active_multipliers(self, w, lam_w, lam_g, par, tol: float = 1e-6):
        """An interior point's multipliers reduced to the constraints active at ``w`` (the others set to 0).

        An interior point leaves every inequality a small multiplier (about
        ``mu / slack``); an active-set QP solver such as ``qrqp`` reads every
        nonzero multiplier as an active constraint, and that many active rows
        make its first KKT system singular ("Failed to calculate search
        direction").  A row counts as active within ``tol`` of a bound (the
        constraints are scaled to order one); equalities always are.
        """
        tr = self.transcription
        _f, g = self.merit(w, par)

        def keep(value, lower, upper, lam):
            active = (value - lower <= tol) | (upper - value <= tol)
            return np.where(active, lam, 0.0)

        return keep(w, *tr.bounds(par), lam_w), keep(g, tr.lbg, tr.ubg, lam_g)

    # -- the route protocol ---------------------------------------------------------------------
    def solve(self, guess=None, warm: OCPSolution | None = None, **parameters) -> OCPSolution:
        """Iterate to convergence; raises ``NotConverged`` (with the last iterate) if it does not."""
        return self.attempt(guess, warm, **parameters).check()

    def attempt(self, guess=None, warm: OCPSolution | None = None, max_iter: int | None = None,
                multipliers=None, relax=(), **parameters) -> OCPSolution:
        """Iterate and return the last iterate whatever its status (check ``success``).

        Parameters
        ----------
        guess : array_like, optional
            Decision vector to start from (``Transcription.layout.pack``).
        warm : OCPSolution, optional
            A solution to start from, with its multipliers (instead of ``guess``).
        max_iter : int, optional
            Iterations of this call (default: the route's).
        multipliers : (lam_w, lam_g), optional
            Multipliers to warm-start the first QP's active set with ``guess``.
        relax : sequence of str
            Names of constraints dropped from a QP that cannot be solved with them.
        **parameters
            The problem's parameters by name (``p``: the model parameters).
        """
        start = time.perf_counter()  # the whole step: the parameters, bounds and iterations
        tr = self.transcription
        par = tr.parameter_vector(parameters)
        if warm is not None:
            w, lam_w, lam_g = warm.w.copy(), warm.lam_w, warm.lam_g
            if warm.route in INTERIOR_POINT:
                lam_w, lam_g = self._active_multipliers(w, lam_w, lam_g, par)
        else:
            w = tr.default_guess() if guess is None else np.asarray(guess, float).copy()
            lam_w, lam_g = multipliers if multipliers is not None else (None, None)
        bounds = tr.bounds(par)
        w = np.clip(w, *bounds)
        rows = self._relaxed_rows(tuple(relax))
        w, lam_w, lam_g, status, ok, it, f = self.iterate(w, lam_w, lam_g, par, max_iter or self.max_iter, rows,
                                                          bounds)
        elapsed = time.perf_counter() - start
        if f is None:
            f, _g = self.merit(w, par)
        lam_w = np.zeros(w.size) if lam_w is None else lam_w
        lam_g = np.zeros(tr.lbg.size) if lam_g is None else lam_g
        return OCPSolution(self.name, status, ok, it, elapsed, float(f), w, lam_w, lam_g, par, tr)

    def _relaxed_rows(self, names: tuple):
        """``(rows of g, entries of w)`` of the constraints named ``names`` (rows, or simple bounds)."""
        if not names:
            return None
        cache = self.__dict__.setdefault("_relax_cache", {})
        if names not in cache:
            tr = self.transcription
            cache[names] = (np.concatenate([tr.rows_of(name) for name in names]).astype(int),
                            np.concatenate([tr.columns_of(name) for name in names]).astype(int))
        return cache[names]

    def to_function(self, relax=()) -> ca.Function:
        """One full SQP step as a CasADi Function ``(w, lam_w, lam_g, par) -> (w, lam_w, lam_g, violation,
        relaxed)``.

        As an iteration of ``iterate`` without line search: ``w`` clipped to its bounds, the QP there
        (warm-started from ``lam_w, lam_g``), the full step, clipped again; ``violation`` is the largest
        violation of the QP's constraints and bounds by its step (``_violation_of``: an active-set solver
        may stop on an infeasible QP).  If that exceeds ``qp_feasibility`` and ``relax`` names
        constraints, the QP is solved once more, cold, without them (``relaxed`` is then 1, and
        ``violation`` that of the relaxed QP), as ``_qp_step`` does.  The QP solver is inside the Function
        and the linearisation is the structured one (``StructuredLinearisation.symbolic``: the stage
        Functions mapped, not expanded), so the step can be generated as compact C (a route built with
        ``compiled=False``).
        """
        tr = self.transcription
        n, m = tr.w.numel(), tr.g.numel()
        w, lw, lg, par = ca.MX.sym("w", n), ca.MX.sym("lam_w", n), ca.MX.sym("lam_g", m), ca.MX.sym("par",
                                                                                                   tr.par.numel())
        lbw, ubw = tr.bounds_symbolic(par)
        w0 = ca.fmin(ca.fmax(w, lbw), ubw)
        H, grad, g, J, _f = self.linearisation.symbolic(w0, par)
        args = dict(h=H, g=grad, a=J, lba=tr.lbg - g, uba=tr.ubg - g, lbx=lbw - w0, ubx=ubw - w0)

        def violation_of(a, d):
            rows = ca.mtimes(J, d)
            return ca.mmax(ca.vertcat(a["lba"] - rows, rows - a["uba"], a["lbx"] - d, d - a["ubx"], 0))

        sol = self.qp(**args, lam_x0=lw, lam_a0=lg)
        d, lam_x, lam_a = sol["x"], sol["lam_x"], sol["lam_a"]
        violation, relaxed = violation_of(args, d), ca.MX(0)
        rows, columns = self._relaxed_rows(tuple(relax)) or (np.zeros(0, int), np.zeros(0, int))
        if rows.size or columns.size:
            loose = dict(args)
            for key, index, size in (("lba", rows, m), ("uba", rows, m), ("lbx", columns, n), ("ubx", columns, n)):
                mask = np.zeros(size)
                mask[index] = 1.0
                loose[key] = ca.if_else(ca.DM(mask), ca.DM.ones(size) * (-np.inf if key.startswith("lb") else np.inf),
                                        args[key])
            names = list(loose)
            inputs = [ca.MX.sym(name, args[name].sparsity()) for name in names]
            qp = self.qp(**dict(zip(names, inputs)))
            again = ca.Function("ocp_qp_relaxed", inputs, [qp["x"], qp["lam_x"], qp["lam_a"]])
            skip = ca.Function("ocp_qp_kept", inputs, [ca.MX.zeros(n), ca.MX.zeros(n), ca.MX.zeros(m)])
            relaxed = violation > self.qp_feasibility
            d2, lam_x2, lam_a2 = ca.Function.conditional("ocp_qp_relax_if", [skip], again)(
                relaxed, *[loose[name] for name in names])
            d, lam_x, lam_a = (ca.if_else(relaxed, a, b) for a, b in ((d2, d), (lam_x2, lam_x), (lam_a2, lam_a)))
            violation = ca.if_else(relaxed, violation_of(loose, d2), violation)
        return ca.Function("ocp_sqp_step", [w, lw, lg, par],
                           [ca.fmin(ca.fmax(w0 + d, lbw), ubw), lam_x, lam_a, violation, relaxed],
                           ["w", "lam_w", "lam_g", "par"], ["w_next", "lam_w_next", "lam_g_next", "violation",
                                                            "relaxed"])


class RTIRoute(SQPRoute):
    """The real-time iteration: one full Gauss-Newton SQP step per call, from a warm start.

    ``solve``/``attempt`` take ``max_iter`` (default 1) steps; a step whose QP
    fails is reported with the QP's status.  The solution's ``cost`` is the
    objective where the last step was linearised (a real-time iteration
    evaluates the problem once), and its ``solve_time`` the whole call.
    """

    name = "rti"
    single_step = True

    def __init__(self, transcription, qp_solver: str = "qrqp", iterations: int = 1, **options):
        options.setdefault("line_search", False)
        super().__init__(transcription, qp_solver, max_iter=iterations, **options)
