"""The exported C project: the NMPC's own step replayed on this machine, its time, code and data size.

Exports the N-shape (``rollbot-oc export-c``: the NMPC with ``NMPCSettings.embedded()``, its run recorded at the
step's boundary), builds it (``make``, the hand-written C at -std=c99 -O2 linked to the step's library, the NMPC's
own -O1 build) and replays the whole recorded run three times (``replay``): the step's time over every period and
over the solves (one RTI each), median, p95 and max, pinned to one core (``_one_core``), against the Python NMPC's
own step times in the recorded run.  The Cortex-M7's instructions, RAM and flash are ``bench_firmware.py``'s.

Run: .venv/bin/python benchmarks/bench_export_c.py [--out DIR]
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

from rollbot_oc.export.project import build, export_c
from rollbot_oc.scenarios.bundled import load_bundled


def _one_core():
    """Pin the replay to one core, as a control loop runs: a process that migrates between cores refills their
    caches with its work arrays."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})


def replay_times(folder: Path) -> dict:
    out = subprocess.run(["./replay", "replay_log.bin"], cwd=folder, capture_output=True, text=True, check=True,
                         preexec_fn=_one_core).stdout
    found = {}
    for what in ("all periods", "solves"):
        m = re.search(rf"step time {what} \((\d+)\): median (\S+) us, p95 (\S+) us, max (\S+) us, mean (\S+) us", out)
        found[what] = (int(m.group(1)), float(m.group(2)), float(m.group(3)), float(m.group(4)), float(m.group(5)))
    found["diff"] = float(re.search(r"max \|diff\| = (\S+)", out).group(1))
    found["context"] = int(re.search(r"context: (\d+) bytes", out).group(1))
    return found


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
    m = result.metrics
    print(f"Exported NMPC step (NMPCSettings.embedded()), N-shape (bundled), {len(result.log)} periods of 10 ms, "
          f"{result.solves} solves, 2-core machine shared with other work")
    print(f"  export {exported:.1f} s (the NMPC's run recorded), build (make -j2: the hand-written C, the step's "
          f"library reused) {built:.1f} s")
    print(f"  the recorded run: completed {m['completed']} in {m['completion_time']:.2f} s, stop errors "
          f"{', '.join(f'{100 * e:.1f}' for e in m['stop_errors'])} cm")
    runs = [replay_times(folder) for _ in range(3)]
    print(f"  replay: max |diff| = {max(r['diff'] for r in runs):.3e} rad/s^2 against the Python NMPC's step")
    for what in ("all periods", "solves"):
        n = runs[0][what][0]
        med = statistics.median(r[what][1] for r in runs)
        p95 = statistics.median(r[what][2] for r in runs)
        top = max(r[what][3] for r in runs)
        print(f"  C step, {what:11s} ({n:4d}): median {med:8.1f} us  p95 {p95:8.1f} us  max {top:8.1f} us "
              "(measure, solve, commit; median of 3 replays; max of all)")
    t = 1e6 * np.asarray(m["solve_time_median"] and [m["solve_time_median"], m["solve_time_p95"], m["solve_time_max"]])
    print(f"  Python NMPC's solves in the recorded run (the same compiled step): median {t[0]:8.1f} us  p95 {t[1]:8.1f} us"
          f"  max {t[2]:8.1f} us")
    s = result.sizes
    print(f"\nData: context (rollbot_context, static) {runs[0]['context']} bytes: memory {s['memory_bytes']} bytes, "
          f"work arrays {s['work_bytes']} bytes (sz_arg {s['sz_arg']}, sz_res {s['sz_res']} pointers, sz_iw "
          f"{s['sz_iw']} ints, sz_w {s['sz_w']} doubles); a reference window {s['window_bytes']} bytes")
    print("Code (host, x86-64, the step's library at -O1; text includes the constant sparsity tables):")
    out = subprocess.run(["size", "librollbot_step.so", "rollbot_controller.o", "rollbot_data.o"], cwd=folder,
                         capture_output=True, text=True, check=True).stdout
    print("  " + out.strip().replace("\n", "\n  "))


if __name__ == "__main__":
    main()
