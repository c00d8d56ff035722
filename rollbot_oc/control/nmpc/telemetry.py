"""What the NMPC records of a run: one typed record, turned into the run's JSON keys by ``report``."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Telemetry"]


@dataclass
class Telemetry:
    """Counts and times of a run of the NMPC (times in s; counts of solves, plans and fallbacks).

    Attributes
    ----------
    solve_times : list of float
        Wall-clock time of every tracking solve.
    statuses : list of str
        Status of every tracking solve, and of every failed plan (``"plan failed: ..."``).
    tilt : list of list of float
        The tilt estimate at every solve.
    plan_solve_times : list of float
        Wall-clock time of every plan (legs, entries, gate plans).
    failed, late : int
        Tracking solves that failed, or succeeded too late to be used.
    cold_retries : int
        Warm-started solves that failed and were solved once more from the reference.
    fallback_shifted, fallback_pid, fallback_brake : int
        Failed or late solves after which the previous solution was followed; PID and brake fallbacks taken.
    replans : int
        Stops: recoveries planned from where the robot was; gates: plans through the gates left from rest
        (reported as ``stop_replans``).
    brakes : int
        Stops: recoveries (the robot brought to rest off its plan).
    plan_failures, plan_late, stones, unfit : int
        Plans that failed; plans ready after the start they were planned from; stepping stones; legs planned
        ahead that did not fit where the robot was.
    plan_wait, stop_wait : float
        Time held at a stop while the next leg was computed; time past a leg's end before its stop was reached.
    """

    solve_times: list = field(default_factory=list)
    statuses: list = field(default_factory=list)
    tilt: list = field(default_factory=list)
    plan_solve_times: list = field(default_factory=list)
    failed: int = 0
    late: int = 0
    cold_retries: int = 0
    fallback_shifted: int = 0
    fallback_pid: int = 0
    fallback_brake: int = 0
    replans: int = 0
    brakes: int = 0
    plan_failures: int = 0
    plan_late: int = 0
    stones: int = 0
    unfit: int = 0
    plan_wait: float = 0.0
    stop_wait: float = 0.0

    def plan_failed(self, status: str) -> None:
        """Count a plan that failed with ``status``."""
        self.statuses.append(f"plan failed: {status}")
        self.plan_failures += 1

    def report(self) -> dict:
        """The run's JSON keys of the tracking solves, fallbacks and plans (the README's metrics)."""
        times = np.array(self.solve_times) if self.solve_times else np.zeros(1)
        plan_times = np.array(self.plan_solve_times) if self.plan_solve_times else np.zeros(1)
        return {
            "solves": len(self.solve_times),
            "solve_time_min": float(times.min()),
            "solve_time_median": float(np.median(times)),
            "solve_time_p95": float(np.percentile(times, 95)),
            "solve_time_max": float(times.max()),
            "solver_statuses": dict(Counter(self.statuses)),
            "failed_solves": self.failed,
            "cold_retries": self.cold_retries,
            "late_solves": self.late,
            "fallback_shifted": self.fallback_shifted,
            "fallback_pid": self.fallback_pid,
            "fallback_brake": self.fallback_brake,
            "stop_replans": self.replans,
            "brakes": self.brakes,
            "stones": self.stones,
            "plans_unfit": self.unfit,
            "plan_solves": len(self.plan_solve_times),
            "plan_failures": self.plan_failures,
            "plan_late": self.plan_late,
            "plan_wait": self.plan_wait,
            "stop_wait": self.stop_wait,
            "plan_solve_time_median": float(np.median(plan_times)),
            "plan_solve_time_max": float(plan_times.max()),
        }
