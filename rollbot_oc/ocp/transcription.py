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
apply.  The cost is::

    f = time_weight * sum(T) + general terms + 0.5 |residuals|^2 + soft penalties,

and ``general`` (everything but the least squares) and ``residuals`` are also
kept apart for the Gauss-Newton routes.

Simple bounds.  A hard path constraint whose every row is affine in a
single state or control, ``lower <= c(p) x_i + e(p) <= upper`` with ``c``
and ``e`` functions of the parameters only (a speed or a control within a
limit the parameters give, a position box), becomes a bound
on that entry of ``w`` instead of a row of ``g`` (as acados' ``idxbx`` and
``idxbu``): QP solvers treat bounds separately and more robustly.  The bounds
then depend on the parameters: ``Transcription.bounds(par)``.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.core.fastcall import FastFunction
from rollbot_oc.ocp.terms import Constraint, FreeTime
from rollbot_oc.model.codegen import compiled as compile_function

if TYPE_CHECKING:  # the problem builds its transcription (OCP.solver): the type only, for the annotations
    from rollbot_oc.ocp.problem import OCP

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
    stage_parameters : dict
        Name -> slice of one node's stage-parameter column.
    stage_block : slice
        Where the stage parameters sit in the parameter vector: a column of
        ``n_stage`` entries per node, node after node.
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
    stage_parameters: dict
    stage_block: slice

    @property
    def n_stage(self) -> int:
        """Stage-parameter entries per node."""
        return sum(sl.stop - sl.start for sl in self.stage_parameters.values())

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


@dataclass(frozen=True)
class Stage:
    """One stage of the transcription: an interval with its start node, or the last node.

    Attributes
    ----------
    index : int
        Node index ``k``.
    function : casadi.Function
        ``(y, v, p, q, sq, hs) -> (c, l, r)``: the stage's constraint rows, its
        general cost and its least-squares residuals, from its local vector
        ``y`` (``x_k, tau_k, u_k, s_k, x_{k+1}, tau_{k+1}``, then the slacks of
        its soft node constraints; the last node has ``x_N, tau_N`` and its
        slacks), the global variables ``v``, the model parameters ``p``, the
        problem's parameters ``q``, the stage parameters of its node ``sq``
        and ``hs`` (the interval length, or ``1 / N_phase`` when durations are
        free: ``h = tau_k hs``).
    columns : numpy.ndarray of int
        Where ``y`` sits in ``w``.
    rows : slice
        Where ``c`` sits in ``g``.
    hs : float
    lower, upper : numpy.ndarray
        Bounds of ``c``.
    """

    index: int
    function: ca.Function
    columns: np.ndarray
    rows: slice
    hs: float
    lower: np.ndarray
    upper: np.ndarray


