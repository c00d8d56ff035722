"""Rollbot on a floor it can slide on: Coulomb contact, rolling resistance and floor damping, in CasADi.

The no-slip model (``dynamics``) ties the shell centre's velocity to the
shell's spin, ``v = omega x R z``.  Here that velocity is free state: the
contact point's velocity (the slip velocity)

    v_slip = v - omega x R z

is zero while the contact sticks and not while it slides.  Newton's and
Euler's laws for the shell and the internal point masses are written with
the shell's angular acceleration, the centre's acceleration and the ground
force as unknowns (9), and the contact mode closes the linear system:

* stick: ``a = omega_dot x R z`` (the rolling constraint differentiated;
  its vertical row keeps the shell on the floor); the ground force is what
  the constraint needs.  This is the no-slip model of ``dynamics`` written
  another way (``tests/test_contact.py`` checks they agree to round-off).
* slide: the centre stays on the floor (``a_z = 0``) and the friction force
  is Coulomb's, ``N_t = -mu N_z s``, ``s`` the unit slip direction (the
  direction ``d`` given with the state when the slip speed is below
  ``SLIP_TINY``, i.e. at the instant sliding starts).

The CasADi Functions come from the residual of those equations (its
Jacobian in the unknowns by AD and a linear solve), no hand derivatives.

Floor losses, both torques on the shell about the floor's horizontal axis
along ``omega_h = (wx, wy, 0)`` (the axis perpendicular to the rolling
direction, ``omega x z``), opposing rolling:

* rolling resistance ``-c_rr N_z omega_h / max(|omega_h|, ROLL_EPS)``: the
  normal force acting ``c_rr`` (m) ahead of the contact point.  Below
  ``ROLL_EPS`` (rad/s) of rolling it is regularised to a linear (viscous)
  torque, so a ball at rest is not pushed and the equations stay an ODE;
* floor damping ``-c_d omega_h`` with ``c_d`` in N m s (sand-like viscous
  resistance to rolling).

State ``X`` (13): the no-slip state ``x`` (11, ``dynamics.STATE_NAMES``)
followed by the shell centre's velocity along the floor (vx, vy), m/s.
Floor vector ``fl`` (3): friction coefficient ``mu`` (1), rolling
resistance ``c_rr`` (m), damping ``c_d`` (N m s).  Slide direction ``d``
(2): a unit vector, used only while the slip speed is below ``SLIP_TINY``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import casadi as ca

from rollbot_oc.model.dynamics import (
    NU, NW, NX, OMEGA, POS, QUAT, THETA, THETA_DOT, gravity_vector, motor_accel_limits, pendulum_mass,
)
from rollbot_oc.model.params import NP, ParamView
from rollbot_oc.model.rotations import quat_derivative, quat_to_matrix

__all__ = ["NXC", "VEL", "NFL", "STICK", "SLIDE", "MODES", "ROLL_EPS", "SLIP_TINY", "ContactModel", "contact_model"]

NXC = NX + 2  # the no-slip state and the centre's velocity along the floor
VEL = slice(NX, NX + 2)
NFL = 3  # mu, rolling resistance (m), damping (N m s)
STICK, SLIDE = 0, 1
MODES = ("stick", "slide")
ROLL_EPS = 0.01  # rad/s: below this rolling rate the rolling-resistance torque is linear in the rate
SLIP_TINY = 1e-9  # m/s: below this slip speed the slide direction is the one given (d), not the slip's own

_EZ = ca.DM([0.0, 0.0, 1.0])


def _terms(X, u, p, w, fl, d, mode: int, hold=0) -> dict:
    """The contact model's symbolic quantities in one mode (see module doc)."""
    P = ParamView(p)
    mu, c_rr, c_d = fl[0], fl[1], fl[2]
    T = quat_to_matrix(X[QUAT])
    omega = X[OMEGA]
    v = ca.vertcat(X[NX], X[NX + 1], 0)
    Rz = P.R * _EZ
    q = pendulum_mass(X[THETA], X[THETA_DOT], u[0], m=P.m, r0=P.r0, phi=P.phi)
    gravity = gravity_vector(P.g, P.tilt_x, P.tilt_y)
    force, ext_torque = w[0:3], w[3:6]
    slip = v - ca.cross(omega, Rz)
    slip_speed = ca.sqrt(slip[0] ** 2 + slip[1] ** 2)
    own = ca.logic_and(slip_speed > SLIP_TINY, hold == 0)
    direction = ca.if_else(own, slip / ca.fmax(slip_speed, SLIP_TINY), ca.vertcat(d, 0))
    roll = ca.vertcat(omega[0], omega[1], 0)
    roll_rate = ca.sqrt(omega[0] ** 2 + omega[1] ** 2)

    r = ca.mtimes(T, q.position)
    v_rel = ca.mtimes(T, q.velocity)
    h = ca.cross(omega, ca.cross(omega, r)) + 2 * ca.cross(omega, v_rel) + ca.mtimes(T, q.acceleration)
    damping = -P.k0 * omega
    floor_damping = -c_d * roll

    def mass_force(omega_dot, accel):
        """The force the shell exerts on the mass, N (Newton's law for the mass)."""
        return q.mass * (accel + ca.cross(omega_dot, r) + h - gravity)

    if mode == STICK:
        # unknowns: omega_dot; the centre follows the rolling constraint and the ground force is what
        # Newton's law for the shell then needs
        omega_dot = ca.SX.sym("omega_dot", 3)
        y = omega_dot
        accel = ca.cross(omega_dot, Rz)
        F = mass_force(omega_dot, accel)
        N = P.M * accel - P.M * gravity - force + F
        extra = []
    else:
        # unknowns: omega_dot, the centre's acceleration along the floor, the normal force; friction is Coulomb's
        omega_dot, a_t, N_z = ca.SX.sym("omega_dot", 3), ca.SX.sym("a_t", 2), ca.SX.sym("N_z")
        y = ca.vertcat(omega_dot, a_t, N_z)
        accel = ca.vertcat(a_t, 0)
        F = mass_force(omega_dot, accel)
        N = ca.vertcat(-mu * N_z * direction[0], -mu * N_z * direction[1], N_z)
        extra = [P.M * accel - P.M * gravity - N - force + F]  # Newton's law for the shell
    resistance = -c_rr * N[2] * roll / ca.fmax(roll_rate, ROLL_EPS)
    torque = damping + ext_torque + resistance + floor_damping
    residual = ca.vertcat(*extra, P.I * omega_dot - ca.cross(-Rz, N) - torque + ca.cross(r, F))  # Euler's law
    A = ca.jacobian(residual, y)
    b = ca.substitute(residual, y, ca.DM.zeros(y.numel()))
    sol = ca.solve(A, -b)
    subs = lambda e: ca.substitute(e, y, sol)  # noqa: E731
    omega_dot_s, accel_s, N_s = sol[0:3], subs(accel), subs(N)
    F_s = subs(F)
    xdot = ca.vertcat(v[0:2], quat_derivative(X[QUAT], omega), omega_dot_s, X[THETA_DOT], u[0], accel_s[0:2])
    motor_axis = ca.mtimes(T, _EZ)
    tau_m = ca.dot(motor_axis, ca.cross(r, F_s))
    centre = ca.vertcat(X[POS], P.R)
    v_mass = v + ca.cross(omega, r) + v_rel
    kinetic = 0.5 * P.M * ca.sumsqr(v) + 0.5 * P.I * ca.sumsqr(omega) + 0.5 * P.m * ca.sumsqr(v_mass)
    potential = -P.M * ca.dot(gravity, centre) - P.m * ca.dot(gravity, centre + r)
    resistance_s, floor_damping_s = subs(resistance), floor_damping
    power = ca.vertcat(tau_m * X[THETA_DOT], ca.dot(damping, omega), ca.dot(force, v) + ca.dot(ext_torque, omega),
                       ca.dot(N_s, slip), ca.dot(resistance_s, omega), ca.dot(floor_damping_s, omega))
    tangential = ca.sqrt(N_s[0] ** 2 + N_s[1] ** 2)
    margins = ca.vertcat(N_s[2], mu * N_s[2] - tangential)
    return dict(xdot=xdot, reaction=N_s, margins=margins, tau_m=tau_m, energy=kinetic + potential, power=power,
                slip=slip[0:2], direction=direction[0:2], P=P)


