"""Throughput of the campaign engine: cases per second with 1 and 2 workers, and what one case costs.

Two workloads, each run in this process (``--workers 1``) and on a local Dask
cluster of 2 worker processes, each into a fresh folder:

* design points (the ``design`` kind, 30 speeds): cheap cases, so the figure
  is the engine's own overhead per case (Dask scheduling, rows, part files);
* PID courses (the ``closed_loop`` kind): random courses whose robots are
  drawn near the prototype (so the paper's PID accepts them all), the
  courses' own durations: the cost of a real closed-loop case.

For each: cases, wall time (cluster start included), start-up time, cases
per second over the wall time and after start-up, and the median time per
case measured in the workers.  The last block plans a campaign from these
figures (see the README's "Campaigns at scale").

Run: .venv/bin/python benchmarks/bench_campaign.py [--design N] [--courses N] [--result FILE]
"""

import argparse
import os
import shutil
import tempfile
from pathlib import Path

from rollbot_oc.campaign import campaign_from_dict, run_campaign
from rollbot_oc.core.outputs import atomic_write_text

DESIGN = {"name": "bench_design", "kind": "design",
          "design": {"speeds": 30, "reference": False, "grid": {"phi_deg": {"from": 30, "to": 60, "steps": 10}}}}
NEAR_PROTOTYPE = {"phi_deg": [44.0, 46.0], "m": [0.30, 0.31], "r0": [0.090, 0.095], "R": [0.118, 0.122]}


def workloads(design_cases: int, courses: int) -> dict:
    m_steps = max(1, design_cases // 10)
    design = {**DESIGN, "design": {**DESIGN["design"], "grid": {
        **DESIGN["design"]["grid"], "m": {"from": 0.2, "to": 0.45, "steps": m_steps}}}}
    pid = {"name": "bench_pid", "kind": "closed_loop", "seed": 1,
           "closed_loop": {"courses": courses, "controllers": ["pid"], "ranges": NEAR_PROTOTYPE}}
    return {"design points": design, "PID courses": pid}


def measure(spec: dict, workers: int) -> dict:
    folder = Path(tempfile.mkdtemp(prefix="bench_campaign_"))
    try:
        summary = run_campaign(campaign_from_dict(spec, spec["name"]), folder, workers=workers, figures=False).summary
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    compute = summary["wall_time"] - summary["startup_time"]
    return {**summary, "steady_rate": summary["cases"] / compute if compute > 0 else None}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--design", type=int, default=100, help="design points (default 100)")
    parser.add_argument("--courses", type=int, default=6, help="PID courses (default 6)")
    parser.add_argument("--result", help="also write the report to this file")
    args = parser.parse_args()
    lines = ["Campaign throughput (2-core machine shared with other work; wall time includes the cluster's start)", ""]
    per_case = {}
    for name, spec in workloads(args.design, args.courses).items():
        for workers in (1, 2):
            s = measure(spec, workers)
            per_case.setdefault(name, s["case_time_median"])  # one worker: the least contended measure
            line = (f"  {name:<14} workers {workers}  cases {s['cases']:4d}  wall {s['wall_time']:7.1f} s  "
                    f"start-up {s['startup_time']:5.1f} s  {s['cases_per_second']:8.2f} cases/s  "
                    f"({s['steady_rate']:8.2f} after start-up)  per case median {s['case_time_median']:.3f} s  "
                    f"succeeded {s['succeeded']}/{s['cases']}  load average {os.getloadavg()[0]:.1f}")
            print(line, flush=True)
            lines.append(line)
    lines += ["", "Planning 10,000 PID courses on 50 nodes of 2 cores (100 workers), from the one-worker median per case:",
              f"  {10_000 * per_case['PID courses'] / 100 / 60:.1f} min of computing, plus the cluster's start"]
    text = "\n".join(lines) + "\n"
    if args.result:
        atomic_write_text(args.result, text)


if __name__ == "__main__":
    main()
