"""Direct multiple shooting: an ``OCP`` becomes one structured NLP that every route solves.

Decision vector ``w``, ordered stage by stage (what structure-exploiting
solvers need): for each interval ``k`` the state at its start ``x_k``, the
duration ``tau_k`` of its phase (only when some phase has a free duration),
its control ``u_k`` and the slacks of its soft path constraints; then the last
state ``x_N`` and ``tau_N``; then the global entries: the problem's variables
and the slacks of soft node constraints.  A free duration is carried from
node to node (``tau_{k+1} = tau_k`` inside a phase) rather than kept as one
global entry: a global entry would couple every stage and fill the QPs'
factorisations, the node-wise copy keeps them banded.

Per interval (one SX Function, mapped over all intervals, so the NLP stays
small and its derivatives keep the stage structure): the continuity gap
``x_{k+1} - F(x_k, u_k, h_k)`` with ``F`` the model's RK4 over the interval
``h_k = T_phase / N_phase``, the path constraints, the general cost
``h_k l(x_k, u_k)`` and the least-squares residuals ``sqrt(h_k) r(x_k, u_k)``.
Node terms (start, end of a phase, a node index) are evaluated where they
apply.  The cost is

    f = time_weight * sum(T) + general terms + 0.5 |residuals|^2 + soft penalties,

and ``general`` (everything but the least squares) and ``residuals`` are also
kept apart for the Gauss-Newton routes.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from rollbot_oc.errors import ConfigError
from rollbot_oc.ocp.problem import OCP, Constraint, FreeTime

__all__ = ["Transcription", "Layout"]


@dataclass(frozen=True)
class Layout:
    """Where each part of the problem sits in ``w`` and in the parameter vector.

    Attributes
    ----------
    nx, nt, nu, n_soft_path : int
        Sizes per stage: states, phase duration (1 if some phase is free, else
        0), controls, slacks of soft path constraints.
    N : tuple of int
        Intervals per phase.
    durations : tuple
        Each phase's duration: a number (fixed) or ``FreeTime``.
    variables : dict
        Name -> slice in ``w``.
    node_slacks : slice
        Slacks of soft node constraints in ``w``.
    parameters : dict
        Name -> slice of the parameter vector (``"p"`` first: the model parameters).
    """

    nx: int
    nt: int
    nu: int
    n_soft_path: int
    N: tuple
    durations: tuple
    variables: dict
    node_slacks: slice
    parameters: dict

    @property
    def stage(self) -> int:
        """Length of one interval's block ``(x_k, tau_k, u_k, s_k)``."""
        return self.nx + self.nt + self.nu + self.n_soft_path

    @property
    def intervals(self) -> int:
        """Intervals over all phases."""
        return sum(self.N)

    @property
    def first_nodes(self) -> np.ndarray:
        """Index of each phase's first node."""
        return np.concatenate([[0], np.cumsum(self.N)[:-1]]).astype(int)

    @property
    def size(self) -> int:
        """Length of ``w``."""
        return self.node_slacks.stop

    def _blocks(self, w) -> np.ndarray:
        n = self.intervals
        return np.asarray(w, float)[:n * self.stage].reshape(n, self.stage)

    def _last(self, w) -> np.ndarray:
        n = self.intervals
        return np.asarray(w, float)[n * self.stage:n * self.stage + self.nx + self.nt]

    def states(self, w) -> np.ndarray:
        """States (nx, intervals + 1) of a decision vector."""
        return np.vstack([self._blocks(w)[:, :self.nx], self._last(w)[:self.nx]]).T

    def controls(self, w) -> np.ndarray:
        """Controls (nu, intervals) of a decision vector."""
        return self._blocks(w)[:, self.nx + self.nt:self.nx + self.nt + self.nu].T

    def phase_durations(self, w) -> np.ndarray:
        """Duration of each phase (s) in a decision vector."""
        if not self.nt:
            return np.array([float(t) for t in self.durations])
        tau = self._blocks(w)[:, self.nx]
        return tau[self.first_nodes].copy()

    def pack(self, states, controls, durations=None, variables=None, template=None) -> np.ndarray:
        """A decision vector from states (nx, N+1), controls (nu, N), phase durations (s) and variables.

        Entries not given (slacks, unspecified variables) come from ``template``
        (e.g. ``Transcription.default_guess()``) or are zero.
        """
        n = self.intervals
        w = np.zeros(self.size) if template is None else np.array(template, float)
        states = np.asarray(states, float)
        controls = np.asarray(controls, float).reshape(self.nu, n)
        blocks = w[:n * self.stage].reshape(n, self.stage)
        blocks[:, :self.nx] = states[:, :-1].T
        blocks[:, self.nx + self.nt:self.nx + self.nt + self.nu] = controls.T
        last = n * self.stage
        w[last:last + self.nx] = states[:, -1]
        if self.nt and durations is not None:
            tau = np.repeat(np.ravel(durations).astype(float), self.N)
            blocks[:, self.nx] = tau
            w[last + self.nx] = tau[-1]
        w[:n * self.stage] = blocks.ravel()
        for name, value in (variables or {}).items():
            w[self.variables[name]] = value
        return w