class Transcription:
    """The NLP of an ``OCP`` by direct multiple shooting (see module doc), built once.

    Every stage is one SX Function of its local variables (``stages``); stages
    alike share one Function (mapped over them).  The NLP in MX for the
    interior-point routes and the structured linearisation of the SQP routes
    are both built from these Functions, so every route solves the same
    problem.

    Attributes
    ----------
    ocp : OCP
    layout : Layout
    stages : list of Stage
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
        self._simple = [b for b in (_simple_bound(c, ocp) for c in path if c.soft is None) if b is not None]
        simple = {id(b.constraint) for b in self._simple}
        self._hard_path = [c for c in path if c.soft is None and id(c) not in simple]
        self._soft_path = [c for c in path if c.soft is not None]
        n_soft_path = sum(c.expr.numel() for c in self._soft_path)
        nt = int(any(isinstance(t, FreeTime) for t in ocp.durations))
        n = sum(ocp.N)
        stage = nx + nt + nu + n_soft_path
        cursor = n * stage + nx + nt
        variables = {}
        for name, (sym, *_rest) in ocp.variables.items():
            variables[name] = slice(cursor, cursor + sym.numel())
            cursor += sym.numel()
        params = {"p": slice(0, m.np)}
        offset = m.np
        for name, sym in ocp.parameters.items():
            params[name] = slice(offset, offset + sym.numel())
            offset += sym.numel()
        stage_params, n_sq = {}, 0
        for name, sym in ocp.stage_parameters.items():
            stage_params[name] = slice(n_sq, n_sq + sym.numel())
            n_sq += sym.numel()
        stage_block = slice(offset, offset + n_sq * (n + 1))
        offset = stage_block.stop
        phase_of = np.repeat(np.arange(len(ocp.N)), ocp.N)
        firsts = np.concatenate([[0], np.cumsum(ocp.N)[:-1]]).astype(int)
        # node terms: hard constraints, soft constraints and costs at each node
        hard = {k: [] for k in range(n + 1)}
        soft = {k: [] for k in range(n + 1)}
        costs = {k: [] for k in range(n + 1)}
        hard[n] += [c for c in self._hard_path if not ca.depends_on(c.expr, ocp.u)]  # also at the last node
        for c, at in ocp.constraints:
            if at != "path":
                (hard if c.soft is None else soft)[self._node(at, firsts, n)].append(c)
        for kind, e, at in ocp.costs:
            if at != "path":
                costs[self._node(at, firsts, n)].append((kind, e))
        n_slacks = sum(c.expr.numel() for k in soft for c in soft[k])
        node_slacks = slice(cursor, cursor + n_slacks)
        self.layout = L = Layout(nx, nt, nu, n_soft_path, tuple(ocp.N), tuple(ocp.durations), variables,
                                 node_slacks, params, stage_params, stage_block)
        self._symbols = _Symbols(ocp, nt, n_soft_path)
        linked = {k for k in range(n) if k + 1 == n or phase_of[k + 1] == phase_of[k]} if nt else set()

        # -- the stages ------------------------------------------------------------------------
        functions, self.stages, row, slack = {}, [], 0, node_slacks.start
        self._named_rows: dict[str, list] = {}
        for k in range(n + 1):
            last = k == n
            phase = phase_of[min(k, n - 1)]
            first = k in set(firsts.tolist()) and not last
            key = (last, k in linked, first, tuple(map(id, hard[k])), tuple(map(id, soft[k])),
                   tuple(id(e) for _, e in costs[k]))
            if key not in functions:
                duration = None if nt else float(ocp.durations[phase])
                functions[key] = self._stage_function(last, k in linked, first, hard[k], soft[k], costs[k], duration)
            fun, lower, upper, names = functions[key]
            for name, local_rows in names.items():
                self._named_rows.setdefault(name, []).append(row + local_rows)
            n_e = sum(c.expr.numel() for c in soft[k])
            local = (np.arange(k * stage, k * stage + nx + nt) if last else
                     np.arange(k * stage, (k + 1) * stage + nx + nt))
            columns = np.concatenate([local, np.arange(slack, slack + n_e)]).astype(int)
            slack += n_e
            hs = 1.0 / ocp.N[phase] if nt else float(ocp.durations[phase]) / ocp.N[phase]
            self.stages.append(Stage(k, fun, columns, slice(row, row + lower.size), hs, lower, upper))
            row += lower.size

        # -- the NLP in MX: stages alike evaluated by one mapped call ---------------------------
        w = ca.MX.sym("w", L.size)
        par = ca.MX.sym("par", offset)
        self.w, self.par = w, par
        self.f, self.g, self.general, self.residuals = self.nlp()
        self.lbg = np.concatenate([st.lower for st in self.stages])
        self.ubg = np.concatenate([st.upper for st in self.stages])
        self.lbw, self.ubw = self._variable_bounds(phase_of)
        self._bound_places = self._simple_bound_places()
        self.global_columns = np.concatenate([np.arange(sl.start, sl.stop) for sl in variables.values()]
                                             ).astype(int) if variables else np.zeros(0, int)

    def nlp(self, compiled: bool = False):
        """``(f, g, general, residuals)``: the NLP in MX of ``w`` and ``par``, its stages alike evaluated by one
        mapped call of their Function; ``compiled``: that Function and its Jacobian as compiled C
        (``rollbot_oc.model.codegen``; then an NLP solver has first derivatives only: a limited-memory Hessian)."""
        ocp, L, w, par = self.ocp, self.layout, self.w, self.par
        n = L.intervals
        p = par[L.parameters["p"]]
        q = ca.vertcat(*[par[L.parameters[name]] for name in ocp.parameters]) if ocp.parameters else ca.MX(0, 1)
        v = ca.vertcat(*[w[L.variables[name]] for name in ocp.variables]) if ocp.variables else ca.MX(0, 1)
        SQ = ca.reshape(par[L.stage_block], L.n_stage, n + 1)
        c_of, l_of, r_of = {}, {}, {}
        for fun, group in self.groups():
            if compiled:
                # without optimisation: a stage and its Jacobian are 2 MB of C that gcc -O1 takes a minute to
                # compile and -O0 seconds, and an NLP solver's time goes to its own linear algebra, not to them
                fun = compile_function(fun, flags=("-O0",), jacobian=True)
            Y = ca.reshape(w[np.concatenate([st.columns for st in group]).tolist()], group[0].columns.size,
                           len(group))
            C, Lc, R = fun.map(len(group))(Y, v, p, q, SQ[:, [st.index for st in group]],
                                           ca.DM([st.hs for st in group]).T)
            for j, st in enumerate(group):
                c_of[st.index], l_of[st.index], r_of[st.index] = C[:, j], Lc[:, j], R[:, j]
        g = ca.vertcat(*[c_of[k] for k in range(n + 1)])
        general = ca.sum1(ca.vertcat(*[l_of[k] for k in range(n + 1)]))
        residuals = ca.vertcat(*[r_of[k] for k in range(n + 1)])
        return general + 0.5 * ca.sumsqr(residuals), g, general, residuals

    def groups(self):
        """Stages that share a Function, as ``(function, [stages])`` in order of first appearance."""
        out = {}
        for st in self.stages:
            out.setdefault(id(st.function), (st.function, []))[1].append(st)
        return list(out.values())

    def _simple_bound_places(self):
        """``(columns of w, index of the coefficient row)`` of every simple bound, node by node.

        Controls have no last node, and neither has a constraint that involves
        them (as its rows would not).  A state fixed at the start by
        ``OCP.initial_state`` is not bounded there (as acados keeps node 0
        apart): the measured state of an NMPC may lie outside a bound, and
        the problem must still have a solution that brings it back.
        """
        L, n = self.layout, self.layout.intervals
        columns, which, row = [], [], 0
        self._bound_columns = {}
        for b in self._simple:
            last = n + 1 if not b.is_control.any() else n
            for i, (index, control) in enumerate(zip(b.index, b.is_control)):
                local = L.nx + L.nt + index - L.nx if control else index
                first = 1 if (self.ocp.fixed_start and not control) else 0
                for k in range(first, last):
                    columns.append(k * L.stage + local)
                    which.append(row + i)
                    self._bound_columns.setdefault(b.constraint.name, []).append(columns[-1])
            row += b.index.size
        return np.array(columns, int), np.array(which, int)

    def columns_of(self, name: str) -> np.ndarray:
        """Entries of ``w`` (indices) that the constraints named ``name`` bound, when they are kept as simple
        bounds (none when they are rows: ``rows_of``)."""
        self.rows_of(name)  # an unknown name is an error
        return np.array(self._bound_columns.get(name, []), int)

    def _bound_function(self) -> ca.Function:
        """``(p, q) -> (lower, upper)`` of the simple bounds' entries of ``w`` (one row per bound row)."""
        ocp = self.ocp
        q = ca.vertcat(*ocp.parameters.values()) if ocp.parameters else ca.SX(0, 1)
        lows, highs = [], []
        for b in self._simple:
            lo, hi = (ca.DM(b.constraint.lower) - b.offset) / b.scale, (ca.DM(b.constraint.upper) - b.offset) / b.scale
            lows.append(ca.fmin(lo, hi))  # a negative coefficient turns the bounds round
            highs.append(ca.fmax(lo, hi))
        return ca.Function("simple_bounds", [ocp.p, q], [ca.densify(ca.vertcat(*lows)), ca.densify(ca.vertcat(*highs))])

    def bounds(self, par) -> tuple[np.ndarray, np.ndarray]:
        """``(lbw, ubw)`` of the decision vector for the parameter vector ``par`` (simple bounds included)."""
        columns, which = self._bound_places
        if not columns.size:
            return self.lbw, self.ubw
        par = np.asarray(par, float)
        funs = self.__dict__.setdefault("_bounds_funs", {})  # buffers per thread: a route may be shared
        thread = threading.get_ident()
        if thread not in funs:
            funs[thread] = FastFunction(self._bound_function())
        L = self.layout
        q = np.concatenate([par[L.parameters[name]] for name in self.ocp.parameters]) \
            if self.ocp.parameters else np.zeros(0)
        lo, hi = funs[thread](par[L.parameters["p"]], q)
        lbw, ubw = self.lbw.copy(), self.ubw.copy()
        np.maximum.at(lbw, columns, lo[which])  # several bounds of one entry: the tightest holds
        np.minimum.at(ubw, columns, hi[which])
        return lbw, ubw

    def bounds_symbolic(self, par: ca.MX) -> tuple[ca.MX, ca.MX]:
        """``bounds`` as CasADi expressions of a symbolic parameter vector (for ``to_function``)."""
        columns, which = self._bound_places
        lbw, ubw = ca.MX(ca.DM(self.lbw)), ca.MX(ca.DM(self.ubw))
        if not columns.size:
            return lbw, ubw
        L = self.layout
        q = ca.vertcat(*[par[L.parameters[name]] for name in self.ocp.parameters]) if self.ocp.parameters \
            else ca.MX(0, 1)
        lo, hi = self._bound_function()(par[L.parameters["p"]], q)
        for column, row in zip(columns.tolist(), which.tolist()):  # one at a time: the tightest of several holds
            lbw[column] = ca.fmax(lbw[column], lo[row])
            ubw[column] = ca.fmin(ubw[column], hi[row])
        return lbw, ubw

    def rows_of(self, name: str) -> np.ndarray:
        """Rows of ``g`` (indices) that belong to the constraints named ``name``, at every node (none for a
        constraint kept as simple bounds).

        Raises
        ------
        ConfigError
            If no constraint has that name.
        """
        if name not in self._named_rows:
            bounds = {b.constraint.name for b in self._simple}
            if name in bounds:
                return np.zeros(0, int)  # kept as bounds of w, not rows of g
            raise ConfigError(f"no constraint named {name!r}; named are "
                              f"{', '.join(sorted(set(self._named_rows) | bounds))}")
        return np.concatenate(self._named_rows[name]).astype(int)

    def _stage_function(self, last, linked, first, hard, soft, costs, duration):
        """The SX Function ``(y, v, p, q, sq, hs) -> (c, l, r)`` of one kind of stage, with the bounds of ``c``
        and the local rows of each named hard constraint."""
        ocp, S = self.ocp, self._symbols
        m = ocp.model
        e = ca.SX.sym("e", sum(c.expr.numel() for c in soft))
        h = S.tau[0] * S.hs if S.tau.numel() else S.hs
        # rows: the continuity gaps first (the dynamics block of structure-exploiting QP solvers), then
        # the node's own conditions, the path constraints and the soft rows
        rows = []
        general = [ca.SX(0)]
        residuals = []
        if not last:
            gap = S.x_next - m.interval(ocp.substeps)(ocp.x, ocp.u, h, ocp.p)
            rows.append((gap, np.zeros(m.nx), np.zeros(m.nx)))
            if linked:  # a phase's duration is the same at each of its nodes
                rows.append((S.tau_next - S.tau, np.zeros(1), np.zeros(1)))
        rows += [(c.expr, c.lower, c.upper, c.name) for c in hard]
        if not last:
            rows += [(c.expr, c.lower, c.upper, c.name) for c in self._hard_path]
            soft_rows, lb, ub, cost, res = _soft_rows(self._soft_path, S.s)
            rows.append((soft_rows, lb, ub))
            general += [h * sum((x for kind, x, at in ocp.costs if kind == "general" and at == "path"), ca.SX(0)),
                        cost]
            lsq = [x for kind, x, at in ocp.costs if kind == "lsq" and at == "path"]
            residuals += [ca.sqrt(h) * x for x in lsq] + [res]
        if first:
            general.append(ocp.time_weight * (S.tau[0] if S.tau.numel() else duration))
        soft_rows, lb, ub, cost, res = _soft_rows(soft, e)
        rows.append((soft_rows, lb, ub))
        general.append(cost)
        residuals.append(res)
        general += [x for kind, x in costs if kind == "general"]
        residuals += [x for kind, x in costs if kind == "lsq"]
        y = ca.vertcat(ocp.x, S.tau, e) if last else ca.vertcat(ocp.x, S.tau, ocp.u, S.s, S.x_next, S.tau_next, e)
        c = ca.vertcat(*[r[0] for r in rows])
        lower = np.concatenate([np.broadcast_to(r[1], (r[0].numel(),)) for r in rows])
        upper = np.concatenate([np.broadcast_to(r[2], (r[0].numel(),)) for r in rows])
        names, start = {}, 0
        for r in rows:
            size = r[0].numel()
            if len(r) > 3:
                names.setdefault(r[3], []).extend(range(start, start + size))
            start += size
        fun = ca.Function("last_node" if last else "stage", [y, S.v, ocp.p, S.q, S.sq, S.hs],
                          [c, sum(general[1:], general[0]), ca.vertcat(*residuals) if residuals else ca.SX(0, 1)],
                          ["y", "v", "p", "q", "sq", "hs"], ["c", "l", "r"])
        return fun, lower, upper, {name: np.array(rows_, int) for name, rows_ in names.items()}

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
        declared = list(L.parameters) + list(L.stage_parameters)
        unknown = sorted(set(values) - set(declared))
        if unknown:
            raise ConfigError(f"unknown OCP parameter(s) {', '.join(unknown)}; declared are "
                              f"{', '.join(declared)}")
        out = np.empty(self.par.numel())
        nodes = L.intervals + 1
        column = out[L.stage_block].reshape(nodes, L.n_stage)  # a view: node after node
        for name, rows in L.stage_parameters.items():
            n_rows = rows.stop - rows.start
            if name not in values:
                raise ConfigError(f"OCP stage parameter {name!r} ({n_rows} per node) was not given")
            value = np.asarray(values[name], float)
            if value.shape in ((n_rows,), (n_rows, 1)):
                value = np.repeat(value.reshape(n_rows, 1), nodes, axis=1)
            elif n_rows == 1 and value.shape == (nodes,):
                value = value[None, :]
            if value.shape != (n_rows, nodes):
                raise ConfigError(f"OCP stage parameter {name!r} has shape {value.shape}, expected "
                                  f"({n_rows}, {nodes}) (a column per node) or ({n_rows},)")
            column[:, rows] = value.T
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


