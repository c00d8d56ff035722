"""The rest-to-rest leg the optimal-control tests share, built with the OCP layer's own vocabulary."""

from rollbot_oc.ocp import OCP
from rollbot_oc.planning.rollbot import (at_rest, driving_speed, motor_accel, motor_torque, no_jump, no_slide,
                                        rollbot_ocp)


def leg_problem(N: int, T, substeps: int = 2, minimum_time: bool = False, effort: float = 1.0) -> OCP:
    """From the state ``x0`` to rest on the parameter ``goal`` (m), within the motor's and the floor's limits.

    Parameters
    ----------
    N : int
        Shooting intervals.
    T : float or FreeTime
        Duration, s.
    substeps : int
        RK4 steps per interval.
    minimum_time : bool
        Add the duration (s) to the cost.
    effort : float
        Weight of the least-squares motor effort, ``(accel / max_accel)^2`` integrated over time.
    """
    ocp = rollbot_ocp(N=N, T=T, substeps=substeps)
    x, u = ocp.state, ocp.control
    ocp.initial_state()
    goal = ocp.parameter("goal", 2)
    if minimum_time:
        ocp.minimize_time()
    ocp.add_least_squares(u.accel / ocp.params.max_accel, weight=effort)
    ocp.subject_to(motor_torque(ocp, 0.9), no_jump(ocp, 0.2), no_slide(ocp, 0.9), driving_speed(ocp, 0.95),
                   motor_accel(ocp))
    ocp.subject_to(x.position == goal, at="end")
    ocp.subject_to(at_rest(ocp), at="end")
    return ocp
