"""Which QP route can one control step (Python and generated C alike) use at the NMPC's own horizon (N = 60)?

The real QPs: the N-shape closed loop is run in-process with the NMPC (RTI, HPIPM) and every QP of the
tracking problem (670 variables, 790 rows: 610 equalities, 180 path inequalities, 120 finite bounds) that
``SQPRoute._solve_qp`` receives is recorded (wrapped in this script, the library is not changed).  The
reference is HPIPM solved tightly (residuals 1e-8, "robust"; 1e-9 stagnates at iter_max), cross-checked
against the exact active-set solvers (qrqp, DAQP), which agree with each other to ~1e-9.  Per candidate route:

* generates C: ``Function.generate`` of an MX Function calling the conic, compiled by gcc (-O2) into a shared
  library without libcasadi (``-Wl,--no-undefined``, no ``-lcasadi``; ``ldd`` shown); the figures of a
  generatable route are those of that compiled C (loaded with ``casadi.external``), not of CasADi's plugin;
* accuracy: max over the QPs of |first control of the step - HPIPM's| and of |step - HPIPM's| (all 670);
* time per QP solve on this machine (pinned to one core): median / p95 / max, ms;
* work memory of the generated Function: sz_w doubles + sz_iw ints + sz_arg/sz_res pointers, 8 bytes each;
* failures: a QP whose solve returns a failure, or whose step violates the QP's constraints by > 1e-6, is
  counted (with its status) and left out of nothing: its |diff| is in the max.

Routes: the full sparse QP (qrqp, HPIPM, DAQP, ...) and the condensed QP: the states eliminated by CasADi
expressions (``condense_functions``: the continuity rows give x_{k+1} = A_k x_k + B_k u_k + c_k, so
d = T du + t with T (670 x 60) and t from the recursion), leaving 60 variables and 240 dense rows.  Its
split: preparation (T, H_c, A_c: independent of the measured state, as acados condenses before the
measurement) and feedback (t, g_c, bounds, the dense QP, the step).

A second set ("STRESS", synthetic) is the same QPs with the motor acceleration bounds narrowed to 20 %, so
that up to 25 bounds are active (the real QPs have at most 4): it shows how the active-set solvers' iteration
counts, and so their times, grow.

Run: PYTHONPATH=. .venv/bin/python benchmarks/bench_qp_routes.py [--quick] [--qps FILE] [--out FILE]
(about 4 min; --quick about 1 min: 100 QPs from a 5 s run)
"""

from __future__ import annotations

import argparse
import datetime
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

CASADI_DIR = Path(ca.__file__).parent
TOL_FEAS = 1e-6  # SQPRoute.qp_feasibility


# -- the QPs -------------------------------------------------------------------------------------------------
def capture(duration: float) -> dict:
    """Run the N-shape with the NMPC for ``duration`` s and record the tracking QPs (N = 60) in order."""
    from rollbot_oc.ocp.routes import sqp
    from rollbot_oc.scenarios.problem import load_problem, run_problem

    qps, meta = [], {}
    original = sqp.SQPRoute._solve_qp

    def recording(self, args, lam_w, lam_g):
        result = original(self, args, lam_w, lam_g)
        lin = self.linearisation
        if lin.n > 500:  # the tracking problem at N = 60 (not a planner's QP)
            if not meta:
                layout = self.transcription.layout
                index = np.arange(lin.n, dtype=float)
                meta.update(H_sp=lin.H_sparsity.serialize(), J_sp=lin.J_sparsity.serialize(), n=lin.n, m=lin.m,
                            x_cols=np.asarray(layout.states(index)).astype(int),
                            u_cols=np.asarray(layout.controls(index)).ravel().astype(int),
                            lbg=self.transcription.lbg.copy(), ubg=self.transcription.ubg.copy())
            qps.append({k: np.array(v, float).copy() for k, v in args.items()})
        return result

    sqp.SQPRoute._solve_qp = recording
    try:
        root = Path(__file__).resolve().parents[1]
        run_problem(load_problem(root / "problems" / "n_shape.toml"), "nmpc", duration=duration)
    finally:
        sqp.SQPRoute._solve_qp = original
    return dict(meta=meta, qps=qps)


# -- helpers -------------------------------------------------------------------------------------------------
def pin_one_core():
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})


def load() -> str:
    return "load %.2f %.2f %.2f" % os.getloadavg()


def stats_ms(times) -> str:
    if not times:
        return "-"
    t = np.array(times) * 1e3
    return f"{np.median(t):7.3f} {np.percentile(t, 95):7.3f} {np.max(t):7.3f}"


def violation(qp, J_sp, d) -> float:
    rows = np.array(ca.DM(J_sp, qp["a"]) @ ca.DM(d)).ravel()
    return float(max(np.max(qp["lba"] - rows, initial=0), np.max(rows - qp["uba"], initial=0),
                     np.max(qp["lbx"] - d, initial=0), np.max(d - qp["ubx"], initial=0)))


