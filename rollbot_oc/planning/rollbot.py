"""Rollbot on the optimal-control layer: its model (``rollbot_model``), an ``OCP`` of it (``rollbot_ocp``), and
the named constraints of its problems, written once for every route and controller.

The layer below (``rollbot_oc.ocp``) is generic: it knows a system only through the ``OCPModel`` it is given.
This module gives it Rollbot in the pendulum frame, its states named as ``ocp.state.position``,
``.quaternion``, ``.omega``, ``.theta_dot``, ``.velocity``, its control as ``ocp.control.accel`` and its
parameters as ``ocp.params.max_accel``, ... (``model.params.ParamView``).

Each constraint function returns a ``Constraint`` in the stage symbols of an ``OCP`` of that model
(states ``x``, control ``u``, model parameters ``p``), scaled to be
dimensionless and of order one, which active-set QP solvers need.  The
robot's limits come from the parameter vector ``p``, so one problem serves
any robot and floor; the margins are the fraction of a limit a plan may use.

All of them are built from the same symbolic model as the plant
(``dynamics.reduced_model``: motor torque, ground reaction), so the plant
and the controllers agree on what a limit is.

It sits in the planning layer, the lowest one above both the model (``rollbot_oc.model``) and the generic
optimal-control layer: it needs both, and every user of a Rollbot OCP (planners, the NMPC, exports,
scenarios) sits at or above it.
"""

from __future__ import annotations

import functools

import casadi as ca
import numpy as np

from rollbot_oc.model.dynamics import NU, NW, NZ, REDUCED, REDUCED_NAMES, imbalance, reduced_model
from rollbot_oc.model.params import NP, PARAM_VECTOR_FIELDS, ParamView
from rollbot_oc.ocp import OCP, Constraint, OCPModel

__all__ = ["rollbot_model", "rollbot_ocp", "motor_torque", "driving_speed", "motor_accel", "no_jump", "no_slide",
           "position_box", "circular_obstacle", "at_rest", "reaction_force", "robot_limits"]


@functools.lru_cache(maxsize=None)
def rollbot_model() -> OCPModel:
    """Rollbot in the pendulum frame (``dynamics.reduced_model``, 10 states), no external wrench.

    States ``(x, y, pw, px, py, pz, wx, wy, wz, theta_dot)`` (m, unit quaternion of
    the pendulum frame, rad/s, rad/s), with the parts of ``dynamics.REDUCED`` (``position``,
    ``quaternion``, ``omega``, ``theta_dot``, ``velocity``); control the motor acceleration
    ``theta_ddot`` (rad/s^2), also named ``accel``; parameters ``RollbotParams.vector()`` (the floor's tilt
    included), read through ``ParamView``.
    """
    red = reduced_model()
    z, u, p = ca.SX.sym("z", NZ), ca.SX.sym("u", NU), ca.SX.sym("p", NP)
    f = ca.Function("rollbot", [z, u, p], [red.f(z, u, p, ca.DM.zeros(NW))], ["x", "u", "p"], ["xdot"])
    parts = {name: getattr(REDUCED, name) for name in ("position", "quaternion", "omega", "theta_dot", "velocity")}
    return OCPModel("rollbot", f, REDUCED_NAMES, ("theta_ddot",), PARAM_VECTOR_FIELDS, state_parts=parts,
                    control_parts={"accel": 0}, parameter_view=ParamView)


def rollbot_ocp(N=40, T=None, substeps: int = 2) -> OCP:
    """An ``OCP`` of Rollbot (``rollbot_model()``): ``N`` intervals in ``T`` seconds (or ``FreeTime``), per
    phase, ``substeps`` RK4 steps per interval (``OCP``)."""
    return OCP(rollbot_model(), N=N, T=T, substeps=substeps)


_W0 = ca.DM.zeros(NW)


def reaction_force(x, u, p):
    """Ground force on the shell (3,), N, at a stage (floor frame)."""
    return reduced_model().reaction(x, u, p, _W0)


