"""Symbolic equations of motion of Rollbot in CasADi, built once.

The model (paper eqns "motion" and "generalmotion"): a spherically symmetric
shell (mass ``M``, isotropic inertia ``I``, radius ``R``) rolls without slip on
a plane and is driven by internal point masses that follow prescribed
trajectories in the shell's body frame.  Rollbot has one mass ``m`` on a circle
of radius ``r0 sin(phi)`` around the motor axis (the body z' axis),

    r' = r0 (sin phi cos theta, sin phi sin theta, -cos phi),

and a damping torque ``-k0 omega`` from its beads.  Summing the moments of the
mass, the shell and its no-slip constraint about the contact point gives::

    (sum_q m_q (|u_q|^2 I3 - u_q u_q^T) + M R^2 (I3 - z z^T) + I I3) omega_dot
        = sum_q m_q u_q x (g - h_q) + M R z x g + R z x f + tau,

with ``u_q = R z + r_q`` the vector from the contact point to mass ``q``,
``h_q`` its acceleration in the co-rotating frame (centripetal, Coriolis and
relative terms) and ``g`` the gravity vector.  On a level floor ``g = -g z``
and the ``M R z x g`` term vanishes, which recovers the paper's equation; on a
sloped floor it is the shell's own weight rolling it downhill.

Frames and units: the floor frame has z normal to the floor (up); on a slope
gravity has an in-plane component towards ``slope_dir``.  The body frame is
fixed to the shell; the motor axis is body z'.  SI units, radians.

State ``x`` (11): shell-centre position on the floor (x, y) [m]; unit
quaternion body->floor (qw, qx, qy, qz); shell angular velocity in the floor
frame (wx, wy, wz) [rad/s]; motor angle theta [rad]; driving speed theta_dot
[rad/s].

Input ``u`` (1): motor acceleration theta_ddot [rad/s^2].  Acceleration rather
than speed or torque is the input because it keeps the model an ODE with the
mass trajectory prescribed (the paper's assumption); the torque the motor must
supply follows from it (``motor_torque``), and speed commands become
accelerations through the plant's speed loop (``simulation.plant``).

External wrench ``w`` (6): force on the shell centre (3) [N] and torque on
the shell (3) [N m], floor frame; zero unless given.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from rollbot_oc.model.params import NP, TILT, ParamView, RollbotParams
from rollbot_oc.core.integration import rk4
from rollbot_oc.core.reproducible import dot, matmul, norm
from rollbot_oc.model.rotations import (
    matrix_to_quat_np, quat_derivative, quat_multiply, quat_multiply_np, quat_to_matrix, rot_y_np, rot_z_np,
)

__all__ = [
    "STATE_NAMES", "STATE_UNITS", "NX", "NU", "NW", "POS", "QUAT", "OMEGA", "THETA", "THETA_DOT",
    "PointMass", "ShellDynamics", "shell_dynamics", "pendulum_mass", "gravity_vector", "rk4", "motor_speed_clip",
    "motor_accel_limits",
    "SymbolicModel", "symbolic_model", "RollbotModel", "rest_state", "rest_attitude", "imbalance",
    "NZ", "REDUCED_NAMES", "ReducedModel", "reduced_model", "to_reduced", "from_reduced",
    "motor_axis", "heading", "tilt",
    "StateSlices", "FULL", "REDUCED",
]

STATE_NAMES = ("x", "y", "qw", "qx", "qy", "qz", "wx", "wy", "wz", "theta", "theta_dot")
STATE_UNITS = ("m", "m", "1", "1", "1", "1", "rad/s", "rad/s", "rad/s", "rad", "rad/s")
INPUT_NAMES = ("theta_ddot",)
INPUT_UNITS = ("rad/s^2",)
NX, NU, NW = len(STATE_NAMES), len(INPUT_NAMES), 6


@dataclass(frozen=True)
class StateSlices:
    """Named parts of a state vector: index it as ``x[FULL.omega]`` or ``z[REDUCED.position]``.

    Attributes
    ----------
    position : slice
        Shell-centre position (x, y), m.
    quaternion : slice
        Unit quaternion, scalar first: the shell frame (full state) or the
        pendulum frame (reduced state), body -> floor.
    omega : slice
        Shell angular velocity in the floor frame, rad/s.
    theta_dot : int
        Driving speed, rad/s.
    velocity : slice
        Everything that is zero at rest: ``omega`` and ``theta_dot``.
    theta : int or None
        Motor angle, rad (full state only).
    """

    position: slice
    quaternion: slice
    omega: slice
    theta_dot: int
    velocity: slice
    theta: int | None = None


FULL = StateSlices(slice(0, 2), slice(2, 6), slice(6, 9), 10, slice(6, 11), theta=9)
POS, QUAT, OMEGA, THETA, THETA_DOT = FULL.position, FULL.quaternion, FULL.omega, FULL.theta, FULL.theta_dot

_EZ = ca.DM([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class PointMass:
    """An internal point mass moving on a prescribed trajectory in the body frame.

    Attributes
    ----------
    mass : float or casadi.SX
        Mass, kg.
    position, velocity, acceleration : casadi.SX (3,)
        Position relative to the shell centre and its first and second time
        derivatives, all in the body frame: m, m/s, m/s^2.
    """

    mass: object
    position: object
    velocity: object
    acceleration: object


@dataclass(frozen=True)
class ShellDynamics:
    """Symbolic results of ``shell_dynamics`` (all floor frame, SI).

    Attributes
    ----------
    omega_dot : angular acceleration of the shell, rad/s^2.
    centre_accel : acceleration of the shell centre, m/s^2.
    reaction : ground force on the shell (normal plus friction), N.
    offsets : positions of the masses relative to the shell centre, m.
    velocities : absolute velocities of the masses, m/s.
    forces : forces the shell exerts on each mass, N.
    relative_velocities : velocities of the masses relative to the shell body, m/s.
    """

    omega_dot: object
    centre_accel: object
    reaction: object
    offsets: tuple
    velocities: tuple
    forces: tuple
    relative_velocities: tuple


def shell_dynamics(T, omega, masses, *, M, I, R, gravity, force, torque) -> ShellDynamics:
    """Angular acceleration and ground reaction of a rolling shell with internal masses.

    Implements the paper's eqn "generalmotion" (with the shell weight's moment
    about the contact point on a sloped floor).

    Parameters
    ----------
    T : casadi.SX (3, 3)
        Rotation body -> floor.
    omega : casadi.SX (3,)
        Shell angular velocity, floor frame, rad/s.
    masses : sequence of PointMass
        The internal point masses.
    M, I, R : scalar
        Shell mass (kg), isotropic moment of inertia (kg m^2), radius (m).
    gravity : casadi.SX (3,)
        Gravity vector in the floor frame, m/s^2.
    force, torque : casadi.SX (3,)
        External force on the shell centre (N) and torque on the shell (N m),
        including damping.

    Returns
    -------
    ShellDynamics
    """
    Rz = R * _EZ
    inertia = M * R**2 * (ca.DM.eye(3) - ca.mtimes(_EZ, _EZ.T)) + I * ca.DM.eye(3)
    moment = ca.cross(Rz, force) + torque + M * ca.cross(Rz, gravity)
    offsets, rel_vel, coriolis = [], [], []
    for q in masses:
        r = ca.mtimes(T, q.position)
        v_rel = ca.mtimes(T, q.velocity)
        h = ca.cross(omega, ca.cross(omega, r)) + 2 * ca.cross(omega, v_rel) + ca.mtimes(T, q.acceleration)
        u = Rz + r
        inertia += q.mass * (ca.dot(u, u) * ca.DM.eye(3) - ca.mtimes(u, u.T))
        moment += q.mass * ca.cross(u, gravity - h)
        offsets.append(r)
        rel_vel.append(v_rel)
        coriolis.append(h)
    omega_dot = ca.solve(inertia, moment)
    centre_accel = ca.cross(omega_dot, Rz)
    centre_vel = ca.cross(omega, Rz)
    total_mass = M + sum(q.mass for q in masses)
    forces, velocities = [], []
    reaction = total_mass * centre_accel - total_mass * gravity - force
    for q, r, v_rel, h in zip(masses, offsets, rel_vel, coriolis):
        accel = centre_accel + ca.cross(omega_dot, r) + h
        forces.append(q.mass * (accel - gravity))
        velocities.append(centre_vel + ca.cross(omega, r) + v_rel)
        reaction += q.mass * (accel - centre_accel)
    return ShellDynamics(omega_dot, centre_accel, reaction, tuple(offsets), tuple(velocities),
                         tuple(forces), tuple(rel_vel))


def pendulum_mass(theta, theta_dot, theta_ddot, *, m, r0, phi) -> PointMass:
    """Rollbot's pendulum: a point mass on the motor circle, body frame.

    ``r' = r0 (sin phi cos theta, sin phi sin theta, -cos phi)`` with motor
    angle ``theta`` (rad), speed ``theta_dot`` (rad/s) and acceleration
    ``theta_ddot`` (rad/s^2).
    """
    radial = ca.vertcat(ca.cos(theta), ca.sin(theta), 0)
    tangent = ca.vertcat(-ca.sin(theta), ca.cos(theta), 0)
    rho = r0 * ca.sin(phi)
    position = rho * radial - r0 * ca.cos(phi) * _EZ
    velocity = rho * theta_dot * tangent
    acceleration = rho * (theta_ddot * tangent - theta_dot**2 * radial)
    return PointMass(m, position, velocity, acceleration)


def gravity_vector(g, tilt_x, tilt_y):
    """Gravity in the floor frame, m/s^2, from its in-plane part per g (``RollbotParams.tilt_x``, ``tilt_y``)."""
    return g * ca.vertcat(tilt_x, tilt_y, -ca.sqrt(1 - tilt_x**2 - tilt_y**2))


def motor_speed_clip(a, theta_dot, max_speed, dt):
    """Motor acceleration ``a`` (rad/s^2) clipped so that a period ``dt`` (s) held from driving speed
    ``theta_dot`` ends within ``+-max_speed`` (rad/s): the motor driver's speed limit (CasADi)."""
    return ca.fmin(ca.fmax(a, (-max_speed - theta_dot) / dt), (max_speed - theta_dot) / dt)