def work_bytes(f: ca.Function) -> int:
    return 8 * (f.sz_w() + f.sz_iw() + f.sz_arg() + f.sz_res())


class Generated:
    """An MX Function generated as C, compiled without libcasadi and loaded back (``casadi.external``)."""

    def __init__(self, f: ca.Function, folder: Path, extra_flags=(), libs=()):
        self.f, self.name = f, f.name()
        self.c = folder / f"{self.name}.c"
        self.so = folder / f"lib{self.name}.so"
        here = os.getcwd()
        os.chdir(folder)
        try:
            f.generate(self.c.name, {"with_header": False})
        finally:
            os.chdir(here)
        text = self.c.read_text()
        self.error = next((line.strip() for line in text.splitlines() if "#error" in line), None)
        cmd = ["gcc", "-O2", "-fPIC", "-shared", "-Wl,--no-undefined", *extra_flags, str(self.c), *libs, "-o",
               str(self.so), "-lm"]
        t0 = time.perf_counter()
        run = subprocess.run(cmd, capture_output=True, text=True)
        self.compile_s = time.perf_counter() - t0
        self.ok = run.returncode == 0 and self.error is None
        self.why = self.error or (run.stderr.strip().splitlines() or ["?"])[-1][:120] if not self.ok else ""
        self.ldd = ""
        if self.ok:
            ldd = subprocess.run(["ldd", str(self.so)], capture_output=True, text=True).stdout
            self.ldd = ", ".join(sorted(line.split()[0] for line in ldd.splitlines() if "=>" in line))
            self.links_casadi = "casadi" in ldd
            self.uses_malloc = "malloc" in subprocess.run(["nm", "-u", str(self.so)], capture_output=True,
                                                          text=True).stdout
            self.ext = ca.external(self.name, str(self.so))
            self.buffer, self.evaluate = self.ext.buffer()
            self.ins = [np.zeros(self.ext.nnz_in(i)) for i in range(self.ext.n_in())]
            self.outs = [np.zeros(self.ext.nnz_out(i)) for i in range(self.ext.n_out())]
            for i, a in enumerate(self.ins):
                self.buffer.set_arg(i, memoryview(a))
            for i, a in enumerate(self.outs):
                self.buffer.set_res(i, memoryview(a))

    def __call__(self, *args):
        """Outputs (copies), return flag (0: success) and seconds of the C call."""
        for a, v in zip(self.ins, args):
            a[:] = np.ravel(v)
        t0 = time.perf_counter()
        self.evaluate()
        dt = time.perf_counter() - t0
        return [o.copy() for o in self.outs], self.buffer.ret(), dt


def conic_function(name: str, plugin: str, h_sp, a_sp, opts: dict) -> tuple[ca.Function, ca.Function]:
    """(the conic, an MX Function h, g, a, lba, uba, lbx, ubx, lam_x0, lam_a0 -> x, lam_x, lam_a calling it)."""
    conic = ca.conic(f"{name}_qp", plugin, {"h": h_sp, "a": a_sp}, opts)
    h, a = ca.MX.sym("h", h_sp), ca.MX.sym("a", a_sp)
    n, m = h_sp.size1(), a_sp.size1()
    g, lbx, ubx, lx = (ca.MX.sym(s, n) for s in ("g", "lbx", "ubx", "lam_x0"))
    lba, uba, la = (ca.MX.sym(s, m) for s in ("lba", "uba", "lam_a0"))
    sol = conic(h=h, g=g, a=a, lba=lba, uba=uba, lbx=lbx, ubx=ubx, lam_x0=lx, lam_a0=la)
    return conic, ca.Function(name, [h, g, a, lba, uba, lbx, ubx, lx, la], [sol["x"], sol["lam_x"], sol["lam_a"]],
                              ["h", "g", "a", "lba", "uba", "lbx", "ubx", "lam_x0", "lam_a0"],
                              ["x", "lam_x", "lam_a"])


