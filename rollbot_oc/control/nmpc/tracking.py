"""The NMPC's tracking problem and its solvers: IPOPT to convergence, or real-time iterations."""

from __future__ import annotations

import functools
import time

import casadi as ca
import numpy as np

from rollbot_oc.codegen import compiled, compiler
from rollbot_oc.control.nmpc.settings import NMPCSettings, TrackingWeights
from rollbot_oc.control.ocp import NP, interval_function, stage_function
from rollbot_oc.dynamics import NZ, reduced_model
from rollbot_oc.errors import interruptible
from rollbot_oc.params import ParamView, RollbotParams

__all__ = ["TrackingSolver", "RTISolver"]


class TrackingSolver:
    """The tracking NLP of the NMPC solved to convergence by IPOPT (exact Hessian), built once.

    Parameters of each solve: the initial reduced state, the reference states
    (10, N+1) and accelerations (N,), the model parameter vector and the
    target circle.  ``RTISolver`` solves the same problem by real-time iterations.
    """

    def __init__(self, params: RollbotParams, settings: NMPCSettings, weights: TrackingWeights):
        s = self.settings = settings
        self.params = params
        N = s.N
        stage = stage_function(s.substeps, s.friction_margin).map(N)
        Z, U = ca.MX.sym("Z", NZ, N + 1), ca.MX.sym("U", 1, N)
        z0, Zr, Ur, p = ca.MX.sym("z0", NZ), ca.MX.sym("Zr", NZ, N + 1), ca.MX.sym("Ur", 1, N), ca.MX.sym("p", NP)
        gs = stage(Z[:, :-1], U, Z[:, 1:], s.h, p)
        weight = params.total_mass * params.g
        tau = s.torque_margin * params.max_torque
        g = ca.vertcat(Z[:, 0] - z0, ca.vec(gs))
        self.lbg = np.concatenate([np.zeros(NZ), np.tile(np.concatenate([np.zeros(NZ), [-tau, s.normal_margin * weight,
                                                                                          0.0]]), N)])
        self.ubg = np.concatenate([np.zeros(NZ), np.tile(np.concatenate([np.zeros(NZ), [tau, np.inf, np.inf]]), N)])
        self._path_rows = np.concatenate([np.zeros(NZ, bool), np.tile(np.arange(13) >= NZ, N)])
        # least-squares tracking residuals (Gauss-Newton friendly); the square roots of the weights are
        # a parameter of each solve
        self.diag = weights.diagonal(N)
        root = ca.MX.sym("root", NZ * (N + 1) + N)
        res_state = (Z - Zr) * ca.reshape(root[:NZ * (N + 1)], NZ, N + 1)
        res_input = (U - Ur) * root[NZ * (N + 1):].T
        # circles: the distance from the target circle (only its radial part matters for the mission)
        circle = ca.MX.sym("circle", 3 + N + 1)  # centre (2), radius, square root of each node's weight
        offsets = Z[0:2, :] - ca.repmat(circle[0:2], 1, N + 1)
        radial = circle[3:].T * (ca.sqrt(ca.sum1(offsets**2) + 1e-9) - circle[2])
        residual = ca.vertcat(ca.vec(res_state), ca.vec(res_input), ca.vec(radial))
        x = ca.vertcat(ca.vec(Z), ca.vec(U))
        n = x.shape[0]
        self.lbx, self.ubx = np.full(n, -np.inf), np.full(n, np.inf)
        speed = 0.98 * params.max_speed
        self.lbx[9:NZ * (N + 1):NZ], self.ubx[9:NZ * (N + 1):NZ] = -speed, speed
        self.lbx[NZ * (N + 1):], self.ubx[NZ * (N + 1):] = -params.max_accel, params.max_accel
        par = ca.vertcat(z0, ca.vec(Zr), ca.vec(Ur), p, circle, root)
        self.n_x, self.n_g = n, g.shape[0]
        nlp = {"x": x, "p": par, "f": 0.5 * ca.sumsqr(residual), "g": g}
        opts = {"ipopt": {"print_level": 0, "sb": "yes", "max_iter": 50, "tol": 1e-6,
                          "warm_start_init_point": "yes", "warm_start_bound_push": 1e-6,
                          "warm_start_mult_bound_push": 1e-6, "mu_init": 1e-4},
                "print_time": False}
        self.nlp = ca.nlpsol("nmpc_ipopt", "ipopt", nlp, opts)

    def solve(self, z0, Zr, Ur, p, warm=None, circle=None, diag=None):
        """Solve from ``warm``; returns ``(x, lam, status, success, seconds)``.

        ``circle = (centre (2,), radius, weights (N+1,))`` adds each node's squared distance from a
        target circle, weighted, to the tracking cost (m, 1/m^2).  ``diag``: the tracking weights of
        every decision variable (``TrackingWeights.diagonal``), else those the solver was built with.
        """
        if circle is None:
            circle = (np.zeros(2), 1.0, np.zeros(self.settings.N + 1))
        centre, radius, node_weights = circle
        c = np.concatenate([centre, [radius], np.sqrt(node_weights)])
        root = np.sqrt(self.diag if diag is None else diag)
        par = np.concatenate([z0, np.asarray(Zr).T.ravel(), np.ravel(Ur), p, c, root])
        x_warm, lam_x, lam_g = warm if warm is not None else (None, None, None)
        if x_warm is None:
            x_warm = np.concatenate([np.asarray(Zr).T.ravel(), np.ravel(Ur)])
            x_warm[:NZ] = z0
        start = time.perf_counter()
        args = dict(x0=x_warm, p=par, lbx=self.lbx, ubx=self.ubx, lbg=self.lbg, ubg=self.ubg)
        if lam_x is not None:
            args.update(lam_x0=lam_x, lam_g0=lam_g)
        try:
            with interruptible("NMPC solve"):
                sol = self.nlp(**args)
        except RuntimeError as exc:  # a failed solve, never a crash of the loop
            return x_warm, (lam_x, lam_g), f"error: {str(exc)[:60]}", False, time.perf_counter() - start
        seconds = time.perf_counter() - start
        stats = self.nlp.stats()
        status = str(stats["return_status"])
        x = np.array(sol["x"]).ravel()
        ok = (bool(stats["success"]) or status == "Solved_To_Acceptable_Level") and bool(np.all(np.isfinite(x)))
        return x, (np.array(sol["lam_x"]).ravel(), np.array(sol["lam_g"]).ravel()), status, ok, seconds

    def split(self, x):
        """``(Z (10, N+1), U (N,))`` of a solution vector."""
        N = self.settings.N
        return x[:NZ * (N + 1)].reshape(N + 1, NZ).T, x[NZ * (N + 1):]

    def modelled_time(self) -> float:
        """Modelled compute time of the last solve: its IPOPT iterations times ``ipopt_iteration_time``, s."""
        return self.nlp.stats().get("iter_count", 0) * self.settings.ipopt_iteration_time


