"""NMPC solve times: IPOPT against real-time iterations (interpreted and compiled), and the OCP's Hessians.

Closed-loop runs on the full plant (1 deg slope, noise, latency); each prints
the median, 95th percentile and largest solve time over all solves of the run.
IPOPT runs without the real-time limit (``max_solve_time``) so that its solves
are used and measured rather than replaced by fallbacks.
Run: .venv/bin/python benchmarks/bench_nmpc.py [--quick]
"""

import statistics
import sys
import time

from rollbot_oc.model.codegen import compiler
from rollbot_oc.control.nmpc import NMPCSettings
from rollbot_oc.planning.min_time import OCPSettings, RestToRest
from rollbot_oc.model.dynamics import rest_state
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.scenarios.problem import load_problem, run_problem


def closed_loop(label, problem, settings, duration=None):
    m = run_problem(problem, "nmpc", settings=settings, duration=duration).metrics
    print(f"  {label:34s} solves {m['solves']:5d}  median {1e3 * m['solve_time_median']:7.2f} ms  "
          f"p95 {1e3 * m['solve_time_p95']:7.2f} ms  max {1e3 * m['solve_time_max']:7.2f} ms  "
          f"failed {m['failed_solves']}  late {m['late_solves']}  fallbacks {m['fallback_shifted']}/{m['fallback_pid']}"
          f"  completion {m['completion_time']}")
    if m.get("plan_solves"):
        print(f"  {'':34s} first command after {m['plan_time']:.2f} s; {m['plan_solves']} leg plans while moving, "
              f"median {m['plan_solve_time_median']:.2f} s, max {m['plan_solve_time_max']:.2f} s, "
              f"waited {m['plan_wait']:.1f} s at stops")
    return m


def main():
    quick = "--quick" in sys.argv
    n_shape = load_problem("problems/n_shape.toml")
    circle = load_problem("problems/circle_R050.toml")
    default = NMPCSettings()
    print(f"NMPC solve times, N = {default.horizon.N} intervals of {default.horizon.h} s, 10 states, RK4 x{default.horizon.substeps} "
          "(2-core machine)")
    closed_loop("RTI, compiled C (default)" if compiler() else "RTI (no C compiler)", n_shape, default)
    closed_loop("RTI, 30 intervals of 0.1 s, RK4 x2", n_shape, NMPCSettings(horizon={"N": 30, "h": 0.1, "substeps": 2}, recovery={"max_failures": 3}))
    closed_loop("RTI, CasADi virtual machine", n_shape, NMPCSettings(horizon={"compiled": False}))
    closed_loop("RTI on a circle (compiled)", circle, NMPCSettings(), duration=60.0 if quick else 300.0)
    closed_loop("IPOPT, exact Hessian, converged", circle, NMPCSettings(horizon={"solver": "ipopt"}, timing={"max_solve_time": 60.0}),
                duration=2.5 if quick else 10.0)

    print("\nMinimum-time rest-to-rest OCP, 1.2 m leg, N = 60 (median of 3)")
    params = RollbotParams()
    start = rest_state(params)
    for label, settings in (("limited-memory", OCPSettings()), ("exact", OCPSettings(hessian="exact")),
                            ("l-m, compiled", OCPSettings(compiled=True))):
        ocp = RestToRest(params, settings)
        times, iters = [], []
        for _ in range(3):
            t0 = time.perf_counter()
            plan = ocp.solve(start, [0.0, 1.2])
            times.append(time.perf_counter() - t0)
            iters.append(plan.iterations)
        print(f"  IPOPT {label:15s} median {statistics.median(times):6.2f} s  iterations {iters[0]}  "
              f"T = {plan.T:.2f} s")


if __name__ == "__main__":
    main()