@dataclass(frozen=True)
class ContactModel:
    """Rollbot's equations on a floor with Coulomb contact, per mode, as CasADi Functions (see module doc).

    Every Function takes ``(X, u, p, w, fl, d)``: state (13), motor
    acceleration (rad/s^2), ``RollbotParams.vector()``, external wrench (6),
    floor vector (3) and slide direction (2); index them by mode
    (``STICK``, ``SLIDE``).

    Attributes
    ----------
    rhs : tuple of Function -> Xdot (13,)
        State derivative with ``u`` clipped to the motor's torque and
        acceleration limits (the motor saturates).
    diag : tuple of Function -> (u_applied, tau_m, N (3), margins (2), slip (2))
        Applied (clipped) motor acceleration, motor torque (N m), ground
        force (N, floor frame), no-jump margin ``N_z`` and no-slide margin
        ``mu N_z - |N_t|`` (N; zero while sliding), and slip velocity (m/s).
    step : tuple of Function (X, u, p, w, fl, d, h, hold) -> (X_end, events (3,))
        One RK4 step of length ``h`` (s) with the saturated right-hand side,
        and at its end the normal force (N) and the mode's event function:
        the no-slide margin in ``STICK`` (N; sliding starts where it turns
        negative), the slip velocity along the slip direction of the step's
        start in ``SLIDE`` (m/s; the contact sticks again where it reaches
        zero); third, the smallest slip along that direction at the RK4
        stages (m/s).  With ``hold = 1`` the friction keeps the direction
        ``d`` over the step instead of following the slip: the step in which
        the slip ends (its stages would otherwise straddle the slip's zero
        and average the friction away).
    energy : Function (X, p) -> E
        Kinetic plus gravitational energy, J (the same in both modes).
    power : tuple of Function -> (6,)
        Motor, shell damping (``k0``), external, friction (``N . v_slip``),
        rolling-resistance and floor-damping power, W; ``dE/dt`` is their sum.
    """

    rhs: tuple
    diag: tuple
    step: tuple
    energy: ca.Function
    power: tuple


