"""Tune the quasi-stable PID baseline: a grid search over gains and the acceleration limit.

The NMPC is judged against this baseline, so the baseline gets its best honest
tuning within the paper's design.  Every candidate runs the full nonlinear
plant on the 1 deg slope with sensor noise:

* the N-shape (completion time; every stop must be within 5 cm, a margin on
  the paper's 7 cm), and
* the hardest circle, R_g = 0.65 m (average and maximum deviation).

The best candidates on the N-shape are then checked on all four circles.
Run: .venv/bin/python benchmarks/tune_pid.py [--quick]   (2 worker processes)
"""

import itertools
import json
import sys
import time
from multiprocessing import Pool

from rollbot_oc.control.pid import PIDGains
from rollbot_oc.scenarios.problem import load_problem, run_problem

GRID = dict(kp=[0.3, 0.6, 1.2], ki=[0.05, 0.1, 0.2], kr=[0.3, 0.6], max_accel=[1.0, 2.0, 4.0, 8.0], max_radius=[0.9])
QUICK = dict(kp=[0.3, 1.2], ki=[0.05], kr=[0.1, 0.3], max_accel=[0.5, 2.0], max_radius=[0.9])
STOP_LIMIT = 0.05  # m


def evaluate(kwargs):
    gains = PIDGains(**kwargs)
    n = run_problem(load_problem("problems/n_shape.toml"), "pid", gains=gains).metrics
    c = run_problem(load_problem("problems/circle_R065.toml"), "pid", gains=gains).metrics
    ok = n["completed"] and max(n["stop_errors"], default=1.0) <= STOP_LIMIT and c["completed"]
    return dict(gains=kwargs, ok=bool(ok), n_time=n["completion_time"], stops=n["stop_errors"],
                c_avg=c["avg_deviation"], c_max=c["max_deviation"])


def circles(kwargs):
    gains = PIDGains(**kwargs)
    out = {}
    for name in ("circle_R020", "circle_R035", "circle_R050", "circle_R065"):
        m = run_problem(load_problem(f"problems/{name}.toml"), "pid", gains=gains).metrics
        out[name] = (m["avg_deviation"], m["max_deviation"])
    return out


def main():
    grid = QUICK if "--quick" in sys.argv else GRID
    candidates = [dict(zip(grid, values)) for values in itertools.product(*grid.values())]
    start = time.perf_counter()
    with Pool(2) as pool:
        results = pool.map(evaluate, candidates)
    good = sorted((r for r in results if r["ok"]), key=lambda r: r["n_time"])
    print(f"{len(candidates)} candidates in {time.perf_counter() - start:.0f} s; {len(good)} meet the stop limit")
    print(f"{'kp':>5} {'ki':>5} {'kr':>5} {'acc':>5} {'N time (s)':>10} {'max stop (cm)':>13} "
          f"{'R065 avg/max (cm)':>18}")
    for r in good[:10]:
        g = r["gains"]
        print(f"{g['kp']:5.2f} {g['ki']:5.2f} {g['kr']:5.2f} {g['max_accel']:5.2f} {r['n_time']:10.1f} "
              f"{100 * max(r['stops']):13.1f} {100 * r['c_avg']:8.2f}/{100 * r['c_max']:.2f}")
    with Pool(2) as pool:
        checked = pool.map(circles, [r["gains"] for r in good[:4]])
    for r, c in zip(good[:4], checked):
        print(json.dumps({"gains": r["gains"], "n_time": r["n_time"],
                          "circles_cm": {k: [round(100 * v, 2) for v in vals] for k, vals in c.items()}}))


if __name__ == "__main__":
    main()
