"""The NMPC's leg planner: wall-clock time per IPOPT iteration and of the quasi-stable guesses.

In simulation the NMPC uses a leg only once its modelled compute time has
passed (``NMPCSettings.timing.plan_iteration`` per IPOPT iteration and
``timing.plan_guess`` per set of quasi-stable guesses), so that runs do not
depend on how busy the machine is.  This benchmark measures what those two
figures stand for: it plans every leg of the N-shape and of random courses
as the NMPC plans a leg from rest (the planner's settings, the course's
believed robot on its floor, each of ``planner.starts`` quasi-stable guesses
solved in turn, the next leg from where the fastest ended), and prints the
median, 95th percentile and largest time per iteration over the solves (the
wall time of a solve over its iterations: setting up a solve is in it) and
of the guesses.  With ``--busy`` a closed-loop NMPC run of the N-shape
occupies the other core meanwhile, as the controller's own loop would.

Run: .venv/bin/python benchmarks/bench_planner.py [--courses 10] [--busy]
"""

import argparse
import subprocess
import sys
import time

import numpy as np

from rollbot_oc.control.nmpc import NMPCSettings
from rollbot_oc.planning.min_time import RestToRest, SolveFailed, quasi_stable_guesses
from rollbot_oc.scenarios.courses import random_course
from rollbot_oc.model.dynamics import REDUCED, to_reduced
from rollbot_oc.scenarios.bundled import load_bundled

BUSY = ("from rollbot_oc.scenarios.problem import run_problem\nfrom rollbot_oc.scenarios.bundled import load_bundled\n"
        "while True:\n    run_problem(load_bundled('n_shape'), 'nmpc', show_progress=False)\n")


def courses(count: int):
    """(name, believed robot on the plant's floor, start state, stops): the N-shape and random courses."""
    n_shape = load_bundled("n_shape")
    yield "n_shape", n_shape.params, n_shape.initial_state(), n_shape.mission.stops
    for index in range(count):
        course = random_course(seed=0, index=index)
        problem = course.problem
        believed = course.believed.replace(slope=problem.params.slope, slope_dir=problem.params.slope_dir)
        yield f"course {index}", believed, problem.initial_state(), problem.mission.stops


def plan_course(params, start, stops, settings: NMPCSettings, per_iteration: list, guess_times: list):
    """Plan the legs of one course as the NMPC plans a leg from rest; appends the measurements."""
    level = params.replace(slope=0.0)
    legs = RestToRest(level, settings.planner.legs)
    legs.build()
    z = to_reduced(start)
    for stop in stops:
        goal = np.asarray(stop, float)
        t0 = time.perf_counter()
        guesses = quasi_stable_guesses(z, goal, level, settings.planner.legs.N, settings.planner.starts)
        guess_times.append(time.perf_counter() - t0)
        best = None
        for guess in guesses:
            t0 = time.perf_counter()
            try:
                plan = legs.solve(z, goal, guess=guess, model=params.vector())
            except SolveFailed as exc:
                plan = exc.plan
            wall = time.perf_counter() - t0
            if plan is not None and plan.iterations > 0:
                per_iteration.append(wall / plan.iterations)
            if plan is not None and plan.success and (best is None or plan.T < best.T):
                best = plan
        if best is None:
            return
        z = best.z[:, -1].copy()
        z[REDUCED.velocity] = 0.0


def stats(label: str, values, unit: str, scale: float) -> str:
    v = np.asarray(values) * scale
    return (f"  {label:28s} {len(v):4d}  median {np.median(v):7.2f} {unit}  p95 {np.percentile(v, 95):7.2f} {unit}"
            f"  max {v.max():7.2f} {unit}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--courses", type=int, default=10, help="random courses besides the N-shape (default 10)")
    parser.add_argument("--busy", action="store_true", help="a closed-loop NMPC run on the other core meanwhile")
    args = parser.parse_args()
    settings = NMPCSettings()
    busy = subprocess.Popen([sys.executable, "-c", BUSY], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL) if args.busy else None
    try:
        per_iteration, guess_times = [], []
        for name, params, start, stops in courses(args.courses):
            plan_course(params, start, stops, settings, per_iteration, guess_times)
            print(f"  {name}: {len(per_iteration)} solves so far", file=sys.stderr)
    finally:
        if busy is not None:
            busy.kill()
    print(f"Leg planner (N = {settings.planner.legs.N}, compiled stages, at most {settings.planner.legs.max_iter} iterations), "
          f"N-shape and random courses 0 to {args.courses - 1}, {'beside a closed-loop run' if args.busy else 'idle'}")
    print(stats("time per IPOPT iteration", per_iteration, "ms", 1e3))
    print(stats("quasi-stable guesses", guess_times, "ms", 1e3))
    print(f"  modelled: timing.plan_iteration {1e3 * settings.timing.plan_iteration:.1f} ms, "
          f"timing.plan_guess {1e3 * settings.timing.plan_guess:.0f} ms")


if __name__ == "__main__":
    main()
