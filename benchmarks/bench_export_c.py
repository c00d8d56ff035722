"""The exported C controller: its step time on this machine, its code and data size, and its cost on a Cortex-M.

1. Exports the N-shape (``rollbot-oc export-c``), builds it (``make``, -std=c99 -O2) and replays the whole
   recorded log three times (``replay``): the step's time over every period and over the solve instants
   (one RTI each), median, p95 and max, pinned to one core (``_one_core``); the Python embedded controller
   (the same Function in CasADi's virtual machine) on the same run for comparison.
2. Code and data: ``size`` of the objects, the context the step works in (bytes).
3. With ``--ops`` (several minutes): the operations the step executes over the whole log, counted by
   valgrind's lackey on a build whose floating-point arithmetic is x87 (``-mfpmath=387``: every
   double-precision operation is then an ``F64`` operation of valgrind's IR), and from them the cycles
   on a Cortex-M7 with a double-precision FPU and a Cortex-M4F (single-precision FPU only: doubles in
   software).  The cycle model and its assumptions are printed with the figures.

Run: .venv/bin/python benchmarks/bench_export_c.py [--ops] [--out DIR]
"""

import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rollbot_oc.export.project import build, embedded_controller, export_c
from rollbot_oc.scenarios.problem import run_problem
from rollbot_oc.scenarios.bundled import load_bundled

# Cortex-M cycle model (stated assumptions, not measurements)
THUMB_PER_X86 = 1.3  # Thumb-2 instructions per x86-64 instruction for this code (loads/stores not folded)
M7_CPI, M7_FP64 = 1.0, 3.0  # M7: integer/memory instructions at ~1 cycle (dual issue offsets stalls);
# an FPv5-D16 double add/multiply ~3 cycles with its dependency (divides and square roots, rare here, ~30)
M4_SOFT_FP64 = 60.0  # M4F: no double FPU, a libgcc soft-float double operation ~40-100 cycles
CLOCKS = {"Cortex-M7 (DP FPU), 480 MHz": (480e6, "m7"), "Cortex-M7 (DP FPU), 216 MHz": (216e6, "m7"),
          "Cortex-M4F (SP FPU only), 168 MHz": (168e6, "m4")}