class Transcription:
    """The NLP of an ``OCP`` by direct multiple shooting (see module doc), built once.

    Attributes
    ----------
    ocp : OCP
    layout : Layout
    w, par : casadi.MX
        Decision vector and parameter vector symbols.
    f, general, residuals, g : casadi.MX
        Cost, its non-least-squares part, the least-squares residuals, the constraints.
    lbg, ubg, lbw, ubw : numpy.ndarray
        Bounds of ``g`` and ``w``.
    """

    def __init__(self, ocp: OCP):
        self.ocp = ocp
        m = ocp.model
        nx, nu = m.nx, m.nu
        path = [c for c, at in ocp.constraints if at == "path"]
        hard_path = [c for c in path if c.soft is None]
        soft_path = [c for c in path if c.soft is not None]
        n_soft_path = sum(c.expr.numel() for c in soft_path)
        nt = int(any(isinstance(t, FreeTime) for t in ocp.durations))
        n = sum(ocp.N)
        stage = nx + nt + nu + n_soft_path
        cursor = n * stage + nx + nt
        variables = {}
        for name, (sym, *_rest) in ocp.variables.items():
            variables[name] = slice(cursor, cursor + sym.numel())
            cursor += sym.numel()
        node_soft = [(c, at) for c, at in ocp.constraints if at != "path" and c.soft is not None]
        node_slacks = slice(cursor, cursor + sum(c.expr.numel() for c, _ in node_soft))
        params = {"p": slice(0, m.np)}
        offset = m.np
        for name, sym in ocp.parameters.items():
            params[name] = slice(offset, offset + sym.numel())
            offset += sym.numel()
        self.layout = L = Layout(nx, nt, nu, n_soft_path, tuple(ocp.N), tuple(ocp.durations), variables,
                                 node_slacks, params)

        # -- symbols ---------------------------------------------------------------------------
        w = ca.MX.sym("w", L.size)
        par = ca.MX.sym("par", offset)
        blocks = ca.reshape(w[:n * stage], stage, n)
        last = w[n * stage:n * stage + nx + nt]
        X = ca.horzcat(blocks[:nx, :], last[:nx])
        U = blocks[nx + nt:nx + nt + nu, :]
        S = blocks[nx + nt + nu:, :]
        per_interval = np.concatenate([np.full(Ni, 1.0 / Ni) for Ni in ocp.N])
        phase_of = np.repeat(np.arange(len(ocp.N)), ocp.N)
        firsts = L.first_nodes
        if nt:
            TAU = ca.horzcat(blocks[nx, :], last[nx])
            h = TAU[:, :-1] * ca.DM(per_interval).T
            durations = ca.vertcat(*[TAU[0, int(k)] for k in firsts])
        else:
            durations = ca.DM([float(t) for t in ocp.durations])
            h = ca.DM(np.array([float(ocp.durations[i]) for i in phase_of]) * per_interval).T
        p = par[params["p"]]
        q = ca.vertcat(*[par[params[name]] for name in ocp.parameters]) if ocp.parameters else ca.MX(0, 1)
        v = ca.vertcat(*[w[variables[name]] for name in ocp.variables]) if ocp.variables else ca.MX(0, 1)

        # -- one SX Function per interval, mapped ----------------------------------------------
        qs = ca.vertcat(*ocp.parameters.values()) if ocp.parameters else ca.SX(0, 1)
        vs = ca.vertcat(*[sym for sym, *_ in ocp.variables.values()]) if ocp.variables else ca.SX(0, 1)
        xs, us, ps = ocp.x, ocp.u, ocp.p
        xn, hs = ca.SX.sym("x_next", nx), ca.SX.sym("h")
        ss = ca.SX.sym("s", n_soft_path)
        gap = xn - m.interval(ocp.substeps)(xs, us, hs, ps)
        hard = ca.vertcat(*[c.expr for c in hard_path]) if hard_path else ca.SX(0, 1)
        soft_rows, soft_lb, soft_ub, soft_cost, soft_res = _soft_rows(soft_path, ss)
        general_path = sum((e for kind, e, at in ocp.costs if kind == "general" and at == "path"), ca.SX(0))
        lsq_path = [e for kind, e, at in ocp.costs if kind == "lsq" and at == "path"]
        res_path = ca.sqrt(hs) * ca.vertcat(*lsq_path) if lsq_path else ca.SX(0, 1)
        interval = ca.Function("interval", [xs, us, xn, hs, ps, qs, vs, ss],
                               [ca.vertcat(gap, hard, soft_rows), hs * general_path + soft_cost,
                                ca.vertcat(res_path, soft_res)],
                               ["x", "u", "x_next", "h", "p", "q", "v", "s"], ["g", "l", "r"])
        g_int, l_int, r_int = interval.map(n)(X[:, :-1], U, X[:, 1:], h, p, q, v, S)
        lb_int = np.concatenate([np.zeros(nx), *[c.lower for c in hard_path], soft_lb])
        ub_int = np.concatenate([np.zeros(nx), *[c.upper for c in hard_path], soft_ub])
        # rows in stage order (each node's own conditions, then its interval's gap and path rows), which
        # structure-exploiting solvers need
        rows = {k: [] for k in range(n + 1)}  # node -> [(expression, lower, upper)]
        linked = {k for k in range(n) if k + 1 == n or phase_of[k + 1] == phase_of[k]} if nt else set()
        columns = ca.horzsplit(g_int)
        for k in range(n):
            rows[k].append((columns[k], lb_int, ub_int))
            if k in linked:  # a phase's duration is the same at each of its nodes
                rows[k].append((TAU[0, k + 1] - TAU[0, k], np.zeros(1), np.zeros(1)))
        general = [ca.sum2(l_int), ocp.time_weight * ca.sum1(durations)]
        residuals = [ca.vec(r_int)]

        def at_node(expr, k):
            uk = U[:, k] if k < n else ca.MX.zeros(nu)
            return ca.Function("node", [xs, us, ps, qs, vs], [expr])(X[:, k], uk, p, q, v)

        # path constraints without controls also hold at the last node
        node_terms = [(c, "end") for c in hard_path if not ca.depends_on(c.expr, us)]
        node_terms += [(c, at) for c, at in ocp.constraints if at != "path" and c.soft is None]
        for c, at in node_terms:
            k = self._node(at, firsts, n)
            rows[k].insert(0 if k < n else len(rows[k]), (at_node(c.expr, k), c.lower, c.upper))
        slack = node_slacks.start
        for c, at in node_soft:
            k = self._node(at, firsts, n)
            s = w[slack:slack + c.expr.numel()]
            slack += c.expr.numel()
            soft, lb, ub, cost, res = _soft_rows([c], s, at_node(c.expr, k))
            rows[k].append((soft, lb, ub))
            general.append(cost)
            residuals.append(res)
        ordered = [r for k in range(n + 1) for r in rows[k]]
        g_parts = [e for e, _, _ in ordered]
        lbg = [np.broadcast_to(lo, (e.numel(),)) for e, lo, _ in ordered]
        ubg = [np.broadcast_to(hi, (e.numel(),)) for e, _, hi in ordered]
        for kind, e, at in ocp.costs:
            if at != "path":
                (general if kind == "general" else residuals).append(at_node(e, self._node(at, firsts, n)))
        self.w, self.par = w, par
        self.g = ca.vertcat(*g_parts)
        self.lbg, self.ubg = np.concatenate(lbg), np.concatenate(ubg)
        self.general = sum(general[1:], general[0])
        self.residuals = ca.vertcat(*residuals)
        self.f = self.general + 0.5 * ca.sumsqr(self.residuals)
        self.lbw, self.ubw = self._variable_bounds(phase_of)
        self.interval_function = interval

    @staticmethod
    def _node(at, firsts, n) -> int:
        if isinstance(at, tuple):  # ("end", phase): the first node of the next phase
            ends = list(firsts[1:]) + [n]
            return int(ends[at[1]])
        if isinstance(at, int):
            k = at if at >= 0 else n + 1 + at
            if not 0 <= k <= n:
                raise ConfigError(f"node index {at} is out of range: valid is 0 .. {n}")
            return k
        return 0 if at == "start" else n

    def _variable_bounds(self, phase_of):
        L, ocp = self.layout, self.ocp
        lbw, ubw = np.full(L.size, -np.inf), np.full(L.size, np.inf)
        n = L.intervals
        blocks_lb = lbw[:n * L.stage].reshape(n, L.stage)
        blocks_ub = ubw[:n * L.stage].reshape(n, L.stage)
        blocks_lb[:, L.nx + L.nt + L.nu:] = 0.0  # slacks of soft path constraints
        if L.nt:
            for k in range(n + 1):
                t = ocp.durations[phase_of[min(k, n - 1)]]
                lo, hi = (t.lower, t.upper) if isinstance(t, FreeTime) else (float(t), float(t))
                if k < n:
                    blocks_lb[k, L.nx], blocks_ub[k, L.nx] = lo, hi
                else:
                    lbw[n * L.stage + L.nx], ubw[n * L.stage + L.nx] = lo, hi
        lbw[:n * L.stage], ubw[:n * L.stage] = blocks_lb.ravel(), blocks_ub.ravel()
        for name, (_sym, lower, upper, _guess) in ocp.variables.items():
            lbw[L.variables[name]], ubw[L.variables[name]] = lower, upper
        lbw[L.node_slacks] = 0.0
        return lbw, ubw

    # -- numbers in and out -------------------------------------------------------------------
    def parameter_vector(self, values: dict) -> np.ndarray:
        """The parameter vector from ``{name: value}`` (``"p"``: the model parameters).

        Raises
        ------
        ConfigError
            If a parameter is missing, unknown or of the wrong size.
        """
        L = self.layout
        unknown = sorted(set(values) - set(L.parameters))
        if unknown:
            raise ConfigError(f"unknown OCP parameter(s) {', '.join(unknown)}; declared are "
                              f"{', '.join(L.parameters)}")
        out = np.empty(self.par.numel())
        for name, index in L.parameters.items():
            if name not in values:
                raise ConfigError(f"OCP parameter {name!r} ({index.stop - index.start} entries) was not given")
            value = np.ravel(np.asarray(values[name], float))
            if value.size != index.stop - index.start:
                raise ConfigError(f"OCP parameter {name!r} has {value.size} entries, expected "
                                  f"{index.stop - index.start}")
            out[index] = value
        return out

    def default_guess(self) -> np.ndarray:
        """A decision vector with the durations and variables at their guesses, all else zero."""
        ocp = self.ocp
        guesses = [t.guess if isinstance(t, FreeTime) else float(t) for t in ocp.durations]
        variables = {name: guess for name, (*_rest, guess) in ocp.variables.items()}
        L = self.layout
        return L.pack(np.zeros((L.nx, L.intervals + 1)), np.zeros((L.nu, L.intervals)), guesses, variables)

    def durations_of(self, w) -> np.ndarray:
        """Phase durations (s) of a decision vector."""
        return self.layout.phase_durations(w)


def _soft_rows(constraints: list[Constraint], slacks, values=None):
    """Rows ``c + s >= lower`` and ``c - s <= upper`` of soft constraints, with their penalty and residual."""
    if not constraints:
        return ca.SX(0, 1), np.zeros(0), np.zeros(0), ca.SX(0), ca.SX(0, 1)
    exprs = values if values is not None else ca.vertcat(*[c.expr for c in constraints])
    lower = np.concatenate([c.lower for c in constraints])
    upper = np.concatenate([c.upper for c in constraints])
    l1 = np.concatenate([np.full(c.expr.numel(), c.soft) for c in constraints])
    l2 = np.concatenate([np.full(c.expr.numel(), c.soft_quadratic) for c in constraints])
    rows = ca.vertcat(exprs + slacks, exprs - slacks)
    lb = np.concatenate([lower, np.full(lower.size, -np.inf)])
    ub = np.concatenate([np.full(upper.size, np.inf), upper])
    cost = ca.dot(ca.DM(l1), slacks)
    residual = ca.DM(np.sqrt(l2)) * slacks if np.any(l2 > 0) else slacks[0:0]
    return rows, lb, ub, cost, residual
