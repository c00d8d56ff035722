"""Speed of the onboard estimator: time per update, on the readings of a closed-loop run (median, p95, max).

The PID drives the N-shape on the estimate of the default consumer IMU and encoder, fused with 100 Hz motion
capture; every call of the filter is timed:

* IMU update: one IMU sample and the encoder (prediction, error transition by AD, Joseph update), the cost that
  repeats at the IMU rate;
* motion-capture update: one capture (delayed by a period);
* whole step: everything the loop spends on sensing per control period (sensor noise, the updates, the record).

Run: .venv/bin/python benchmarks/bench_estimator.py
"""

import statistics
import time

import numpy as np

from rollbot_oc.simulation.ekf import ErrorStateEKF
from rollbot_oc.simulation.onboard import OnboardSensing
from rollbot_oc.scenarios.problem import make_controller
from rollbot_oc.scenarios.bundled import load_bundled
from rollbot_oc.simulation.sensors import SensingConfig
from rollbot_oc.simulation.plant import simulate

DURATION = 60.0  # s simulated


class Timed:
    """Wraps a bound method and keeps the wall time of every call."""

    def __init__(self, method):
        self.method, self.times = method, []

    def __call__(self, *args, **kwargs):
        start = time.perf_counter()
        out = self.method(*args, **kwargs)
        self.times.append(time.perf_counter() - start)
        return out


def summary(name: str, times: list[float], per: int = 1) -> str:
    t = np.asarray(times) / per * 1e6
    return (f"  {name:28s} median {statistics.median(t):7.1f} us   p95 {np.percentile(t, 95):7.1f} us   "
            f"max {t.max():8.1f} us   ({t.size} calls)")


def main():
    problem = load_bundled("n_shape")
    believed = problem.params.replace(slope=0.0)
    sensing = OnboardSensing(SensingConfig("imu+mocap"), believed, problem.dt, seed=0)
    ekf: ErrorStateEKF = sensing.filter
    propagate, fuse, observe = Timed(ekf.propagate), Timed(ekf.fuse), Timed(sensing.observe)
    ekf.propagate, ekf.fuse, sensing.observe = propagate, fuse, observe
    simulate(problem.initial_state(), 1.0, params=problem.params, controller=make_controller("pid", problem),
             dt=problem.dt, sensor=sensing)  # build the Functions first
    for timer in (propagate, fuse, observe):
        timer.times.clear()
    start = time.perf_counter()
    simulate(problem.initial_state(), DURATION, params=problem.params, controller=make_controller("pid", problem),
             dt=problem.dt, sensor=sensing)
    wall = time.perf_counter() - start
    print(f"estimator benchmark: PID on the N-shape, {DURATION:.0f} s at 100 Hz, default IMU and encoder, "
          f"100 Hz motion capture; {ekf.samples} IMU sample(s) per period")
    print(summary("IMU + encoder update", propagate.times, ekf.samples))
    print(summary("motion-capture update", fuse.times))
    print(summary("whole sensing step", observe.times))
    print(f"  closed loop: {wall:.2f} s wall for {DURATION:.0f} s simulated ({DURATION / wall:.0f}x real time)")


if __name__ == "__main__":
    main()