@dataclass(frozen=True)
class SymbolicModel:
    """Rollbot's equations as CasADi Functions over ``(x, u, p, w)`` (see module doc).

    ``p`` is ``RollbotParams.vector()``.  Every Function is built once per
    process (``symbolic_model`` is cached) and evaluated many times.

    Attributes
    ----------
    f : Function (x, u, p, w) -> xdot
        State derivative.
    reaction : Function (x, u, p, w) -> N (3,)
        Ground force on the shell, floor frame, N.
    margins : Function (x, u, p, w) -> (2,)
        No-jump margin ``N_z`` (N) and no-slide margin ``mu N_z - |N_t|`` (N);
        both must stay positive.
    motor_torque : Function (x, u, p, w) -> tau_m
        Torque the motor must supply to follow ``u``, N m.
    energy : Function (x, p) -> E
        Total mechanical energy (kinetic plus gravitational), J.
    power : Function (x, u, p, w) -> (3,)
        Motor power ``tau_m theta_dot``, damping power ``-k0 |omega|^2`` and
        external power, W.  ``dE/dt`` is their sum.
    accel_bounds : Function (x, p, w) -> (2,)
        Motor accelerations (rad/s^2) the torque and acceleration limits allow.
    plant_rhs : Function (x, u, p, w) -> xdot
        State derivative with ``u`` clipped to ``accel_bounds`` (the motor
        saturates).
    """

    f: ca.Function
    reaction: ca.Function
    margins: ca.Function
    motor_torque: ca.Function
    energy: ca.Function
    power: ca.Function
    accel_bounds: ca.Function
    plant_rhs: ca.Function


