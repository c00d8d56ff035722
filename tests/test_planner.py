"""The NMPC's planner: one computer, plans one after the other, ready at solve instants by the compute-time model."""

import numpy as np
import pytest

from rollbot_oc.control.nmpc.planner import PendingPlan, Planner
from rollbot_oc.control.nmpc.settings import Timing
from rollbot_oc.control.nmpc.telemetry import Telemetry
from rollbot_oc.planning.min_time import Plan, SolveFailed


def _plan(iterations: int) -> Plan:
    return Plan(np.array([0.0, 1.0]), np.zeros((10, 2)), np.zeros(1), 1.0, "Solve_Succeeded", True, iterations, 0.0)


def _failing(iterations: int):
    def attempt():
        raise SolveFailed("injected", "Maximum_Iterations_Exceeded", _plan(iterations))
    return attempt


def test_plans_queue_behind_each_other_and_are_ready_at_solve_instants():
    """Modelled: 50 iterations of 8 ms (0.4 s) asked at 1.0 s is ready at the first solve instant after 1.4 s;
    a second asked at the same time begins when the first ends; the wall clock is only reported."""
    log = Telemetry()
    planner = Planner(0.05, Timing(plan_iteration=0.008), log)
    first, tried = planner.solve(1, [lambda: _plan(50)], t_now=1.0, start=None)
    assert tried == 1 and first.ready == pytest.approx(1.4) and first.is_ready(1.4) and not first.is_ready(1.35)
    second, _ = planner.solve(2, [lambda: _plan(10)], t_now=1.0, start=None)
    assert second.ready == pytest.approx(1.5)  # 1.4 + 0.08 s, up to the next solve instant
    assert planner.free == pytest.approx(1.5) and len(log.plan_solve_times) == 2
    planner.drop(2, t_now=1.0)  # the second abandoned: the planner is free once the first is done
    assert planner.get(2) is None and planner.free == pytest.approx(1.4)


def test_failed_attempts_are_counted_and_charged_and_the_first_converging_kept():
    log = Telemetry()
    planner = Planner(0.05, Timing(plan_iteration=0.01, plan_guess=0.3), log)
    pending, tried = planner.solve(0, [_failing(20), lambda: _plan(10), lambda: _plan(1)], t_now=0.0, start=0.5,
                                   modelled_extra=lambda tried: tried * 0.3)
    assert tried == 2 and pending.plan.iterations == 10
    assert pending.ready == pytest.approx(0.9)  # (20 + 10) * 0.01 s + two sets of guesses, 0.6 s
    assert pending.late and log.plan_failures == 1 and log.statuses == ["plan failed: Maximum_Iterations_Exceeded"]
    none, tried = planner.solve(0, [_failing(5)], t_now=2.0, start=None)
    assert none.plan is None and tried == 1 and log.plan_failures == 2


def test_on_a_robot_the_wall_clock_decides():
    planner = Planner(0.05, Timing(realtime=True, plan_iteration=100.0), Telemetry())
    pending, _ = planner.solve(0, [lambda: _plan(1000)], t_now=0.0, start=None)
    assert pending.ready <= 0.5  # the measured time of a trivial 'solve', not 1000 modelled iterations


def test_a_pending_plan_says_whether_it_is_late():
    assert not PendingPlan(None, None, 3.0).late  # taken when its stop is reached: never late
    assert PendingPlan(None, 2.0, 2.05).late and not PendingPlan(None, 2.0, 2.0).late
