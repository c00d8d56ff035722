"""The NMPC's planner: one computer that solves plans one after the other, and its queue of pending plans.

A supervisor asks for a plan with a list of attempts (functions that solve and return a ``Plan``, or raise
``SolveFailed``); the planner keeps the first that converges as a ``PendingPlan`` under a key (a leg's
segment, or 0 for a circle's entry) with the instant it may be used: the first solve instant after the one
planner has finished it.  How long a plan took is the compute-time model's: modelled from its IPOPT
iterations (``Timing.plan_iteration``, ``plan_guess``) in simulation, so that results do not depend on the
machine, or the measured wall-clock time with ``Timing.realtime`` (a robot).  The planner knows nothing of
missions: what to plan and from where is the supervisor's.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

from rollbot_oc.control.nmpc.settings import Timing
from rollbot_oc.control.nmpc.telemetry import Telemetry
from rollbot_oc.planning.min_time import Plan, SolveFailed

__all__ = ["PendingPlan", "Planner"]


@dataclass
class PendingPlan:
    """A plan computed for later use.

    Attributes
    ----------
    plan : Plan or None
        The plan; None if every attempt failed.
    start : float or None
        When it is to be followed from, s (None: from the moment it is taken, e.g. when the stop before it
        is reached).
    ready : float
        When it may be used, s (a solve instant).
    stone : bool
        A leg to a stepping stone towards its stop (planned again from its end).
    """

    plan: Plan | None
    start: float | None
    ready: float
    stone: bool = False

    def is_ready(self, t_now: float) -> bool:
        """Whether it may be used at ``t_now``."""
        return t_now >= self.ready - 1e-9

    @property
    def late(self) -> bool:
        """Ready only after the instant it was planned to start from."""
        return self.start is not None and self.ready > self.start + 1e-9


class Planner:
    """The one planner and its queue (module doc).

    Parameters
    ----------
    h : float
        The solve period, s: plans are used at solve instants.
    timing : Timing
        The compute-time model.
    telemetry : Telemetry
        Where plan times and failures are counted.
    """

    def __init__(self, h: float, timing: Timing, telemetry: Telemetry):
        self.h, self.timing, self.telemetry = h, timing, telemetry
        self.queue: dict[int, PendingPlan] = {}
        self.free = 0.0  # when the planner has finished the plans it was given, s

    def reset(self, telemetry: Telemetry) -> None:
        """Forget every pending plan; the planner is free from the start."""
        self.queue, self.free, self.telemetry = {}, 0.0, telemetry

    def solve(self, key: int, attempts, t_now: float, start: float | None, guessed=(0.0, 0.0),
              modelled_extra=None) -> tuple[PendingPlan, int]:
        """Solve the first converging of ``attempts`` and queue it under ``key``.

        Parameters
        ----------
        key : int
            Where the plan is queued (a previous plan there is replaced).
        attempts : sequence of callables
            Each solves and returns a ``Plan`` or raises ``SolveFailed`` (counted, never followed).
        t_now : float
            When it is asked for, s.
        start : float or None
            When it is to be followed from, s (``PendingPlan.start``).
        guessed : (float, float)
            Wall-clock and modelled time already spent on it (its initial guesses), s.
        modelled_extra : callable, optional
            ``tried -> s``: modelled time of what the attempts needed before solving (their guesses).

        Returns
        -------
        (PendingPlan, int)
            The pending plan and how many attempts were tried.
        """
        wall = time.perf_counter() - guessed[0]
        plan, iterations, tried = self.first_converged(attempts)
        extra = modelled_extra(tried) if modelled_extra is not None else guessed[1]
        ready = self.schedule(t_now, time.perf_counter() - wall, iterations * self.timing.plan_iteration + extra)
        pending = self.queue[key] = PendingPlan(plan, start, ready)
        return pending, tried

    def first_converged(self, attempts):
        """Call the ``attempts`` in turn until one converges; each failure is counted.  Returns the plan (None
        if every attempt failed), the IPOPT iterations of all of them and how many were tried."""
        iterations, tried = 0, 0
        for attempt in attempts:
            tried += 1
            try:
                plan = attempt()
            except SolveFailed as exc:  # reported, never followed
                self.telemetry.plan_failed(exc.status)
                iterations += exc.plan.iterations if exc.plan is not None else 0
                continue
            return plan, iterations + plan.iterations, tried
        return None, iterations, tried

    def schedule(self, t_now: float, wall: float, modelled: float) -> float:
        """When a plan asked for at ``t_now`` may be used, s: the first solve instant after the planner has
        finished it, ``modelled`` s after it began (after the plans before it; with ``realtime``, the measured
        ``wall`` s instead).  The wall-clock time is reported."""
        self.telemetry.plan_solve_times.append(wall)
        begin = max(t_now, self.free)
        compute = wall if self.timing.realtime else modelled
        ready = t_now + self.h * math.ceil((begin - t_now + compute) / self.h - 1e-9)
        self.free = ready
        return ready

    def get(self, key: int) -> PendingPlan | None:
        """The plan pending under ``key``, if any."""
        return self.queue.get(key)

    def pop(self, key: int) -> PendingPlan | None:
        """Take the plan pending under ``key`` out of the queue."""
        return self.queue.pop(key, None)

    def drop(self, first: int, t_now: float) -> None:
        """Forget the plans under keys ``first`` on (legs chain from one another); a computation still running
        for them is abandoned, so the planner is free from ``t_now``."""
        for key in [key for key in self.queue if key >= first]:
            del self.queue[key]
        self.free = min(self.free, max([t_now] + [pending.ready for pending in self.queue.values()]))