@dataclass(frozen=True)
class _SimpleBound:
    """A hard path constraint that bounds single entries: row i is ``scale_i(p) * z[index_i] + offset_i(p)``."""

    constraint: Constraint
    index: np.ndarray       # entry of (x, u) each row bounds
    is_control: np.ndarray  # whether that entry is a control
    scale: ca.SX
    offset: ca.SX


def _simple_bound(c: Constraint, ocp: OCP):
    """The ``_SimpleBound`` of ``c`` if every row is affine in one state or control with coefficients of the
    model and problem parameters only, else None."""
    xu = ca.vertcat(ocp.x, ocp.u)
    others = [s for s in list(ocp.stage_parameters.values()) + [sym for sym, *_ in ocp.variables.values()]]
    if any(ca.depends_on(c.expr, s) for s in others):
        return None
    J = ca.jacobian(c.expr, xu)
    if ca.depends_on(J, xu):
        return None
    index = []
    for i in range(c.expr.numel()):
        cols = [j for j in range(xu.numel()) if not J[i, j].is_zero()]
        if len(cols) != 1:
            return None
        index.append(cols[0])
    if len(set(index)) != len(index):
        return None
    index = np.array(index, int)
    scale = ca.vertcat(*[J[i, j] for i, j in enumerate(index)])
    offset = ca.substitute(c.expr, xu, ca.SX.zeros(xu.numel()))
    return _SimpleBound(c, index, index >= ocp.model.nx, scale, offset)


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


class _Symbols:
    """The SX symbols of one stage besides the OCP's own (duration, slacks, next node, scale, globals)."""

    def __init__(self, ocp: OCP, nt: int, n_soft_path: int):
        self.tau = ca.SX.sym("tau", nt)
        self.tau_next = ca.SX.sym("tau_next", nt)
        self.x_next = ca.SX.sym("x_next", ocp.model.nx)
        self.s = ca.SX.sym("s", n_soft_path)
        self.hs = ca.SX.sym("hs")
        self.q = ca.vertcat(*ocp.parameters.values()) if ocp.parameters else ca.SX(0, 1)
        self.sq = ca.vertcat(*ocp.stage_parameters.values()) if ocp.stage_parameters else ca.SX(0, 1)
        self.v = ca.vertcat(*[sym for sym, *_ in ocp.variables.values()]) if ocp.variables else ca.SX(0, 1)