def _rollbot_terms(x, u, p, w):
    """Symbolic shell dynamics and derived quantities of Rollbot."""
    P = ParamView(p)
    T = quat_to_matrix(x[QUAT])
    omega = x[OMEGA]
    theta, theta_dot, theta_ddot = x[THETA], x[THETA_DOT], u[0]
    pendulum = pendulum_mass(theta, theta_dot, theta_ddot, m=P.m, r0=P.r0, phi=P.phi)
    gravity = gravity_vector(P.g, P.tilt_x, P.tilt_y)
    force, ext_torque = w[0:3], w[3:6]
    damping = -P.k0 * omega
    dyn = shell_dynamics(T, omega, [pendulum], M=P.M, I=P.I, R=P.R,
                         gravity=gravity, force=force, torque=damping + ext_torque)
    centre_vel = ca.cross(omega, P.R * _EZ)
    xdot = ca.vertcat(centre_vel[0:2], quat_derivative(x[QUAT], omega), dyn.omega_dot, theta_dot, theta_ddot)
    # The motor supplies the axial part of the moment the shell exerts on the mass.
    motor_axis = ca.mtimes(T, _EZ)
    tau_m = ca.dot(motor_axis, ca.cross(dyn.offsets[0], dyn.forces[0]))
    centre = ca.vertcat(x[POS], P.R)
    kinetic = 0.5 * P.M * ca.sumsqr(centre_vel) + 0.5 * P.I * ca.sumsqr(omega) \
        + 0.5 * P.m * ca.sumsqr(dyn.velocities[0])
    potential = -P.M * ca.dot(gravity, centre) - P.m * ca.dot(gravity, centre + dyn.offsets[0])
    power = ca.vertcat(tau_m * theta_dot, ca.dot(damping, omega),
                       ca.dot(force, centre_vel) + ca.dot(ext_torque, omega))
    normal = dyn.reaction[2]
    tangential = ca.sqrt(dyn.reaction[0] ** 2 + dyn.reaction[1] ** 2)
    margins = ca.vertcat(normal, P.mu * normal - tangential)
    return dict(xdot=xdot, reaction=dyn.reaction, margins=margins, tau_m=tau_m,
                energy=kinetic + potential, power=power, P=P)