def _one_core():
    """Pin the replay to one core, as a control loop runs: a process that migrates between cores refills their
    caches with its work arrays."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})


def replay_times(folder: Path) -> dict:
    out = subprocess.run(["./replay", "replay_log.txt"], cwd=folder, capture_output=True, text=True, check=True,
                         preexec_fn=_one_core).stdout
    found = {}
    for what in ("all periods", "solve instants"):
        m = re.search(rf"step time {what} \((\d+)\): median (\S+) us, p95 (\S+) us, max (\S+) us, mean (\S+) us", out)
        found[what] = (int(m.group(1)), float(m.group(2)), float(m.group(3)), float(m.group(4)), float(m.group(5)))
    found["diff"] = float(re.search(r"max \|diff\| = (\S+)", out).group(1))
    found["context"] = int(re.search(r"context: (\d+) bytes", out).group(1))
    return found


def python_times(problem) -> dict:
    controller = embedded_controller(problem)[0]
    run = run_problem(problem, controller, show_progress=False)
    times = run.result.step_times
    status = np.asarray(controller.statuses)
    solves = times[(status == 0) | (status == 2)]
    return {"all periods": times, "solve instants": solves, "metrics": run.metrics}


def sizes(folder: Path) -> str:
    objects = ["rollbot_period.o", "rollbot_data.o", "rollbot_controller.o"]
    return subprocess.run(["size", *objects], cwd=folder, capture_output=True, text=True, check=True).stdout


def op_counts(folder: Path) -> dict:
    """Guest instructions and F64 operations over the whole log (valgrind lackey, x87 arithmetic)."""
    sources = ["main.c", "rollbot_period.c", "rollbot_data.c", "rollbot_controller.c"]
    subprocess.run(["cc", "-std=c99", "-O2", "-mfpmath=387", "-o", "replay_x87", *sources, "-lm"], cwd=folder,
                   check=True)
    out = subprocess.run(["valgrind", "--tool=lackey", "--detailed-counts=yes", "./replay_x87", "replay_log.txt",
                          "1e-6"], cwd=folder, capture_output=True, text=True).stderr
    instrs = int(re.search(r"guest instrs:\s+([\d,]+)", out).group(1).replace(",", ""))
    f64 = [int(v.replace(",", "")) for v in re.search(r"F64\s+([\d,]+)\s+([\d,]+)\s+([\d,]+)", out).groups()]
    return {"instrs": instrs, "f64_loads": f64[0], "f64_stores": f64[1], "f64_ops": f64[2]}


def main():
    problem = load_bundled("n_shape")
    args = sys.argv[1:]
    folder = Path(args[args.index("--out") + 1]) if "--out" in args else Path(tempfile.mkdtemp()) / "rollbot_c"
    start = time.perf_counter()
    result = export_c(folder, problem)
    exported = time.perf_counter() - start
    start = time.perf_counter()
    made = build(folder, jobs=2)
    if made.returncode:
        raise SystemExit(made.stderr)
    built = time.perf_counter() - start
    periods = result.log.shape[0]
    print(f"Exported controller, N-shape (bundled), {periods} periods of 10 ms, 2-core machine shared with other work")
    print(f"  export {exported:.1f} s (legs planned, Python run recorded), build (make -j2, -O2) {built:.1f} s")
    runs = [replay_times(folder) for _ in range(3)]
    print(f"  replay: max |diff| = {max(r['diff'] for r in runs):.3e} rad/s^2 against the Python commands")
    for what in ("all periods", "solve instants"):
        n = runs[0][what][0]
        med = statistics.median(r[what][1] for r in runs)
        p95 = statistics.median(r[what][2] for r in runs)
        top = max(r[what][3] for r in runs)
        print(f"  C step, {what:15s} ({n:4d}): median {med:8.1f} us  p95 {p95:8.1f} us  max {top:8.1f} us "
              "(median of 3 replays; max of all)")
    py = python_times(problem)
    for what in ("all periods", "solve instants"):
        t = py[what] * 1e6
        print(f"  Python step (CasADi VM), {what:15s} ({t.size:4d}): median {np.median(t):8.1f} us  "
              f"p95 {np.percentile(t, 95):8.1f} us  max {t.max():8.1f} us")
    m = py["metrics"]
    print(f"  the run: completed {m['completed']} in {m['completion_time']:.2f} s, stop errors "
          f"{', '.join(f'{100 * e:.1f}' for e in m['stop_errors'])} cm")
    s = result.sizes
    print("\nCode and data (host, x86-64 gcc -O2; text includes the constant sparsity tables):")
    print("  " + sizes(folder).strip().replace("\n", "\n  "))
    print(f"  context (rollbot_context, static): {runs[0]['context']} bytes: memory {s['memory_bytes']} bytes, "
          f"work arrays {s['work_bytes']} bytes (sz_arg {s['sz_arg']}, sz_res {s['sz_res']} pointers, "
          f"sz_iw {s['sz_iw']} ints, sz_w {s['sz_w']} doubles), reference windows {s['reference_bytes']} bytes")
    if "--ops" not in args:
        return
    ops = op_counts(folder)
    solves = runs[0]["solve instants"][0]
    print(f"\nOperations over the whole log (valgrind lackey, x87 build): {ops['instrs']:,} x86-64 instructions, "
          f"{ops['f64_ops']:,} double-precision operations (with {ops['f64_loads']:,} loads and "
          f"{ops['f64_stores']:,} stores); includes reading the log and the replay's own work")
    per = {k: v / solves for k, v in ops.items()}
    between = result.step.every - 1
    print(f"  per solve instant (the whole log's count over its {solves} solve instants, the {between} cheap periods "
          f"between included): {per['instrs'] / 1e6:.2f} M instructions, {per['f64_ops'] / 1e6:.2f} M double operations")
    other = per["instrs"] - per["f64_ops"] - per["f64_loads"] - per["f64_stores"]
    fp = per["f64_ops"]
    cycles = {"m7": THUMB_PER_X86 * (other + per["f64_loads"] + per["f64_stores"]) * M7_CPI + M7_FP64 * fp,
              "m4": THUMB_PER_X86 * (other + per["f64_loads"] + per["f64_stores"]) + M4_SOFT_FP64 * fp}
    print(f"  cycle model: Thumb-2 = {THUMB_PER_X86} x the x86-64 non-arithmetic instructions at CPI {M7_CPI}; "
          f"a double operation {M7_FP64} cycles on an M7's DP FPU, {M4_SOFT_FP64} cycles in software on an M4F")
    host = runs[0]["solve instants"]
    ratio = host[1] / host[4]  # the host's median solve instant over its mean: the counts are totals
    print(f"  the host's median solve instant is {ratio:.2f} of its mean (and its max {host[3] / host[4]:.1f} times the "
          "mean): the median below is the mean scaled by that ratio")
    for name, (hz, core) in CLOCKS.items():
        mean = 1e3 * cycles[core] / hz
        print(f"  {name:36s} {cycles[core] / 1e6:7.1f} M cycles per solve instant on average = {mean:7.1f} ms, "
              f"median about {ratio * mean:7.1f} ms, max about {host[3] / host[4] * mean:7.1f} ms "
              f"(the interval is {1e3 * result.step.h:.0f} ms)")


if __name__ == "__main__":
    main()