@functools.lru_cache(maxsize=None)
def _stage_linearisation(substeps: int, friction_margin: float, h: float) -> ca.Function:
    """``(z, u, p) -> (F, path, dF/d(z,u), dpath/d(z,u))`` of one interval: the end state, the path
    constraints and their Jacobians by AD.

    The path constraints are scaled to be dimensionless and of order one (an active-set QP solver
    needs that): motor torque over the torque limit, normal force over the weight, and the friction
    slack over the squared weight.
    """
    red, F = reduced_model(), interval_function(substeps)
    z, u, p = ca.SX.sym("z", NZ), ca.SX.sym("u"), ca.SX.sym("p", NP)
    P = ParamView(p)
    zu = ca.vertcat(z, u)
    end = F(z, u, h, p)
    N = red.reaction(z, u, p, ca.DM.zeros(6))
    weight = P.weight
    slack = ((friction_margin * P.mu * N[2]) ** 2 - N[0] ** 2 - N[1] ** 2) / weight**2
    path = ca.vertcat(red.motor_torque(z, u, p, ca.DM.zeros(6)) / P.max_torque, N[2] / weight, slack)
    return ca.Function("stage_linearisation", [z, u, p], [end, path, ca.jacobian(end, zu), ca.jacobian(path, zu)])