def motor_accel_limits(tau_m, u, P):
    """The motor accelerations (rad/s^2) the torque and acceleration limits allow, ``(lower, upper)``.

    The torque ``tau_m`` (N m, symbolic) is affine in the motor acceleration ``u``:
    ``tau = tau0 + b u`` with ``b > 0`` (the pendulum's effective inertia), so the
    torque limit ``|tau| <= P.max_torque`` is an interval of ``u``, intersected
    with ``|u| <= P.max_accel`` (``P`` a ``ParamView``).
    """
    tau0 = ca.substitute(tau_m, u, ca.DM.zeros(NU))
    b = ca.jacobian(tau_m, u)
    lower = ca.fmax(-P.max_accel, (-P.max_torque - tau0) / b)
    upper = ca.fmin(P.max_accel, (P.max_torque - tau0) / b)
    return lower, upper


@functools.lru_cache(maxsize=None)
def symbolic_model() -> SymbolicModel:
    """Build (once per process) and return Rollbot's CasADi Functions."""
    x = ca.SX.sym("x", NX)
    u = ca.SX.sym("u", NU)
    p = ca.SX.sym("p", NP)
    w = ca.SX.sym("w", NW)
    terms = _rollbot_terms(x, u, p, w)
    P = terms["P"]
    ins, names = [x, u, p, w], ["x", "u", "p", "w"]
    f = ca.Function("rollbot_f", ins, [terms["xdot"]], names, ["xdot"])
    reaction = ca.Function("rollbot_reaction", ins, [terms["reaction"]], names, ["N"])
    margins = ca.Function("rollbot_margins", ins, [terms["margins"]], names, ["margins"])
    motor_torque = ca.Function("rollbot_motor_torque", ins, [terms["tau_m"]], names, ["tau_m"])
    energy = ca.Function("rollbot_energy", [x, p], [terms["energy"]], ["x", "p"], ["E"])
    power = ca.Function("rollbot_power", ins, [terms["power"]], names, ["power"])

    lower, upper = motor_accel_limits(terms["tau_m"], u, P)
    accel_bounds = ca.Function("rollbot_accel_bounds", [x, p, w], [ca.vertcat(lower, upper)],
                               ["x", "p", "w"], ["bounds"])
    u_sat = ca.fmin(ca.fmax(u, lower), upper)
    plant_rhs = ca.Function("rollbot_plant_rhs", ins, [ca.substitute(terms["xdot"], u, u_sat)], names, ["xdot"])
    return SymbolicModel(f, reaction, margins, motor_torque, energy, power, accel_bounds, plant_rhs)


def imbalance(pendulum_quaternion, p):
    """How far the robot is from balance at rest: the centre of mass's offset across gravity, per ``R``.

    A robot at rest is in static equilibrium when its centre of mass lies on the
    line through the contact point along gravity; this is the offset from that
    line in the floor's x and y directions, divided by the shell radius.  On a
    level floor it is the pendulum mass's horizontal offset (scaled); on a
    slope the mass must hang a little uphill of the shell centre.

    Parameters
    ----------
    pendulum_quaternion : casadi.SX or MX (4,)
        Attitude of the pendulum frame (reduced state), body -> floor.
    p : casadi.SX or MX (NP,)
        Parameter vector (its tilt is the floor's slope).

    Returns
    -------
    casadi expression (2,), dimensionless
    """
    P = ParamView(p)
    body = ca.vertcat(P.r0 * ca.sin(P.phi), 0, -P.r0 * ca.cos(P.phi))  # the mass in the pendulum frame
    mass = ca.mtimes(quat_to_matrix(pendulum_quaternion), body)
    up = ca.vertcat(0, 0, P.R)  # shell centre above the contact point
    com = (P.M * up + P.m * (up + mass)) / (P.M + P.m)
    down = ca.vertcat(P.tilt[0], P.tilt[1], -ca.sqrt(1 - P.tilt[0] ** 2 - P.tilt[1] ** 2))  # gravity per g
    across = com - ca.dot(com, down) * down
    return across[0:2] / P.R