# -- condensing ----------------------------------------------------------------------------------------------
def stage_structure(meta: dict, first_qp: dict) -> dict:
    """The stage structure of the tracking QP, read off its sparsity (and checked): each equality row either
    fixes one component of x_0 (the initial state) or is a continuity row of interval k with one entry in
    x_{k+1} (the highest node it touches) and its others in x_k and u_k; each inequality row and each Hessian
    entry lies within one stage (x_k, u_k); the states with finite bounds."""
    J_sp, H_sp = ca.Sparsity.deserialize(meta["J_sp"]), ca.Sparsity.deserialize(meta["H_sp"])
    xc, uc = meta["x_cols"], meta["u_cols"]
    nx, N1 = xc.shape
    N = N1 - 1
    stage_of = np.full(meta["n"], -1)
    node = {}
    for k in range(N1):
        for i, c in enumerate(xc[:, k]):
            stage_of[c], node[int(c)] = k, (k, i)
    stage_of[uc] = np.arange(N)
    assert np.all(stage_of >= 0), "a variable outside the stages (a global one): not handled here"
    rows, cols = (np.asarray(v) for v in J_sp.get_triplet())
    init, cont = {}, [dict() for _ in range(N)]
    path = [[] for _ in range(N1)]
    for r in range(meta["m"]):
        c = cols[rows == r]
        top = stage_of[c].max()
        if meta["lbg"][r] != meta["ubg"][r]:
            assert np.all(stage_of[c] == top), f"inequality row {r} spans stages"
            path[top].append(r)
            continue
        heads = [node[int(x)] for x in c if int(x) in node and node[int(x)][0] == top]
        assert len(heads) == 1, f"row {r}: more than one entry in its highest node"
        if top == 0:
            assert len(c) == 1, f"row {r}: an initial row with more entries"
            init[heads[0][1]] = r
        else:
            assert np.all(stage_of[c] >= top - 1) and not np.any(np.isin(c, uc[top:])), f"row {r}: not one interval"
            cont[top - 1][heads[0][1]] = r
    assert len(init) == nx and all(len(cont[k]) == nx for k in range(N))
    hr, hc = (np.asarray(v) for v in H_sp.get_triplet())
    assert np.all(stage_of[hr] == stage_of[hc]), "the Hessian couples stages"
    bounded = np.isfinite(first_qp["lbx"]) | np.isfinite(first_qp["ubx"])
    assert not np.any(bounded[xc[:, 0]]), "bounds on x_0 (fixed by the initial rows): not handled"
    return dict(nx=nx, N=N, xc=xc, uc=uc, R0=[init[i] for i in range(nx)],
                Rk=[[cont[k][i] for i in range(nx)] for k in range(N)], path=path,
                S=[[i for i in range(nx) if bounded[xc[i, k]]] for k in range(N1)], H_sp=H_sp, J_sp=J_sp,
                n=meta["n"], m=meta["m"])


