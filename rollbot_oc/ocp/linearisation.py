"""The structured linearisation of a transcription: per-stage AD derivatives, assembled by the layout.

For each kind of stage (``Transcription.groups``) one SX Function gives, by
CasADi's AD, the stage's constraint rows ``c`` and their Jacobian, the
gradient of its cost and its Gauss-Newton Hessian block

    grad = J_r^T r + dl/dz,        H = J_r^T J_r + d^2 l / dz^2,

with ``z`` the stage's local variables and the global ones, ``r`` its
least-squares residuals and ``l`` its general cost.  The Function is compiled
to C where a compiler exists (``rollbot_oc.model.codegen``), mapped over the stages
alike, and the blocks land in the global sparse matrices through index maps
computed once from the Functions' sparsity patterns and the stages' places in
``w`` and ``g``.  Nothing here knows what the problem is: every entry and
every sparsity comes from AD of the one transcription (``tests`` check it
against CasADi's Jacobian of the whole NLP).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from rollbot_oc.core.fastcall import FastFunction
from rollbot_oc.model.codegen import compiled

__all__ = ["StructuredLinearisation"]


class _Group:
    """The derivative Function of one kind of stage, mapped over its stages, with its index maps."""

    def __init__(self, fun: ca.Function, stages, global_columns: np.ndarray, compile_it: bool):
        names = ("y", "v", "p", "q", "sq", "hs")
        sizes = [fun.size1_in(i) for i in range(fun.n_in())]
        y, v, p, q, sq, hs = (ca.SX.sym(name, n) for name, n in zip(names, sizes))
        c, l, r = fun(y, v, p, q, sq, hs)
        z = ca.vertcat(y, v)
        Jr = ca.jacobian(r, z)
        derivatives = ca.Function(f"d_{fun.name()}", [y, v, p, q, sq, hs],
                                  [c, ca.jacobian(c, z), ca.mtimes(Jr.T, r) + ca.gradient(l, z),
                                   ca.triu(ca.mtimes(Jr.T, Jr) + ca.hessian(l, z)[0]), l + 0.5 * ca.sumsqr(r)],
                                  list(names), ["c", "J", "grad", "H", "f"])
        if compile_it:
            derivatives = compiled(derivatives)
        count = len(stages)
        shared = [1, 2, 3]  # v, p and q are the same for every stage; y, sq and hs are per stage
        self.derivatives, self.shared = derivatives, shared
        self.fast = FastFunction(derivatives.map(f"{derivatives.name()}_{count}", "serial", count, shared, []))
        self.values = FastFunction(fun.map(f"{fun.name()}_{count}", "serial", count, shared, []))
        self.columns = np.array([np.concatenate([st.columns, global_columns]) for st in stages])  # (count, nz)
        self.y_columns = np.array([st.columns for st in stages])
        self.hs = np.array([st.hs for st in stages])
        self.nodes = np.array([st.index for st in stages])
        self.rows = np.concatenate([np.arange(st.rows.start, st.rows.stop) for st in stages]).astype(int)
        jr, jc = derivatives.sparsity_out(1).get_triplet()
        hr, hc = derivatives.sparsity_out(3).get_triplet()
        starts = np.array([st.rows.start for st in stages])
        # global coordinates of every nonzero, stage after stage (the order of the mapped outputs)
        self.J_rows = (starts[:, None] + np.asarray(jr, int)[None, :]).ravel()
        self.J_cols = self.columns[:, np.asarray(jc, int)].ravel()
        self.H_rows = self.columns[:, np.asarray(hr, int)].ravel()
        self.H_cols = self.columns[:, np.asarray(hc, int)].ravel()
        self.grad_cols = self.columns.ravel()

    def mapped_without_empty(self, keep: list) -> ca.Function:
        """The stage derivatives mapped over the group's stages with only the inputs ``keep`` (the others
        are empty: a mapped empty input generates C that does not compile cleanly)."""
        d = self.derivatives
        if d.is_a("external"):
            raise ValueError("StructuredLinearisation.symbolic needs uncompiled stage Functions (compiled=False)")
        syms = [ca.SX.sym(d.name_in(i), d.sparsity_in(i)) for i in range(d.n_in())]
        inner = ca.Function(f"{d.name()}_used", [syms[i] for i in keep], d(*syms), [d.name_in(i) for i in keep],
                            d.name_out())
        shared = [keep.index(i) for i in self.shared if i in keep]
        return inner.map(f"{d.name()}_{len(self.nodes)}", "serial", len(self.nodes), shared, [])

    def evaluate(self, w, v, p, q, SQ):
        """``(c, J values, grad values, H values, f values)`` of every stage of the group; ``SQ`` the
        stage parameters (n_stage, N+1)."""
        Y = w[self.y_columns].T  # (ny, count), column-major into the mapped Function
        c, J, grad, H, f = self.fast(Y, v, p, q, SQ[:, self.nodes], self.hs)
        return c, J, grad, H, f

    def cost_and_rows(self, w, v, p, q, SQ):
        """``(c, l, r)`` of every stage (no derivatives), for line searches."""
        return self.values(w[self.y_columns].T, v, p, q, SQ[:, self.nodes], self.hs)


class StructuredLinearisation:
    """``(w, par) -> (H, grad, g, J, f)`` of a ``Transcription`` from per-stage AD (see module doc).

    Parameters
    ----------
    transcription : Transcription
    regularisation : float
        Multiple of the identity added to the Hessian.
    compiled : bool
        Evaluate the stage derivatives as compiled C.
    """

    def __init__(self, transcription, regularisation: float = 1e-8, compiled: bool = True):
        tr = self.transcription = transcription
        L = tr.layout
        n, m = L.size, tr.lbg.size
        self.groups = [_Group(fun, stages, tr.global_columns, compiled) for fun, stages in tr.groups()]
        J_rows = np.concatenate([g.J_rows for g in self.groups])
        J_cols = np.concatenate([g.J_cols for g in self.groups])
        order = np.lexsort((J_rows, J_cols))  # column-major, as CasADi stores nonzeros
        self.J_order = order
        self.J_sparsity = ca.Sparsity.triplet(m, n, J_rows[order].tolist(), J_cols[order].tolist())
        self._J_rows, self._J_cols = J_rows[order], J_cols[order]  # of each nonzero, in the sparsity's order
        if self.J_sparsity.nnz() != J_rows.size:
            raise RuntimeError("structured linearisation: two stages claim the same Jacobian entry")
        # Hessian: upper triangle, blocks overlap where stages share a node (summed), plus the diagonal
        diag = np.arange(n)
        H_rows = np.concatenate([g.H_rows for g in self.groups] + [diag])
        H_cols = np.concatenate([g.H_cols for g in self.groups] + [diag])
        lo, hi = np.minimum(H_rows, H_cols), np.maximum(H_rows, H_cols)  # upper triangle
        keys, self.H_index = np.unique(hi * n + lo, return_inverse=True)
        cols, rows = np.divmod(keys, n)
        upper = ca.Sparsity.triplet(n, n, rows.tolist(), cols.tolist())
        self.H_upper = upper
        self.H_sparsity = upper + upper.T  # the conic solvers take the full symmetric pattern
        self.H_full_map = self._symmetric_map(upper)
        self.regularisation = np.full(n, float(regularisation))
        self.grad_cols = np.concatenate([g.grad_cols for g in self.groups])
        self.n, self.m = n, m
        self._v = tr.global_columns

    def _symmetric_map(self, upper: ca.Sparsity) -> np.ndarray:
        """Index of each nonzero of the full symmetric pattern in the upper triangle's nonzeros."""
        full = self.H_sparsity
        fr, fc = full.get_triplet()
        fr, fc = np.asarray(fr), np.asarray(fc)
        ur, uc = upper.get_triplet()
        lookup = {(r, c): i for i, (r, c) in enumerate(zip(ur, uc))}
        return np.array([lookup[(min(r, c), max(r, c))] for r, c in zip(fr, fc)], dtype=int)

    def split_parameters(self, par):
        """``(p, q, SQ)``: the model parameters, the problem's parameters and the stage parameters (n_stage, N+1)."""
        tr = self.transcription
        L = tr.layout
        p = par[L.parameters["p"]]
        q = np.concatenate([par[L.parameters[name]] for name in tr.ocp.parameters]) if tr.ocp.parameters \
            else np.zeros(0)
        SQ = np.asarray(par[L.stage_block]).reshape(L.intervals + 1, L.n_stage).T
        return p, q, SQ

    def __call__(self, w, par):
        """``(H, grad, g, J, f)`` at ``w``: H and J as CasADi sparse DM, the rest numpy."""
        H, grad, g, J, f = self.nonzeros(w, par)
        return ca.DM(self.H_sparsity, H), grad, g, ca.DM(self.J_sparsity, J), f

    def nonzeros(self, w, par):
        """``(H, grad, g, J, f)`` at ``w``, all numpy: H and J as their nonzeros in the order of
        ``H_sparsity`` and ``J_sparsity`` (what a conic solver's buffers take, no DM built)."""
        w = np.asarray(w, float)
        p, q, SQ = self.split_parameters(par)
        v = w[self._v]
        g = np.empty(self.m)
        J_vals, grad_vals, H_vals, f = [], [], [], 0.0
        for group in self.groups:
            c, J, grad, H, fs = group.evaluate(w, v, p, q, SQ)
            g[group.rows] = c
            J_vals.append(J)
            grad_vals.append(grad)
            H_vals.append(H)
            f += float(np.sum(fs))
        J = np.concatenate(J_vals)[self.J_order]
        grad = np.bincount(self.grad_cols, weights=np.concatenate(grad_vals), minlength=self.n)
        upper = np.bincount(self.H_index, weights=np.concatenate(H_vals + [self.regularisation]),
                            minlength=self.H_upper.nnz())
        return upper[self.H_full_map], grad, g, J, f

    def J_times(self, J, d) -> np.ndarray:
        """The product of the Jacobian with nonzeros ``J`` (as ``nonzeros`` gives them) and a vector ``d``."""
        return np.bincount(self._J_rows, weights=J * np.asarray(d, float)[self._J_cols], minlength=self.m)

    def symbolic(self, w: ca.MX, par: ca.MX):
        """``(H, grad, g, J, f)`` as CasADi MX expressions of symbols ``w`` and ``par``, for code generation.

        The same stage Functions, mapped over their stages (a loop in generated C, not one copy of the
        code per stage), and the same index maps as ``__call__``: the assembly is a permutation of the
        stages' nonzeros (``J``, ``g``) and sparse sums of them (``grad``, ``H``).  Needs stage Functions
        that are not compiled libraries (``compiled=False``): CasADi generates C only from its own.
        """
        tr = self.transcription
        L = tr.layout
        p = par[L.parameters["p"]]
        q = ca.vertcat(*[par[L.parameters[name]] for name in tr.ocp.parameters]) if tr.ocp.parameters \
            else ca.MX(0, 1)
        SQ = ca.reshape(par[L.stage_block], L.n_stage, L.intervals + 1)
        v = w[self._v.tolist()] if self._v.size else ca.MX(0, 1)
        rows, cs, Js, grads, Hs, f = [], [], [], [], [], 0
        for group in self.groups:
            count, ny = group.y_columns.shape
            Y = ca.reshape(w[group.y_columns.ravel().tolist()], ny, count)
            hs = ca.DM(group.hs).T
            args = [Y, v, p, q, SQ[:, group.nodes.tolist()], hs]
            keep = [i for i, a in enumerate(args) if a.numel()]  # generated C copies no empty inputs
            c, J, grad, H, fs = group.mapped_without_empty(keep)(*[args[i] for i in keep])
            rows.append(group.rows)
            cs.append(ca.vec(c))
            Js.append(J.nz[:] if J.nnz() else ca.MX(0, 1))
            grads.append(ca.vec(grad))
            Hs.append(H.nz[:] if H.nnz() else ca.MX(0, 1))
            f += ca.sum2(fs)
        g = ca.vertcat(*cs)[np.argsort(np.concatenate(rows)).tolist()]
        J = ca.MX(self.J_sparsity, ca.vertcat(*Js)[self.J_order.tolist()])
        grad = ca.mtimes(_summation(self.grad_cols, self.n), ca.vertcat(*grads))
        upper = ca.mtimes(_summation(self.H_index, self.H_upper.nnz()), ca.vertcat(*Hs, ca.DM(self.regularisation)))
        H = ca.MX(self.H_sparsity, upper[self.H_full_map.tolist()])
        return H, grad, g, J, f

    def cost_and_constraints(self, w, par):
        """``(f, g)`` at ``w`` without derivatives."""
        w = np.asarray(w, float)
        p, q, SQ = self.split_parameters(par)
        v = w[self._v]
        g = np.empty(self.m)
        f = 0.0
        for group in self.groups:
            c, l, r = group.cost_and_rows(w, v, p, q, SQ)
            g[group.rows] = c
            f += float(np.sum(l)) + 0.5 * float(np.sum(np.square(r)))
        return f, g


def _summation(targets: np.ndarray, n: int) -> ca.DM:
    """The sparse matrix (n, len(targets)) of ones that sums entry ``i`` into row ``targets[i]``
    (``numpy.bincount`` with weights, as a product a code generator can write)."""
    targets = np.asarray(targets, int)
    columns = np.arange(targets.size)
    return ca.DM(ca.Sparsity.triplet(n, targets.size, targets.tolist(), columns.tolist()), 1.0)