def rest_state(params: RollbotParams | None = None, position=(0.0, 0.0), heading: float = 0.0,
               theta: float = 0.0) -> np.ndarray:
    """State at rest with the pendulum mass straight below the shell centre.

    Parameters
    ----------
    params : RollbotParams, optional
        Parameters (for ``phi``); the prototype by default.
    position : (float, float)
        Shell-centre position on the floor, m.
    heading : float
        Azimuth of the motor axis' horizontal projection, rad.  In a
        quasi-stable state this is the direction from the centre of curvature
        to the robot (the paper's gamma).
    theta : float
        Motor angle, rad; the shell is turned about its motor axis so that the
        mass still hangs straight down.

    Returns
    -------
    numpy.ndarray (11,)
    """
    params = params or RollbotParams()
    T = matmul(matmul(rot_z_np(heading), rot_y_np(params.phi)), rot_z_np(-theta))
    x = np.zeros(NX)
    x[POS] = position
    x[QUAT] = matrix_to_quat_np(T)
    x[THETA] = theta
    return x


def rest_attitude(quaternion, p) -> np.ndarray:
    """The reduced attitude at rest, balanced on the floor, with the heading of ``quaternion``'s motor axis.

    On a level floor the reduced attitude at rest (the shell's turned back by the motor angle,
    ``to_reduced``) is ``Rz(heading) Ry(phi)`` (``rest_state``): the mass straight below the shell centre,
    one attitude per heading of the motor axis.  On a slope the centre of mass must lie on the line through
    the contact point along gravity (``imbalance`` zero): the motor axis is tilted a little more or less
    than ``phi`` and the frame turned a little about it, ``Rz(heading) Ry(phi + a) Rz(b)`` (Newton's method
    on ``imbalance``, its Jacobian by AD, from the level floor's ``a = b = 0``).  The heading is the one of
    ``quaternion``'s motor axis (what the motor alone can reach: a mass swung over the top swings back
    down), so a rest attitude is its own; the sign is the one nearer ``quaternion`` (q and -q are the same
    attitude).

    Parameters
    ----------
    quaternion : array_like (4,)
        A reduced attitude (w, x, y, z), not necessarily of unit norm.
    p : array_like (NP,) or RollbotParams
        The robot and its floor (``phi``, the masses, ``r0`` and the floor's ``tilt``).

    Returns
    -------
    numpy.ndarray (4,)

    Raises
    ------
    ValueError
        If no balanced attitude is found near the level one (a slope too steep for the robot to rest on).
    """
    vector = p.vector() if isinstance(p, RollbotParams) else np.asarray(p, float)
    q = np.asarray(quaternion, float)
    rest, residual = (np.array(v).ravel() for v in _rest_balance()(q / norm(q), vector))
    if not (np.all(np.isfinite(rest)) and np.max(np.abs(residual)) < 1e-9):
        raise ValueError(f"no attitude at rest on the floor of tilt {vector[TILT].round(4).tolist()} (sin of the slope)")
    return rest if dot(rest, q) >= 0 else -rest


def _axis_quaternion(axis: int, angle):
    """Rotation by ``angle`` about the coordinate axis ``axis`` (0, 1, 2: x, y, z), as a quaternion."""
    half = 0.5 * angle
    return ca.vertcat(ca.cos(half), *[ca.sin(half) if i == axis else 0 for i in range(3)])