def motor_torque(ocp: OCP, margin: float = 1.0) -> Constraint:
    """``|tau_m| <= margin * max_torque``: the motor torque the motion needs (N m), over its limit."""
    red = reduced_model()
    tau = red.motor_torque(ocp.x, ocp.u, ocp.p, _W0) / ocp.params.max_torque
    return Constraint(tau, -margin, margin, "motor torque")


def driving_speed(ocp: OCP, margin: float = 1.0) -> Constraint:
    """``|theta_dot| <= margin * max_speed``."""
    return Constraint(ocp.state.theta_dot / ocp.params.max_speed, -margin, margin, "driving speed")


def motor_accel(ocp: OCP, margin: float = 1.0) -> Constraint:
    """``|theta_ddot| <= margin * max_accel`` (the motor driver's acceleration limit)."""
    return Constraint(ocp.control.accel / ocp.params.max_accel, -margin, margin, "motor acceleration")


def no_jump(ocp: OCP, margin: float = 0.1) -> Constraint:
    """The normal force stays above ``margin`` times the robot's weight (the shell keeps contact)."""
    N = reaction_force(ocp.x, ocp.u, ocp.p)
    return Constraint(N[2] / ocp.params.weight, margin, np.inf, "no jump")


def no_slide(ocp: OCP, margin: float = 0.95) -> Constraint:
    """The ground force stays inside ``margin`` times the friction cone, ``|N_t| <= margin mu N_z``.

    Written smoothly as ``((margin mu N_z)^2 - |N_t|^2) / weight^2 >= 0``, with
    ``no_jump`` keeping ``N_z > 0`` alongside.
    """
    N = reaction_force(ocp.x, ocp.u, ocp.p)
    P = ocp.params
    slack = ((margin * P.mu * N[2]) ** 2 - N[0] ** 2 - N[1] ** 2) / P.weight ** 2
    return Constraint(slack, 0.0, np.inf, "no slide")


def robot_limits(ocp: OCP, torque: float = 1.0, normal: float = 0.1, friction: float = 0.95, speed: float = 1.0,
                 accel: float = 1.0, constraints=()) -> list[Constraint]:
    """Every limit of the robot with its margin (motor torque, no jump, no slide, driving speed, motor
    acceleration), and ``constraints`` (functions of the ``OCP`` giving a ``Constraint`` or a relation):
    what each of the toolkit's own problems (legs, orbit entry, gates, the NMPC's tracking) is subject to::

        ocp.subject_to(*robot_limits(ocp, 0.9, 0.3, 0.8, 0.95, 0.85))
    """
    return [motor_torque(ocp, torque), no_jump(ocp, normal), no_slide(ocp, friction), driving_speed(ocp, speed),
            motor_accel(ocp, accel), *(make(ocp) for make in constraints)]


def position_box(ocp: OCP, lower, upper) -> Constraint:
    """The shell centre stays in the box ``lower <= (x, y) <= upper`` (m)."""
    return Constraint(ocp.state.position, lower, upper, "position box")


def circular_obstacle(ocp: OCP, centre, radius) -> Constraint:
    """The shell keeps out of a round obstacle: centre distance at least ``radius`` plus the shell's radius ``R``.

    Parameters
    ----------
    centre : array_like (2,) or casadi.SX
        Obstacle centre, m (a number, or a problem parameter).
    radius : float or casadi.SX
        Obstacle radius, m.
    """
    offset = ocp.state.position - centre
    clearance = ca.sqrt(ca.sumsqr(offset) + 1e-12) - (radius + ocp.params.R)
    return Constraint(clearance / ocp.params.R, 0.0, np.inf, "circular obstacle")


def at_rest(ocp: OCP) -> Constraint:
    """At rest and balanced: shell and motor still, and the centre of mass straight above the contact point.

    ``omega = 0``, ``theta_dot = 0`` (rad/s), and the robot's centre of mass
    on the line through the contact point along gravity (two conditions,
    scaled by ``R``): a static equilibrium of the full model on the floor the
    parameters describe, level or sloped.  On a level floor it is the
    pendulum straight below the shell centre.
    """
    expr = ca.vertcat(ocp.state.velocity, imbalance(ocp.state.quaternion, ocp.params.vector))
    return Constraint(expr, 0.0, 0.0, "at rest")
