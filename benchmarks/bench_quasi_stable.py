"""Speed of the quasi-stable analysis: the 200-point curve with eigenvalues, the curve alone, and the radius map.

The batched route (what ``quasi_stable_curve`` and ``stability_curve`` use) is timed against the speed-by-speed
continuation it replaced, kept as ``_curve(..., batched=False)``.  Times are per call: median, 95th percentile
and maximum over many repeats, after one warm-up call (which builds the CasADi Functions).

Run: .venv/bin/python benchmarks/bench_quasi_stable.py
"""

import os
import time

import numpy as np

from rollbot_oc.model.params import RollbotParams
from rollbot_oc.analysis.quasi_stable import RadiusMap, _curve, _states, quasi_stable_curve
from rollbot_oc.analysis.stability import _analyse, stability_curve


def timed(run, repeats):
    run()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return np.array(times)


def continuation_with_eigenvalues(omegas, params):
    """The old route: continuation speed by speed, then the same batched linearisation and eigenvalues."""
    omegas, Z, rows, ok = _curve(omegas, params, "slow", batched=False)
    return _analyse(_states(omegas, Z, rows, ok, params, "slow"), Z, params)


def main():
    omegas = np.linspace(0.0, 3 * np.pi, 200)
    params = RollbotParams()
    radius_map = RadiusMap()
    cases = [
        ("curve + eigenvalues, 200 points (stability_curve)", lambda: stability_curve(omegas), 300),
        ("  the same by continuation (old route)", lambda: continuation_with_eigenvalues(omegas, params), 20),
        ("quasi-stable curve, 200 points (slow branch)", lambda: quasi_stable_curve(omegas), 300),
        ("  the same by continuation (old route)", lambda: _curve(omegas, params, "slow", batched=False), 20),
        ("radius map build (121 knots, AD slopes)", lambda: RadiusMap(), 100),
        ("1000 inverse-map calls omega(R)", lambda: [radius_map.omega(0.2 + 1e-3 * i) for i in range(1000)], 30),
    ]
    print(f"quasi-stable benchmark (load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())})")
    for name, run, repeats in cases:
        t = timed(run, repeats) * 1e3
        print(f"  {name:52s} median {np.median(t):7.2f} ms  p95 {np.percentile(t, 95):7.2f}  max {t.max():7.2f}"
              f"  ({repeats} runs)")
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