def condense_functions(meta: dict, first_qp: dict):
    """Condensing of the tracking QP as CasADi MX Functions (generated as C like any other): recursions over
    the stages, one call of a small stage Function per stage (a loop of calls in C), so that the
    sensitivities M_k = d x_k / d u (nx x N) live one stage at a time and every stage's temporaries share
    their work memory (CasADi reuses an MX work slot only for a result of the same size).

    ``prep(h, a) -> (Hc, Ac)``: sum_k Z_k' H_k Z_k (Z_k = [M_k; e_k']) and the rows [J_I,k Z_k; M_{k+1}[S]]
    (path inequalities, bounded states) of each stage; independent of the measured state (acados'
    preparation);
    ``feedback(h, g, a, lba, uba, lbx, ubx) -> (gc, lbA, ubA, lbu, ubu)``: the free trajectory t (x_0 from
    the initial rows, u = 0) forwards, the gradient T'(H t + g) backwards (an adjoint), the bounds;
    ``expand(a, lba, du) -> d``: the states by the dynamics forwards."""
    st = stage_structure(meta, first_qp)
    nx, N, xc, uc, n = st["nx"], st["N"], st["xc"], st["uc"], st["n"]
    J_sp, H_sp = st["J_sp"], st["H_sp"]
    S = st["S"][1]
    assert all(st["S"][k] == S for k in range(1, N + 1)) and not st["path"][N]
    npath = len(st["path"][0])
    assert all(len(st["path"][k]) == npath for k in range(N))

    def lookup(sp):
        r, c = sp.get_triplet()
        return {(i, j): z for z, (i, j) in enumerate(zip(r, c))}

    LJ, LH = lookup(J_sp), lookup(H_sp)

    def block(L, rows, cols):
        """(pattern, nonzero indices) of a sub-block; every stage's must have the same pattern."""
        r, c, nz = [], [], []
        for j, col in enumerate(cols):
            for i, row in enumerate(rows):
                z = L.get((int(row), int(col)))
                if z is not None:
                    r.append(i), c.append(j), nz.append(z)
        return ca.Sparsity.triplet(len(rows), len(cols), r, c), nz

    idx = [xc[:, k].tolist() + [int(uc[k])] for k in range(N)]
    parts = []  # per stage: nonzero indices of H_k, Q_k, r_k, p_k, P_k (in a and h)
    pats = None
    for k in range(N):
        R = st["Rk"][k]
        blocks = [block(LH, idx[k], idx[k]), block(LJ, R, xc[:, k]), block(LJ, R, [uc[k]]),
                  (ca.Sparsity.dense(nx, 1), [LJ[(R[i], int(xc[i, k + 1]))] for i in range(nx)]),
                  block(LJ, st["path"][k], idx[k])]
        if pats is None:
            pats = [b[0] for b in blocks]
        assert all(b[0] == p for b, p in zip(blocks, pats)), f"stage {k} has another pattern"
        parts.append([b[1] for b in blocks])
    HN_sp, HN_nz = block(LH, xc[:, N].tolist(), xc[:, N].tolist())

    # the stage Functions
    Ms, Hcs = ca.MX.sym("M", nx, N), ca.MX.sym("Hc", N, N)
    Hk, Qk, rk, pk, Pk = (ca.MX.sym(s, p) for s, p in zip(("H", "Q", "r", "p", "P"), pats))
    e = ca.MX.sym("e", 1, N)
    A, B = -Qk / ca.repmat(pk, 1, nx), -rk / pk
    Z = ca.vertcat(Ms, e)
    M1 = ca.densify(ca.mtimes(A, Ms) + ca.mtimes(B, e))
    stage = ca.Function("cond_stage", [Ms, Hcs, Hk, Qk, rk, pk, Pk, e],
                        [M1, Hcs + ca.mtimes(Z.T, ca.densify(ca.mtimes(Hk, Z))),
                         ca.densify(ca.vertcat(ca.mtimes(Pk, Z), M1[S, :]))])
    t, c_, lam, du_ = ca.MX.sym("t", nx), ca.MX.sym("c", nx), ca.MX.sym("lam", nx), ca.MX.sym("du")
    g_k, lb_k, ub_k = ca.MX.sym("g", nx + 1), ca.MX.sym("lb", npath), ca.MX.sym("ub", npath)
    forward = ca.Function("cond_forward", [t, Qk, rk, pk, c_, du_], [ca.mtimes(A, t) + B * du_ + c_ / pk])
    z = ca.vertcat(t, 0)
    v = ca.mtimes(Hk, z) + g_k
    r = ca.mtimes(Pk, z)
    backward = ca.Function("cond_backward", [lam, t, Hk, Qk, rk, pk, Pk, g_k, lb_k, ub_k],
                           [v[:nx] + ca.mtimes(A.T, lam), v[nx] + ca.mtimes(B.T, lam), lb_k - r, ub_k - r])

    h, a = ca.MX.sym("h", H_sp), ca.MX.sym("a", J_sp)
    g, lbx, ubx = (ca.MX.sym(s, n) for s in ("g", "lbx", "ubx"))
    lba, uba = (ca.MX.sym(s, st["m"]) for s in ("lba", "uba"))

    def data(k, *which):
        src = (h, a, a, a, a)
        return [ca.MX(pats[i], src[i].nz[parts[k][i]]) for i in which]

    M, Hc = ca.MX.zeros(nx, N), ca.MX.zeros(N, N)
    nrow = npath + len(S)
    Ac = ca.MX.zeros(N * nrow, N)
    for k in range(N):
        eye = np.zeros((1, N))
        eye[0, k] = 1.0
        M, Hc, rows = stage(M, Hc, *data(k, 0, 1, 2, 3, 4), ca.DM(eye))
        Ac[k * nrow:(k + 1) * nrow, :] = rows  # an in-place assignment (SetNonzeros on a dying slot)
    Hc = Hc + ca.mtimes(M.T, ca.mtimes(ca.MX(HN_sp, h.nz[HN_nz]), M))
    prep = ca.Function("cond_prep", [h, a], [Hc, Ac], ["h", "a"], ["Hc", "Ac"])

    def x0():
        return ca.vertcat(*[lba[st["R0"][i]] / a[st["R0"][i], int(xc[i, 0])] for i in range(nx)])

    ts = [x0()]
    for k in range(N):
        ts.append(forward(ts[-1], *data(k, 1, 2, 3), lba[st["Rk"][k]], 0))
    lam = ca.mtimes(ca.MX(HN_sp, h.nz[HN_nz]), ts[N]) + g[xc[:, N].tolist()]
    gc, lbA, ubA = [None] * N, [None] * N, [None] * N
    for k in reversed(range(N)):
        P = st["path"][k]
        lam, gc[k], lb, ub = backward(lam, ts[k], *data(k, 0, 1, 2, 3, 4), g[idx[k]], lba[P], uba[P])
        s_cols = xc[S, k + 1].tolist()
        lbA[k] = ca.vertcat(lb, lbx[s_cols] - ts[k + 1][S])
        ubA[k] = ca.vertcat(ub, ubx[s_cols] - ts[k + 1][S])
    feedback = ca.Function("cond_feedback", [h, g, a, lba, uba, lbx, ubx],
                           [ca.vertcat(*gc), ca.vertcat(*lbA), ca.vertcat(*ubA), lbx[uc.tolist()], ubx[uc.tolist()]],
                           ["h", "g", "a", "lba", "uba", "lbx", "ubx"], ["gc", "lbA", "ubA", "lbu", "ubu"])
    du = ca.MX.sym("du", N)
    xs = [x0()]
    for k in range(N):
        xs.append(forward(xs[-1], *data(k, 1, 2, 3), lba[st["Rk"][k]], du[k]))
    order = np.argsort([xc[i, k] for k in range(N + 1) for i in range(nx)] + list(uc))
    stacked = ca.vertcat(*xs, du)
    expand = ca.Function("cond_expand", [a, lba, du], [stacked[order.tolist()]], ["a", "lba", "du"], ["d"])
    return prep, feedback, expand, Hc.sparsity(), Ac.sparsity()


