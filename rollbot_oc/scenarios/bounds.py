"""The minimum-time bound of a waypoint course: the fastest chain of rest-to-rest legs the motor allows.

This module is the one place where campaigns, course benchmarks and the
hardware co-design call the optimal-control layer, so that switching the
layer (``rollbot_oc.planning.min_time``) is a change to ``_plan_legs`` only.

The bound of a course is the sum of the minimum times of its legs, each a
rest-to-rest plan over the full dynamics with the motor's torque, speed and
acceleration limits and the no-jump and no-slide margins of the planner
(``OCPSettings``), each leg starting where the previous plan ended (heading
included), each the fastest of ``BOUND_STARTS`` starts (``RestToRest.fastest``; if none
converges, up to ``BOUND_RESUMES`` of them are solved again from where IPOPT stopped, as the NMPC's
planner does, ``NMPCSettings.planner.resumes``).  It is
a bound in the planner's sense: what the planner finds, a
local optimum, not a proven global minimum (single starts land in optima up
to twice as slow).

The N-shape bound of a design (``n_shape_bound``) is this bound on the
bundled ``n_shape`` scenario's start and stops, on a level floor: a property
of the robot, not of one lab's floor.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from rollbot_oc.core.errors import NumericalFailure
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.model.dynamics import rest_state
from rollbot_oc.planning.min_time import OCPSettings, SolveFailed, plan_waypoints
from rollbot_oc.scenarios.bundled import load_bundled

__all__ = ["TimeBound", "minimum_time_bound", "n_shape_bound", "BOUND_STARTS", "BOUND_RESUMES"]

BOUND_STARTS = 5  # guesses per leg; the fastest local optimum found is kept
BOUND_RESUMES = 3  # failed starts of a leg solved again from their last iterate when none converged


@dataclass(frozen=True)
class TimeBound:
    """The minimum-time bound of a course.

    Attributes
    ----------
    total : float
        Sum of the legs' minimum times, s.
    legs : tuple of float
        Minimum time of each leg, s.
    wall_time : float
        Computation time, s.
    """

    total: float
    legs: tuple
    wall_time: float


def _plan_legs(params: RollbotParams, start_state: np.ndarray, stops) -> list[float]:
    """Minimum times (s) of the rest-to-rest legs through ``stops`` (the optimal-control layer's call).

    Raises
    ------
    NumericalFailure
        If a leg cannot be planned (the leg and the solver's status are named).
    """

    try:  # the stage constraints as compiled C (the same problem, solved several times faster)
        plans = plan_waypoints(start_state, [np.asarray(s, float) for s in stops], params, OCPSettings(compiled=True),
                               starts=BOUND_STARTS, resumes=BOUND_RESUMES)
    except SolveFailed as exc:
        raise NumericalFailure(str(exc), exc.status) from None
    return [float(plan.T) for plan in plans]


def minimum_time_bound(params: RollbotParams, start_state: np.ndarray, stops) -> TimeBound:
    """The minimum-time bound of a waypoint course (see the module doc).

    Parameters
    ----------
    params : RollbotParams
        The robot and its floor (the plant's slope applies).
    start_state : numpy.ndarray (11,)
        The state at the start (at rest), as ``Problem.initial_state``.
    stops : sequence of (x, y)
        The stops, m, in order.

    Returns
    -------
    TimeBound

    Raises
    ------
    NumericalFailure
        If a leg cannot be planned.
    """
    start = time.perf_counter()
    legs = _plan_legs(params, start_state, stops)
    return TimeBound(float(sum(legs)), tuple(legs), time.perf_counter() - start)


def n_shape_bound(params: RollbotParams) -> TimeBound:
    """The minimum-time bound of the bundled ``n_shape`` course for the robot ``params`` on a level floor."""

    course = load_bundled("n_shape")
    level = params.replace(slope=0.0)
    state = rest_state(level, position=course.start_position, heading=course.start_heading)
    return minimum_time_bound(level, state, course.mission.stops)