@functools.lru_cache(maxsize=1)
def _rest_balance() -> ca.Function:
    """``(q (4,), p) -> (rest (4,), imbalance (2,))``: ``Rz(heading) Ry(phi + a) Rz(b)``, the heading that of
    the unit quaternion ``q``'s motor axis, with the tilt ``a`` of the axis and the turn ``b`` about it that
    balance the robot (``rest_attitude``; Newton's method from ``a = b = 0``, the level floor's rest), and
    what is left of the imbalance there."""
    x, heading, p = ca.SX.sym("x", 2), ca.SX.sym("heading"), ca.SX.sym("p", NP)

    def attitude(x, heading, p):
        return quat_multiply(quat_multiply(_axis_quaternion(2, heading), _axis_quaternion(1, ParamView(p).phi + x[0])),
                             _axis_quaternion(2, x[1]))

    residual = ca.Function("rest_imbalance", [x, heading, p], [imbalance(attitude(x, heading, p), p)])
    newton = ca.rootfinder("rest_newton", "newton", residual, {"abstol": 1e-12, "max_iter": 20, "error_on_fail": False})
    Q, P = ca.MX.sym("q", 4), ca.MX.sym("p", NP)
    axis = ca.mtimes(quat_to_matrix(Q), ca.DM([0, 0, 1]))  # the motor axis in the world
    h = ca.atan2(axis[1], axis[0])
    rest = attitude(newton(ca.MX.zeros(2), h, P), h, P)
    return ca.Function("rest_balance", [Q, P], [rest, imbalance(rest, P)], ["q", "p"], ["rest", "imbalance"])


class RollbotModel:
    """Rollbot's equations bound to one parameter set, for numeric evaluation.

    Every method accepts a single state (shape (11,)) or a trajectory of
    states as columns (shape (11, N)) and evaluates the cached CasADi
    Functions, mapped over the columns.

    Parameters
    ----------
    params : RollbotParams, optional
        The robot; the paper's prototype by default.
    """

    state_names = STATE_NAMES
    state_units = STATE_UNITS
    input_names = INPUT_NAMES
    input_units = INPUT_UNITS

    def __init__(self, params: RollbotParams | None = None):
        self.params = params or RollbotParams()
        self.p = self.params.vector()
        self.sym = symbolic_model()

    def _call(self, fun, x, u=None, w=None):
        x = np.asarray(x, float)
        cols = 1 if x.ndim == 1 else x.shape[1]
        u = np.zeros((NU, cols)) if u is None else np.atleast_2d(np.asarray(u, float)).reshape(NU, -1)
        w = np.zeros((NW, 1)) if w is None else np.asarray(w, float).reshape(NW, -1)
        out = np.array(fun(x.reshape(NX, -1), u, self.p, w))
        return out[:, 0] if x.ndim == 1 else out

    def xdot(self, x, u=None, w=None) -> np.ndarray:
        """State derivative (SI) for motor acceleration ``u`` (rad/s^2, default 0)."""
        return self._call(self.sym.f, x, u, w)

    def reaction(self, x, u=None, w=None) -> np.ndarray:
        """Ground force on the shell (normal plus friction), floor frame, N."""
        return self._call(self.sym.reaction, x, u, w)

    def margins(self, x, u=None, w=None) -> np.ndarray:
        """No-jump margin ``N_z`` and no-slide margin ``mu N_z - |N_t|``, N."""
        return self._call(self.sym.margins, x, u, w)

    def motor_torque(self, x, u=None, w=None):
        """Torque the motor supplies to follow ``u``, N m (float, or array over a trajectory)."""
        tau = self._call(self.sym.motor_torque, x, u, w)
        return float(tau[0]) if np.ndim(x) == 1 else tau[0]

    def accel_bounds(self, x, w=None) -> np.ndarray:
        """Motor accelerations (rad/s^2) allowed by the torque and acceleration limits."""
        x = np.asarray(x, float)
        w = np.zeros((NW, 1)) if w is None else np.asarray(w, float).reshape(NW, -1)
        out = np.array(self.sym.accel_bounds(x.reshape(NX, -1), self.p, w))
        return out[:, 0] if x.ndim == 1 else out

    def energy(self, x):
        """Total mechanical energy, J."""
        x = np.asarray(x, float)
        out = np.array(self.sym.energy(x.reshape(NX, -1), self.p))[0]
        return float(out[0]) if x.ndim == 1 else out

    def power(self, x, u=None, w=None) -> np.ndarray:
        """Motor, damping and external power, W (rows for a trajectory)."""
        return self._call(self.sym.power, x, u, w)


