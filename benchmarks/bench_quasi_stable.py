"""Speed of the quasi-stable analysis: the 200-point curve plus eigenvalues, and the radius map.

Run: .venv/bin/python benchmarks/bench_quasi_stable.py
"""

import statistics
import time

import numpy as np

from rollbot_oc.quasi_stable import RadiusMap, quasi_stable_curve
from rollbot_oc.stability import stability_curve

REPEATS = 7


def timed(run):
    run()  # build the CasADi Functions once
    times = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return statistics.median(times), min(times), max(times)


def main():
    omegas = np.linspace(0.0, 3 * np.pi, 200)
    radius_map = RadiusMap()
    cases = {
        "quasi-stable curve, 200 points (slow branch)": lambda: quasi_stable_curve(omegas),
        "curve + eigenvalues, 199 points": lambda: stability_curve(omegas[1:]),
        "radius map build (121 knots, AD slopes)": lambda: RadiusMap(),
        "1000 inverse-map calls omega(R)": lambda: [radius_map.omega(0.2 + 1e-3 * i) for i in range(1000)],
    }
    print(f"quasi-stable benchmark ({REPEATS} runs)")
    for name, run in cases.items():
        med, lo, hi = timed(run)
        print(f"  {name:46s} median {med * 1e3:8.2f} ms  (min {lo * 1e3:.2f}, max {hi * 1e3:.2f})")


if __name__ == "__main__":
    main()