class RTISolver:
    """The NMPC's tracking problem solved by real-time iterations (Gauss-Newton SQP), built once.

    Each call takes ``iterations`` SQP steps from the warm start (one, the
    real-time iteration, by default).  A step linearises every interval with
    one mapped CasADi call (RK4 end state, path constraints and their AD
    Jacobians), assembles the structured QP in numpy on a fixed sparsity
    (Gauss-Newton Hessian of the least-squares tracking cost: diagonal, plus a
    2x2 block per node for the distance from a target circle), and solves it
    with CasADi's active-set ``qrqp``.

    Parameters
    ----------
    params : RollbotParams
        The robot the controller believes in (for the limits).
    settings : NMPCSettings
    iterations : int
        SQP steps per call.
    """

    def __init__(self, params: RollbotParams, settings: NMPCSettings, weights: TrackingWeights, iterations: int = 1):
        s = self.settings = settings
        self.params, self.iterations = params, iterations
        N = s.N
        stage = _stage_linearisation(s.substeps, s.friction_margin, s.h)
        use_c = s.compiled if s.compiled is not None else compiler() is not None
        self.stages = (compiled(stage) if use_c else stage).map(N)
        self.compiled = use_c
        self.n_x = NZ * (N + 1) + N
        self.n_g = NZ + 13 * N
        tau = s.torque_margin  # the path constraints are scaled (see _stage_linearisation)
        stage_lower = np.concatenate([np.zeros(NZ), [-tau, s.normal_margin, 0.0]])
        self.lbg = np.concatenate([np.zeros(NZ), np.tile(stage_lower, N)])
        self.ubg = np.concatenate([np.zeros(NZ), np.tile(np.concatenate([np.zeros(NZ), [tau, np.inf, np.inf]]), N)])
        self._path_rows = np.concatenate([np.zeros(NZ, bool), np.tile(np.arange(13) >= NZ, N)])
        self.lbx, self.ubx = np.full(self.n_x, -np.inf), np.full(self.n_x, np.inf)
        speed = 0.98 * params.max_speed
        self.lbx[9:NZ * (N + 1):NZ], self.ubx[9:NZ * (N + 1):NZ] = -speed, speed
        self.lbx[NZ * (N + 1):], self.ubx[NZ * (N + 1):] = -params.max_accel, params.max_accel
        self.diag = weights.diagonal(N)  # Gauss-Newton weights of the tracking residuals
        self._build_patterns()

    def _build_patterns(self):
        """Fixed sparsity of the QP's Hessian and constraint matrix, and where each Jacobian entry goes."""
        N, iu = self.settings.N, NZ * (self.settings.N + 1)
        rows, cols = list(range(NZ)), list(range(NZ))  # z_0 - z_meas
        for k in range(N):
            r0 = NZ + 13 * k
            for i in range(13):  # d/d(z_k, u_k): gap rows carry -dF, path rows dpath
                rows += [r0 + i] * (NZ + 1)
                cols += list(range(NZ * k, NZ * k + NZ)) + [iu + k]
            rows += list(range(r0, r0 + NZ))  # d gap / d z_{k+1} = I
            cols += list(range(NZ * (k + 1), NZ * (k + 2)))
        A = _csc(rows, cols, self.n_g, self.n_x)
        self.A_sparsity, self.A_order = A
        hr, hc = list(range(self.n_x)), list(range(self.n_x))
        for k in range(N + 1):  # the 2x2 position block of each node (circle term)
            hr += [NZ * k, NZ * k + 1]
            hc += [NZ * k + 1, NZ * k]
        self.H_sparsity, self.H_order = _csc(hr, hc, self.n_x, self.n_x)
        self.qp = ca.conic("nmpc_qp", "qrqp", {"h": self.H_sparsity, "a": self.A_sparsity},
                           {"print_iter": False, "print_header": False, "error_on_fail": False, "max_iter": 150})

    def _qp_data(self, x, z0, Zr, Ur, p, circle, diag):
        N = self.settings.N
        Z = x[:NZ * (N + 1)].reshape(N + 1, NZ).T
        U = x[NZ * (N + 1):]
        end, path, J_end, J_path = (np.array(v) for v in self.stages(Z[:, :-1], U[None, :], p))
        gap = Z[:, 1:] - end
        g = np.concatenate([Z[:, 0] - z0, np.vstack([gap, path]).T.ravel()])
        # per stage: the 13 x 11 block on (z_k, u_k) (gap rows -dF, path rows dpath), row by row,
        # then the identity of the gap on z_{k+1}
        blocks = np.vstack([-J_end, J_path])
        stage_blocks = blocks.reshape(13, N, NZ + 1).transpose(1, 0, 2).reshape(N, -1)
        data = np.concatenate([np.ones(NZ), np.hstack([stage_blocks, np.ones((N, NZ))]).ravel()])
        A = ca.DM(self.A_sparsity, data[self.A_order])
        # Gauss-Newton cost: diagonal tracking part plus the circle's radial residuals
        xref = np.concatenate([np.asarray(Zr).T.ravel(), np.ravel(Ur)])
        diff = x - xref
        grad = diag * diff
        hdiag = diag.copy()
        offdiag = np.zeros(N + 1)
        if circle is not None and np.any(circle[2] > 0):
            centre, radius, w_r = circle
            rel = Z[0:2] - np.asarray(centre, float)[:, None]
            dist = np.maximum(np.hypot(rel[0], rel[1]), 1e-9)
            n = rel / dist
            res = dist - radius
            idx = NZ * np.arange(N + 1)
            grad[idx] += w_r * res * n[0]
            grad[idx + 1] += w_r * res * n[1]
            hdiag[idx] += w_r * n[0] ** 2
            hdiag[idx + 1] += w_r * n[1] ** 2
            offdiag = w_r * n[0] * n[1]
        H = ca.DM(self.H_sparsity, np.concatenate([hdiag, np.repeat(offdiag, 2)])[self.H_order])
        return H, grad, g, A

    def solve(self, z0, Zr, Ur, p, warm=None, circle=None, diag=None):
        """``iterations`` SQP steps from ``warm``; returns ``(x, lam, status, success, seconds)``.

        ``circle``, ``diag``: as for ``TrackingSolver.solve``.
        """
        diag = self.diag if diag is None else diag
        x, lam_x, lam_g = warm if warm is not None else (None, None, None)
        if x is None:
            x = np.concatenate([np.asarray(Zr).T.ravel(), np.ravel(Ur)])
            x[:NZ] = z0
        start = time.perf_counter()
        ok, status = True, "success"
        for _ in range(self.iterations):
            H, grad, g, A = self._qp_data(x, np.asarray(z0, float), Zr, Ur, p, circle, diag)
            if not (np.all(np.isfinite(g)) and np.all(np.isfinite(grad)) and np.all(np.isfinite(A.nonzeros()))):
                ok, status = False, "non-finite linearisation"
                break
            args = dict(h=H, g=grad, a=A, lba=self.lbg - g, uba=self.ubg - g, lbx=self.lbx - x, ubx=self.ubx - x)
            sol, ok = self._qp(args, lam_x, lam_g)
            stats = self.qp.stats() if sol is not None else {"return_status": "QP error"}
            status = str(stats.get("return_status", "success" if ok else "failed"))
            if not ok:  # e.g. a state no command keeps within the torque or contact limits: without them
                args.update(lba=np.where(self._path_rows, -np.inf, args["lba"]),
                            uba=np.where(self._path_rows, np.inf, args["uba"]))
                sol, ok = self._qp(args, None, None)
                status = f"relaxed ({status})" if ok else status
            if not ok:
                break
            x = np.clip(x + np.array(sol["x"]).ravel(), self.lbx, self.ubx)  # qrqp may overstep a bound a little
            lam_x, lam_g = np.array(sol["lam_x"]).ravel(), np.array(sol["lam_a"]).ravel()
        seconds = time.perf_counter() - start
        return x, (lam_x, lam_g), status, ok and bool(np.all(np.isfinite(x))), seconds

    def _qp(self, args, lam_x, lam_g):
        """Solve the QP warm-started from the previous active set; once more cold if that fails."""
        try:
            with interruptible("NMPC solve"):
                if lam_x is not None:
                    sol = self.qp(**args, lam_x0=lam_x, lam_a0=lam_g)
                    if self.qp.stats()["success"]:
                        return sol, True
                sol = self.qp(**args)
        except RuntimeError:  # an ill-posed QP is a failed solve, never a crash of the loop
            return None, False
        return sol, bool(self.qp.stats()["success"])

    def split(self, x):
        """``(Z (10, N+1), U (N,))`` of a solution vector."""
        N = self.settings.N
        return x[:NZ * (N + 1)].reshape(N + 1, NZ).T, x[NZ * (N + 1):]

    def modelled_time(self) -> float:
        """Modelled compute time of a solve: ``iterations`` RTI steps of ``rti_step_time``, s."""
        return self.iterations * self.settings.rti_step_time


def _csc(rows, cols, n_rows, n_cols):
    """A CasADi sparsity from coordinate lists, and the permutation from coordinate to column-major order."""
    rows, cols = np.asarray(rows), np.asarray(cols)
    order = np.lexsort((rows, cols))
    sp = ca.Sparsity.triplet(n_rows, n_cols, rows.tolist(), cols.tolist())
    if sp.nnz() != len(rows):
        raise ValueError("duplicate entries in a QP sparsity pattern")
    return sp, order