def condensed_step(name, prep, feedback, expand, conic) -> ca.Function:
    """prep, feedback, the condensed QP and the expansion in one MX Function (its work memory is the route's)."""
    h, a = ca.MX.sym("h", prep.sparsity_in(0)), ca.MX.sym("a", prep.sparsity_in(1))
    g, lbx, ubx = (ca.MX.sym(s, feedback.sparsity_in(1)) for s in ("g", "lbx", "ubx"))
    lba, uba = (ca.MX.sym(s, feedback.sparsity_in(3)) for s in ("lba", "uba"))
    lx, la = ca.MX.sym("lam_x0", conic.sparsity_in(8)), ca.MX.sym("lam_a0", conic.sparsity_in(9))
    Hc, Ac = prep(h, a)
    gc, lbA, ubA, lbu, ubu = feedback(h, g, a, lba, uba, lbx, ubx)
    sol = conic(h=Hc, g=gc, a=Ac, lba=lbA, uba=ubA, lbx=lbu, ubx=ubu, lam_x0=lx, lam_a0=la)
    d = expand(a, lba, sol["x"])
    return ca.Function(name, [h, g, a, lba, uba, lbx, ubx, lx, la], [d, sol["x"], sol["lam_x"], sol["lam_a"]],
                       ["h", "g", "a", "lba", "uba", "lbx", "ubx", "lam_x0", "lam_a0"], ["d", "du", "lam_x", "lam_a"])


