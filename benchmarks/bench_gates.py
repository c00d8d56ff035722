"""Random courses of gates under the NMPC: how many pass every gate within its tolerance, and how fast.

Each course is ``courses.random_gate_course(seed, index)`` (3 to 6 gates, 0.4 to 1.2 m apart, turns up to
120 deg, slopes to 2 deg, random robots, sensors and +-10 % model error), run in closed loop with the
controller's believed model and the course's sensor noise, for at most ``20 + 8 n`` s of simulated time
(n gates; the course's own duration is sized for the slow PID).  A course passes when the run completed
(every gate within its tolerance, no contact event) without a torque or speed violation; otherwise its row
says why.  Prints one row per course as it ends and a summary; ``--out FILE`` also writes them (Markdown).

Run: .venv/bin/python benchmarks/bench_gates.py [--courses 50] [--workers 2] [--quick] [--out FILE]
"""

from __future__ import annotations

import argparse
import datetime
import os
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor


def run_course(index: int, seed: int = 0) -> dict:
    from rollbot_oc.scenarios.courses import random_gate_course
    from rollbot_oc.core.errors import NotConverged
    from rollbot_oc.scenarios.problem import run_problem

    course = random_gate_course(seed, index)
    row = {"course": index, "gates": course.inputs["n_gates"], "length": round(course.inputs["length"], 2),
           "slope_deg": round(course.inputs["slope_deg"], 2)}
    start = time.perf_counter()
    try:
        duration = min(course.problem.duration, 20.0 + 8.0 * row["gates"])
        m = run_problem(course.problem, "nmpc", seed=course.noise_seed, params=course.believed, duration=duration,
                        show_progress=False).metrics
    except NotConverged as exc:  # the plan through the gates failed before the robot moved
        return {**row, "passed": False, "why": f"no plan: {exc.status}", "wall": time.perf_counter() - start}
    why = []
    if not m["completed"]:
        why.append(f"{m.get('gates_passed', 0)} of {row['gates']} gates passed")
    if m["torque_limit_violation"] or m["speed_limit_violation"]:
        why.append("motor limit exceeded")
    if m.get("events"):
        why.append("left the no-slip model")
    misses = m.get("gate_misses") or []
    return {**row, "passed": not why, "why": "; ".join(why), "time": m.get("completion_time"),
            "worst_miss_cm": round(100 * max(misses), 2) if misses else None, "replans": m.get("stop_replans"),
            "plan_failures": m.get("plan_failures"), "plan_iterations": [p["iterations"] for p in m.get("plans", [])],
            "wall": time.perf_counter() - start}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--courses", type=int, default=50)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--quick", action="store_true", help="the first 4 courses")
    parser.add_argument("--out", help="write the table and summary here (Markdown)")
    args = parser.parse_args()
    count = 4 if args.quick else args.courses
    rows = []
    with ProcessPoolExecutor(args.workers) as pool:
        for row in pool.map(run_course, range(count)):
            print(row, flush=True)
            rows.append(row)
    lines = [f"# bench_gates {datetime.datetime.now().isoformat(timespec='seconds')}: {count} random gate courses "
             f"(seed 0), NMPC, {args.workers} workers, load {os.getloadavg()[0]:.1f}", "",
             "| course | gates | length m | slope deg | passed | time s | worst miss cm | replans | plan failures "
             "| why |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['course']} | {r['gates']} | {r['length']} | {r['slope_deg']} | {r['passed']} | "
                     f"{r.get('time')} | {r.get('worst_miss_cm')} | {r.get('replans')} | {r.get('plan_failures')} | "
                     f"{r['why']} |")
    passed = [r for r in rows if r["passed"]]
    times = [r["time"] for r in passed]
    lines += ["", f"passed {len(passed)} of {count}" + (f"; completion time median {statistics.median(times):.2f} s, "
                                                        f"max {max(times):.2f} s" if times else "")]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
