"""Speed of the plant: real-time factor of a 60 s run at 100 Hz (median of repeated runs).

Run: .venv/bin/python benchmarks/bench_simulate.py
"""

import statistics
import time

from rollbot_oc.model.dynamics import rest_state
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.control.protocol import Command, ControllerBase
from rollbot_oc.simulation.plant import simulate

DURATION, REPEATS = 60.0, 7


class SpeedRamp(ControllerBase):
    """The cheapest possible controller, so the figure measures the plant and the loop."""

    def reset(self):
        pass

    def __call__(self, obs):
        return Command(speed=min(6.0, 0.5 * obs.t))


def median_time(run) -> tuple[float, float, float]:
    run()  # build and cache the CasADi Functions first
    times = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times), statistics.median(times), max(times)


def main():
    params = RollbotParams(slope=0.0175)
    x0 = rest_state(params)
    cases = {
        "open loop (mapaccum)": lambda: simulate(x0, DURATION, params=params, speed=lambda t: min(6.0, 0.5 * t)),
        "closed loop (Python controller)": lambda: simulate(x0, DURATION, params=params, controller=SpeedRamp()),
    }
    print(f"plant benchmark: {DURATION:.0f} s simulated at 100 Hz, RK4 with 2 substeps, {REPEATS} runs")
    for name, run in cases.items():
        lo, med, hi = median_time(run)
        print(f"  {name:34s} median {med * 1e3:7.1f} ms  (min {lo * 1e3:.1f}, max {hi * 1e3:.1f})  "
              f"real-time factor {DURATION / med:6.0f}x")


if __name__ == "__main__":
    main()