# -- main ----------------------------------------------------------------------------------------------------
def qrqp_iterations(H_sp, J_sp, qps, opts, warm: bool):
    """qrqp's iteration counts on the sequence (CasADi's plugin: the same algorithm as the generated C)."""
    conic = ca.conic("qrqp_iter", "qrqp", {"h": H_sp, "a": J_sp}, opts)
    iters, lx, la = [], None, None
    for qp in qps:
        extra = dict(lam_x0=lx, lam_a0=la) if warm and lx is not None else {}
        sol = conic(**dict(qp, h=ca.DM(H_sp, qp["h"]), a=ca.DM(J_sp, qp["a"])), **extra)
        st = conic.stats()
        iters.append(st["iter_count"])
        if st["success"]:
            lx, la = sol["lam_x"], sol["lam_a"]
    return iters


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="a 5 s run (about 100 QPs) instead of 12 s")
    ap.add_argument("--qps", help="pickle of captured QPs: loaded if it exists, else written")
    ap.add_argument("--out", help="also write the report here")
    args = ap.parse_args()
    lines = []

    def say(text=""):
        print(text, flush=True)
        lines.append(text)

    say(f"# bench_qp_routes {datetime.datetime.now().isoformat(timespec='seconds')}; {load()} (2 cores, shared "
        f"with other jobs); CasADi {ca.__version__}; {'--quick' if args.quick else 'full'}; gcc -O2; times of "
        f"one call of the compiled C (pinned to one core)")
    duration = 5.0 if args.quick else 12.0
    if args.qps and Path(args.qps).exists():
        data = pickle.load(open(args.qps, "rb"))
    else:
        t0 = time.perf_counter()
        data = capture(duration)
        print(f"captured {len(data['qps'])} QPs in {time.perf_counter() - t0:.0f} s", flush=True)
        if args.qps:
            pickle.dump(data, open(args.qps, "wb"))
    meta, qps = data["meta"], data["qps"]
    if args.quick:
        qps = qps[:100]
    H_sp, J_sp = ca.Sparsity.deserialize(meta["H_sp"]), ca.Sparsity.deserialize(meta["J_sp"])
    n, m, uc = meta["n"], meta["m"], meta["u_cols"]
    say(f"QPs: {len(qps)} consecutive RTI QPs of the N-shape's first {len(qps) * 0.05:.1f} s (N = 60, h = 0.05): "
        f"n = {n}, m = {m} (610 equalities), nnz H {H_sp.nnz()}, J {J_sp.nnz()}")
    pin_one_core()
    folder = Path(tempfile.mkdtemp(prefix="qp_routes_"))
    cands = []  # dicts: label, gen, why, note, call(qp, lx, la) -> (x, lam_x, lam_a, flag, seconds, d), warm, work

    def zeros_if_none(v, size):
        return np.zeros(size) if v is None else v

    def gen_note(gen, f):
        return (f"C {gen.c.stat().st_size / 1024:.0f} kB source, .so {gen.so.stat().st_size / 1024:.0f} kB; ldd: "
                f"{gen.ldd}; malloc: {gen.uses_malloc}; sz_w {f.sz_w()}, sz_iw {f.sz_iw()}, sz_arg {f.sz_arg()}, "
                f"sz_res {f.sz_res()}")

    def full_call(gen):
        def call(qp, lx, la):
            out, flag, dt = gen(qp["h"], qp["g"], qp["a"], qp["lba"], qp["uba"], qp["lbx"], qp["ubx"],
                                zeros_if_none(lx, n), zeros_if_none(la, m))
            return out[0], out[1], out[2], flag, dt, out[0]
        return call

    # HPIPM as the NMPC calls it: CasADi's plugin (libcasadi), and its generated C linked to the wheel's HPIPM
    nmpc_hpipm = {"error_on_fail": False,
                  "hpipm": {"iter_max": 50, "mode": "balance", **{f"res_{r}_max": 1e-6 for r in "gbdm"}}}
    conic, fun = conic_function("hpipm_full", "hpipm", H_sp, J_sp, nmpc_hpipm)

    def plugin_call(qp, lx, la, conic=conic):
        """CasADi's plugin through a numpy buffer (as ``_BufferedQP``: no DM built per call)."""
        buf, ev = conic.buffer()
        keep = []
        for i in range(conic.n_in()):  # every input bound (an unbound one crashed the process)
            name = conic.name_in(i)
            v = np.ascontiguousarray(qp[name], float) if name in qp else np.full(conic.nnz_in(i),
                                                                                  conic.default_in(i))
            keep.append(v)
            buf.set_arg(i, memoryview(v))
        outs = [np.zeros(conic.nnz_out(i)) for i in range(conic.n_out())]
        for i, v in enumerate(outs):
            buf.set_res(i, memoryview(v))
        t0 = time.perf_counter()
        ev()
        dt = time.perf_counter() - t0
        st = buf.stats()
        x, lam_x, lam_a = (outs[conic.index_out(k)] for k in ("x", "lam_x", "lam_a"))
        return x, lam_x, lam_a, 0 if st["success"] else st["return_status"], dt, x
    cands.append(dict(label="hpipm full, plugin (NMPC's opts)", gen="-", call=plugin_call, warm=False,
                      work=work_bytes(fun), why="the NMPC's route today (CasADi's HPIPM plugin in libcasadi, "
                                                "called through a buffer)", note=""))
    gen = Generated(fun, folder)
    if not gen.ok:
        inc = CASADI_DIR / "include"
        gen = Generated(ca.Function("hpipm_full_lib", fun.mx_in(), fun.call(fun.mx_in())), folder,
                        ["-I" + str(inc)], [f"-L{CASADI_DIR}", "-lhpipm", "-lblasfeo", f"-Wl,-rpath,{CASADI_DIR}"])
        why = ("plain gcc: 'hpipm_d_ocp_qp_ipm.h' not found; with the wheel's headers and libhpipm.so/libblasfeo.so "
               "(x86 builds) it compiles" if gen.ok else gen.why)
    if gen.ok:
        why += "; its steps are wrong here (status != 0 on every QP, see fails), not investigated further"
        cands.append(dict(label="hpipm full, gen. C + libhpipm", gen="lib", call=full_call(gen), warm=False,
                          work=work_bytes(fun), why=why, note=gen_note(gen, fun)))

    # qrqp on the full sparse QP
    qrqp_opts = {"error_on_fail": False, "print_iter": False, "print_header": False, "max_iter": 1000}
    conic, fun = conic_function("qrqp_full", "qrqp", H_sp, J_sp, qrqp_opts)
    gen = Generated(fun, folder)
    assert gen.ok, gen.why
    for warm in (True, False):
        cands.append(dict(label=f"qrqp full, {'warm' if warm else 'cold'}", gen="yes", call=full_call(gen),
                          warm=warm, work=work_bytes(fun), why="", note=gen_note(gen, fun) if warm else "",
                          iters=(qrqp_opts, warm)))

    # the condensed QP (60 variables): condensing, dense QP, expansion, each generated
    prep, feedback, expand, Hc_sp, Ac_sp = condense_functions(meta, qps[0])
    bounded = np.isfinite(qps[0]["lbx"]) | np.isfinite(qps[0]["ubx"])
    for qp in qps:  # the bounds the condensing keeps are the same on every QP
        assert np.array_equal(np.isfinite(qp["lbx"]) | np.isfinite(qp["ubx"]), bounded)
    gprep, gfeed, gexp = (Generated(f, folder) for f in (prep, feedback, expand))
    assert gprep.ok and gfeed.ok and gexp.ok, (gprep.why, gfeed.why, gexp.why)
    nA = Ac_sp.size1()
    say(f"condensed QP: {Hc_sp.size1()} variables, {nA} rows (path inequalities, bounded states); condensing "
        f"work memory (kB): prep {work_bytes(prep) / 1024:.0f}, feedback {work_bytes(feedback) / 1024:.0f}, "
        f"expand {work_bytes(expand) / 1024:.0f}; C source {sum(g.c.stat().st_size for g in (gprep, gfeed, gexp)) / 1024:.0f} kB")
    inc = ["-I" + str(CASADI_DIR / "include")]
    for label, plugin, opts, warm, flags, libs, gen_flag, why in (
            ("cond + qrqp, warm", "qrqp", qrqp_opts, True, (), (), "yes", ""),
            ("cond + qrqp, cold", "qrqp", qrqp_opts, False, (), (), "yes", ""),
            ("cond + daqp", "daqp", {"error_on_fail": False}, False, inc, [str(CASADI_DIR / "libdaqpstat.a")], "lib",
             "C calls DAQP: needs its headers and library (the wheel's x86 libdaqpstat.a linked in here); DAQP's "
             "setup mallocs and frees its factors on every solve (not in sz_w); generated code ignores DAQP "
             "options (daqp_default_settings) and warm starts")):
        conic, fun = conic_function(f"cond_{plugin}", plugin, Hc_sp, Ac_sp, opts)
        gen = Generated(fun, folder, flags, libs)
        step = condensed_step(f"cond_step_{plugin}", prep, feedback, expand, conic)
        split = ([], [], [])

        def call(qp, lx, la, gen=gen, split=split):
            (Hc, Ac), _f, dt_p = gprep(qp["h"], qp["a"])
            (gc, lbA, ubA, lbu, ubu), _f, dt_f = gfeed(qp["h"], qp["g"], qp["a"], qp["lba"], qp["uba"],
                                                       qp["lbx"], qp["ubx"])
            out, flag, dt = gen(Hc, gc, Ac, lbA, ubA, lbu, ubu, zeros_if_none(lx, Hc_sp.size1()),
                                zeros_if_none(la, nA))
            (d,), _f, dt_e = gexp(qp["a"], qp["lba"], out[0])
            for s, t in zip(split, (dt_p, dt_f, dt_e)):
                s.append(t)
            return out[0], out[1], out[2], flag, dt, d
        cands.append(dict(label=label, gen=gen_flag, call=call, warm=warm, work=work_bytes(step), why=why,
                          note=(f"QP alone {work_bytes(fun) / 1024:.0f} kB; " + gen_note(gen, fun)) if warm or
                          plugin == "daqp" else "", split=split, iters=(qrqp_opts, warm, Hc_sp, Ac_sp, prep,
                                                                         feedback) if plugin == "qrqp" else None))
        if not gen.ok:
            raise RuntimeError(f"{label}: {gen.why}")

    # the conic plugins that do not generate C
    no_gen = []
    for plugin in ("ipqp", "qpoases", "osqp", "daqp", "fatrop", "piqp", "proxqp", "highs", "superscs", "clarabel"):
        if not ca.has_conic(plugin):
            no_gen.append(f"{plugin}: not in this build")
            continue
        try:
            _c, fun = conic_function(f"full_{plugin}", plugin, H_sp, J_sp, {"error_on_fail": False})
        except RuntimeError as exc:
            no_gen.append(f"{plugin}: {str(exc).splitlines()[-1][:80]}")
            continue
        gen = Generated(fun, folder)
        text = gen.c.read_text()
        if gen.error:
            no_gen.append(f"{plugin}: '{gen.error[:60]}'")
        else:
            heads = sorted({line.split("<")[1].split(">")[0] for line in text.splitlines()
                            if line.startswith("#include <") and any(s in line for s in ("/", "_c_api", "daqp"))})
            no_gen.append(f"{plugin}: C generated, but it includes {', '.join(heads)} (the solver's library)"
                          + (f"; dense H and A: {8 * (n * n + m * n) / 1e6:.1f} MB" if plugin == "daqp" else ""))

    # -- evaluation on the real QPs and on a stress set
    stress = []
    for qp in qps:  # the motor acceleration bounds narrowed to 20 %, around the current point (still feasible
        qp = dict(qp)  # for the controls: lbx <= 0 <= ubx)
        for k in ("lbx", "ubx"):
            qp[k] = qp[k].copy()
            qp[k][uc] *= 0.2
        stress.append(qp)
    for set_name, qset in (("the N-shape's QPs", qps), ("STRESS (synthetic): the same QPs, motor acceleration "
                                                        "bounds x 0.2", stress)):
        tight = {"iter_max": 300, "mode": "robust", **{f"res_{r}_max": 1e-8 for r in "gbdm"}}
        ref_conic = ca.conic("ref", "hpipm", {"h": H_sp, "a": J_sp}, {"error_on_fail": False, "hpipm": tight})
        ref, ref_fail, act_rows, act_bounds = [], 0, [], []
        ineq = meta["lbg"] != meta["ubg"]
        for qp in qset:
            d = np.array(ref_conic(**dict(qp, h=ca.DM(H_sp, qp["h"]), a=ca.DM(J_sp, qp["a"])))["x"]).ravel()
            ref_fail += not ref_conic.stats()["success"]
            ref.append(d)
            rows = np.array(ca.DM(J_sp, qp["a"]) @ ca.DM(d)).ravel()
            act_rows.append(int(np.sum(ineq & ((rows - qp["lba"] < 1e-7) | (qp["uba"] - rows < 1e-7)))))
            act_bounds.append(int(np.sum((d - qp["lbx"] < 1e-7) | (qp["ubx"] - d < 1e-7))))
        say()
        say(f"== {set_name}: {len(qset)} QPs, {load()}")
        say(f"reference: HPIPM 'robust', residuals 1e-8 (1e-9 stagnates at iter_max): {ref_fail} not 'success'; "
            f"active path inequalities per QP: max {max(act_rows)}; active bounds per QP: median "
            f"{int(np.median(act_bounds))}, max {max(act_bounds)} ({sum(a > 0 for a in act_bounds)} QPs with any)")
        say(f"{'route':33s} {'gen C':5s} {'max|du0-ref|':>12s} {'max|d-ref|':>10s} {'ms: median':>11s} "
            f"{'p95':>7s} {'max':>7s} {'work kB':>8s} {'fails':>5s}")
        steps = {}  # each route's steps, for the cross-check of the exact (active-set) solvers
        for c in cands:
            if "split" in c:
                for s in c["split"]:
                    s.clear()
            times, du0, dstep, fails, lx, la = [], [], [], [], None, None
            for i, qp in enumerate(qset):
                x, lam_x, lam_a, flag, dt, d = c["call"](qp, lx if c["warm"] else None, la if c["warm"] else None)
                viol = violation(qp, J_sp, d) if np.all(np.isfinite(d)) else np.inf
                if flag != 0 or viol > TOL_FEAS:
                    fails.append(f"QP {i}: flag {flag}, violation {viol:.1e}")
                times.append(dt)
                du0.append(abs(d[uc[0]] - ref[i][uc[0]]) if np.isfinite(d[uc[0]]) else np.inf)
                dstep.append(np.max(np.abs(d - ref[i])))
                if flag == 0 and np.all(np.isfinite(lam_x)):
                    lx, la = lam_x, lam_a
                steps.setdefault(c["label"], []).append(d)
            say(f"{c['label']:33s} {c['gen']:5s} {max(du0):12.2e} {max(dstep):10.2e} {stats_ms(times)} "
                f"{c['work'] / 1024:8.0f} {len(fails):5d}")
            if c.get("iters") and len(c["iters"]) == 2:
                it = qrqp_iterations(H_sp, J_sp, qset, *c["iters"])
                say(f"    qrqp iterations: median {np.median(it):.0f}, p95 {np.percentile(it, 95):.0f}, max {max(it)}; "
                    f"ms per iteration ~ {np.median(np.array(times) / np.maximum(it, 1)) * 1e3:.2f}")
            if "split" in c:
                tp, tf, te = c["split"]
                say(f"    condensing ms (median p95 max): prep {stats_ms(tp)} | feedback {stats_ms(tf)} | "
                    f"expand {stats_ms(te)}")
            for f in fails[:3]:
                say(f"    failed: {f}")
            if set_name.startswith("the"):
                for text in (c["why"], c["note"]):
                    if text:
                        say(f"    {text}")
        pairs = [("qrqp full, cold", "cond + daqp"), ("qrqp full, warm", "qrqp full, cold"),
                 ("qrqp full, cold", "cond + qrqp, cold")]
        for one, two in pairs:
            if one in steps and two in steps:
                a1, a2 = np.array(steps[one]), np.array(steps[two])
                say(f"cross-check {one} vs {two}: max |du0 diff| {np.max(np.abs(a1[:, uc[0]] - a2[:, uc[0]])):.1e}, "
                    f"max |d diff| {np.max(np.abs(a1 - a2)):.1e} (the exact solvers agree far below their distance "
                    f"from the reference: that distance is HPIPM's own error at residuals 1e-8)")
    say()
    say("plugins that do not generate self-contained C (an MX Function calling them, generated and compiled):")
    for text in no_gen:
        say(f"    {text}")
    say(f"end: {load()}")
    if args.out:
        Path(args.out).write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