# --- The reduced model: the spin symmetry of the spherical shell -------------------------------
#
# The shell is spherically symmetric, so turning it about its motor axis by an angle a while turning
# the motor back by a leaves every physical quantity unchanged: the dynamics depend on the shell
# orientation T and the motor angle theta only through the pendulum frame P = T Rz(theta).  The
# reduced state z (10) = (x, y, quaternion of P, omega, theta_dot) is what predictions and
# optimisation need; the shell's own angle about its axis only matters for drawing it.

NZ = 10
REDUCED_NAMES = ("x", "y", "pw", "px", "py", "pz", "wx", "wy", "wz", "theta_dot")
REDUCED = StateSlices(slice(0, 2), slice(2, 6), slice(6, 9), 9, slice(6, 10))


@dataclass(frozen=True)
class ReducedModel:
    """Rollbot's equations in the pendulum frame (10 states), as CasADi Functions over ``(z, u, p, w)``.

    Attributes
    ----------
    f : Function (z, u, p, w) -> zdot
    reaction, margins, motor_torque : Function (z, u, p, w) -> ...
        As in ``SymbolicModel``.
    """

    f: ca.Function
    reaction: ca.Function
    margins: ca.Function
    motor_torque: ca.Function


@functools.lru_cache(maxsize=None)
def reduced_model() -> ReducedModel:
    """Build (once per process) the pendulum-frame model from the full one."""
    sym = symbolic_model()
    z, u = ca.SX.sym("z", NZ), ca.SX.sym("u", NU)
    p, w = ca.SX.sym("p", NP), ca.SX.sym("w", NW)
    R = REDUCED
    # the full state with the shell turned so that theta = 0
    x = ca.vertcat(z[R.position], z[R.quaternion], z[R.omega], 0.0, z[R.theta_dot])
    xdot = sym.f(x, u, p, w)
    motor_axis = ca.mtimes(quat_to_matrix(z[R.quaternion]), _EZ)
    frame_rate = z[R.omega] + z[R.theta_dot] * motor_axis  # angular velocity of the pendulum frame
    zdot = ca.vertcat(xdot[POS], quat_derivative(z[R.quaternion], frame_rate), xdot[OMEGA], u)
    ins, names = [z, u, p, w], ["z", "u", "p", "w"]
    return ReducedModel(
        ca.Function("rollbot_reduced_f", ins, [zdot], names, ["zdot"]),
        ca.Function("rollbot_reduced_reaction", ins, [sym.reaction(x, u, p, w)], names, ["N"]),
        ca.Function("rollbot_reduced_margins", ins, [sym.margins(x, u, p, w)], names, ["margins"]),
        ca.Function("rollbot_reduced_motor_torque", ins, [sym.motor_torque(x, u, p, w)], names, ["tau_m"]),
    )


def to_reduced(x) -> np.ndarray:
    """Reduced state (10,) of a full state (11,): the pendulum frame ``P = T Rz(theta)``."""
    x = np.asarray(x, float)
    half = 0.5 * x[THETA]
    q = quat_multiply_np(x[QUAT], [math.cos(half), 0.0, 0.0, math.sin(half)])
    return np.concatenate([x[POS], q, x[OMEGA], [x[THETA_DOT]]])


def from_reduced(z, theta: float = 0.0) -> np.ndarray:
    """A full state (11,) with motor angle ``theta`` (rad) for a reduced state (10,)."""
    z = np.asarray(z, float)
    half = -0.5 * theta
    q = quat_multiply_np(z[REDUCED.quaternion], [math.cos(half), 0.0, 0.0, math.sin(half)])
    return np.concatenate([z[REDUCED.position], q, z[REDUCED.omega], [theta, z[REDUCED.theta_dot]]])


def motor_axis(x) -> np.ndarray:
    """Motor axis (body z') in the floor frame for a state (11,) or trajectory (11, N)."""
    w, a, b, c = np.asarray(x, float)[QUAT]
    s = 2.0 / (w * w + a * a + b * b + c * c)
    return np.array([s * (a * c + b * w), s * (b * c - a * w), 1 - s * (a * a + b * b)])


def heading(x) -> np.ndarray | float:
    """Azimuth of the motor axis' horizontal projection, rad (the paper's gamma)."""
    axis = motor_axis(x)
    return np.arctan2(axis[1], axis[0])


def tilt(x) -> np.ndarray | float:
    """Angle between the motor axis and the floor normal, rad (the paper's xi)."""
    axis = motor_axis(x)
    return np.arccos(np.clip(axis[2] / np.linalg.norm(axis, axis=0), -1.0, 1.0))
