"""The long version of tests/test_nmpc.py::test_model_error_of_ten_percent: the N-shape's first two stops, not the
first alone.

The plant's masses and damping (``M_s``, ``m``, ``m_b``, ``k0``) 0.9 and 1.1 times the controller's model: the NMPC
reaches both stops within 7 cm, at rest, within the plant's limits.  Asserts what the test asserted on the
two-stop run and prints the figures (the wall time is only reported).

Run: .venv/bin/python benchmarks/bench_model_error.py
"""

import time
from dataclasses import replace

from rollbot_oc.model.params import RollbotParams
from rollbot_oc.scenarios.problem import run_problem
from rollbot_oc.scenarios.bundled import load_bundled


def main():
    base = load_bundled("n_shape")
    p = base.params
    for scale in (0.9, 1.1):
        plant = p.replace(M_s=scale * p.M_s, m=scale * p.m, m_b=scale * p.m_b, k0=scale * p.k0)
        problem = replace(base, params=plant, mission=base.mission.first(2))
        start = time.perf_counter()
        m = run_problem(problem, "nmpc", params=RollbotParams(), show_progress=False).metrics
        wall = time.perf_counter() - start
        print(f"N-shape, first two stops, NMPC (seed 0), plant's masses and damping x{scale}: completed {m['completed']}"
              f" in {m['completion_time']} s; stops at {m['stop_times']} s, errors "
              f"{[round(100 * e, 1) for e in m['stop_errors']]} cm; brakes {m['brakes']}, plan failures "
              f"{m['plan_failures']}; wall time {wall:.1f} s (reported only)")
        assert m["completed"] and len(m["stop_errors"]) == 2 and max(m["stop_errors"]) <= 0.07
        assert not m["torque_limit_violation"] and not m["speed_limit_violation"]
        assert m["min_normal_force"] > 0 and m["min_slide_margin"] > 0 and not m["events"]
    print("all assertions hold")


if __name__ == "__main__":
    main()