@functools.lru_cache(maxsize=None)
def contact_model() -> ContactModel:
    """Build (once per process) and return the contact model's Functions."""
    X, u, p = ca.SX.sym("X", NXC), ca.SX.sym("u", NU), ca.SX.sym("p", NP)
    w, fl, d, hs, hold = (ca.SX.sym("w", NW), ca.SX.sym("fl", NFL), ca.SX.sym("d", 2), ca.SX.sym("h"),
                          ca.SX.sym("hold"))
    ins, names = [X, u, p, w, fl, d], ["X", "u", "p", "w", "fl", "d"]
    rhs, diag, step, power = [], [], [], []
    energy = None
    for mode in (STICK, SLIDE):
        name = MODES[mode]
        terms = _terms(X, u, p, w, fl, d, mode, hold)
        lower, upper = motor_accel_limits(terms["tau_m"], u, terms["P"])
        u_sat = ca.fmin(ca.fmax(u, lower), upper)
        sat = lambda e: ca.substitute(e, u, u_sat)  # noqa: E731
        held = ca.Function(f"contact_{name}_rhs_held", [*ins, hold], [sat(terms["xdot"])])
        free = lambda e: ca.substitute(e, hold, 0)  # noqa: E731
        rhs.append(ca.Function(f"contact_{name}_rhs", ins, [free(sat(terms["xdot"]))], names, ["Xdot"]))
        diag.append(ca.Function(f"contact_{name}_diag", ins,
                                [free(u_sat), free(sat(terms["tau_m"])), free(sat(terms["reaction"])),
                                 free(sat(terms["margins"])), terms["slip"]],
                                names, ["u_applied", "tau_m", "N", "margins", "slip"]))
        power.append(ca.Function(f"contact_{name}_power", ins, [free(terms["power"])], names, ["power"]))
        # one RK4 step, and the slip along the start's slip direction at its stages (where sliding ends)
        k1 = held(X, u, p, w, fl, d, hold)
        k2 = held(X + hs / 2 * k1, u, p, w, fl, d, hold)
        k3 = held(X + hs / 2 * k2, u, p, w, fl, d, hold)
        k4 = held(X + hs * k3, u, p, w, fl, d, hold)
        X_end = X + hs / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        end = ca.Function("end", [*ins, hold], [sat(terms["margins"]), terms["slip"]])
        margins_end, slip_end = end(X_end, u, p, w, fl, d, hold)
        start = free(terms["direction"])
        along = [ca.dot(end(s, u, p, w, fl, d, hold)[1], start) for s in (X + hs / 2 * k1, X + hs / 2 * k2,
                                                                          X + hs * k3, X_end)]
        event = margins_end[1] if mode == STICK else along[-1]
        step.append(ca.Function(f"contact_{name}_step", [*ins, hs, hold],
                                [X_end, ca.vertcat(margins_end[0], event, ca.mmin(ca.vertcat(*along)))],
                                [*names, "h", "hold"], ["X_end", "events"]))
        if energy is None:
            energy = ca.Function("contact_energy", [X, p], [terms["energy"]], ["X", "p"], ["E"])
    return ContactModel(tuple(rhs), tuple(diag), tuple(step), energy, tuple(power))
