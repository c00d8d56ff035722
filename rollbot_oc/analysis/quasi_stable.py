"""Quasi-stable states: Rollbot revolving steadily about a vertical axis (paper eqn "quasi").

At a constant driving speed ``omega0`` Rollbot can revolve about a vertical
axis ``l`` at a rate ``Omega``: in a frame that turns with it, nothing moves.
In the paper's frame at t = 0 (origin on ``l``, x towards the contact point,
motor axis ``z' = (sin xi, 0, cos xi)``, pendulum at motor angle ``theta0``)
the shell spins at ``-omega0 z'``, so ``omega = Omega z - omega0 z'``, the
contact point runs on a circle of radius ``R0 = omega0 R sin(xi) / Omega``,
and the moment balance about the contact point reads

    m u x (-g z + Omega^2 (R0 x + u - (u.z) z)) + M Omega^2 R0 R y
        - k0 (Omega z - omega0 z') + I Omega omega0 sin(xi) y = 0.

Regular unknowns.  Writing ``Omega = kappa omega0`` (so ``R0 = R sin(xi) /
kappa``) the equation becomes ``A0 + omega0 A1 + omega0^2 A2 = 0`` with
``A0 = m u x (-g z)`` (whose z component vanishes identically), ``A1`` the
damping moment and ``A2`` the inertial moments.  Solving for ``(kappa, theta0,
xi)`` the x and y components as they are and the z component divided by
``omega0`` (``A1_z + omega0 A2_z``; ``A2_z`` alone when ``k0 = 0``) keeps the
equations regular down to ``omega0 = 0``, where they give the limit the paper
states: ``theta0 = 0``, ``xi = phi``, ``kappa = cos(phi)``, ``R0 = R tan(phi)``.

Branches.  The *slow* branch (pendulum near the bottom, ``theta0`` near 0)
starts at rest and is the one the paper's experiments and controller use.  The
*fast* branch has the pendulum near the top (``theta0`` near pi) and revolves
the other way (``Omega < 0``, so ``R0 < 0`` in the signed definition above: the
centre of curvature lies on the other side).  Every result names its branch.

Solving.  A curve's speeds are solved together: a coarse continuation
(steps of 0.25 rad/s from omega0 = 0, tangent predictor from implicit
differentiation, one ``mapaccum`` call) gives a cubic Hermite predictor for
every speed, and a damped Newton iteration over a mapped CasADi Function
corrects all of them at once.  A speed where that fails, that ends far from
its predictor (another branch) or that lies beyond the last point the coarse
continuation could follow (a fold) is reached instead by adaptive
continuation (``_continue``) from the last good state below it.

Check against the full model.  Every solution is turned into a full state of
``dynamics`` and the full equations of motion are evaluated there: a relative
equilibrium must satisfy ``omega_dot = Omega z x omega``.  That residual
(``full_residual``) ties the closed form to the general model; results with
a residual above ``FULL_RESIDUAL_TOL`` are marked not converged.

The states are those of a level floor: a slope breaks the symmetry and leaves
no steady revolving state; it is a disturbance the controllers reject.
"""

from __future__ import annotations

import bisect
import functools
import math
from dataclasses import dataclass, field, fields

import casadi as ca
import numpy as np
from scipy.interpolate import CubicHermiteSpline

from rollbot_oc.model.dynamics import NU, NW, OMEGA, POS, QUAT, symbolic_model
from rollbot_oc.core.errors import ConfigError, NumericalFailure
from rollbot_oc.core.fastcall import fast_map
from rollbot_oc.model.params import PARAM_VECTOR_FIELDS, ParamView, RollbotParams
from rollbot_oc.core.reproducible import matmul
from rollbot_oc.model.rotations import quat_multiply_np

__all__ = [
    "BRANCHES", "FULL_RESIDUAL_TOL", "QuasiStableState", "quasi_stable_state",
    "quasi_stable_curve", "quasi_symbolic", "RadiusMap", "level",
]

BRANCHES = ("slow", "fast")
FULL_RESIDUAL_TOL = 1e-9  # rad/s^2, residual of the full equations at a returned state
_EX, _EY, _EZ = ca.DM([1, 0, 0]), ca.DM([0, 1, 0]), ca.DM([0, 0, 1])


def level(params: RollbotParams) -> RollbotParams:
    """The same robot on a level floor (quasi-stable states exist only there)."""
    return params if params.slope == 0 else params.replace(slope=0.0)


@dataclass(frozen=True)
class QuasiSymbolic:
    """CasADi Functions of the quasi-stable problem, unknowns ``z = (kappa, theta0, xi)``.

    Attributes
    ----------
    residual : Function (z, omega0, p) -> (3,)
        The regularised closed-form equations (module doc).
    state : Function (z, omega0, p) -> x (11,)
        The full state at t = 0 in the paper's frame (revolution axis at the
        origin, contact point on +x).
    full_residual : Function (z, omega0, p) -> (3,)
        ``omega_dot - Omega z x omega`` of the full equations at that state, rad/s^2.
    solve : Function (z_guess, omega0, p) -> z
        Newton's method on ``residual`` with its AD Jacobian.
    outputs : Function (z, omega0, p) -> (Omega, R0, speed, N_z, slide margin, motor torque)
    """

    residual: ca.Function
    state: ca.Function
    full_residual: ca.Function
    solve: ca.Function
    outputs: ca.Function


def _geometry(z, omega0, p):
    kappa, theta0, xi = z[0], z[1], z[2]
    P = ParamView(p)
    R, r0, phi = P.R, P.r0, P.phi
    T = ca.vertcat(ca.horzcat(ca.cos(xi), 0, ca.sin(xi)), ca.horzcat(0, 1, 0), ca.horzcat(-ca.sin(xi), 0, ca.cos(xi)))
    r_body = r0 * ca.vertcat(ca.sin(phi) * ca.cos(theta0), ca.sin(phi) * ca.sin(theta0), -ca.cos(phi))
    u = R * _EZ + ca.mtimes(T, r_body)
    z_axis = ca.mtimes(T, _EZ)
    R0 = R * ca.sin(xi) / kappa
    return kappa, theta0, xi, T, u, z_axis, R0


def _closed_form(z, omega0, p):
    """Regularised paper eqn 'quasi' (see module doc)."""
    kappa, theta0, xi, T, u, z_axis, R0 = _geometry(z, omega0, p)
    P = ParamView(p)
    m, M, I, k0, g, R = P.m, P.M, P.I, P.k0, P.g, P.R
    u_h = u - ca.dot(u, _EZ) * _EZ
    A0 = m * ca.cross(u, -g * _EZ)
    A1 = -k0 * (kappa * _EZ - z_axis)
    A2 = m * kappa**2 * ca.cross(u, R0 * _EX + u_h) + M * kappa**2 * R0 * R * _EY + I * kappa * ca.sin(xi) * _EY
    return ca.vertcat(A0[0] + omega0 * A1[0] + omega0**2 * A2[0], A0[1] + omega0**2 * A2[1],
                      A1[2] + omega0 * A2[2])


def _full_state(z, omega0, p):
    kappa, theta0, xi, T, u, z_axis, R0 = _geometry(z, omega0, p)
    omega = kappa * omega0 * _EZ - omega0 * z_axis
    quat = ca.vertcat(ca.cos(xi / 2), 0, ca.sin(xi / 2), 0)  # rotation about y by xi
    return ca.vertcat(R0, 0, quat, omega, theta0, omega0), omega, kappa * omega0, R0


@functools.lru_cache(maxsize=None)
def quasi_symbolic() -> QuasiSymbolic:
    """Build (once per process) the quasi-stable Functions and Newton solver."""
    sym = symbolic_model()
    z, omega0 = ca.SX.sym("z", 3), ca.SX.sym("omega0")
    p = ca.SX.sym("p", len(PARAM_VECTOR_FIELDS))
    x, omega, Omega, R0 = _full_state(z, omega0, p)
    u0, w0 = ca.DM.zeros(NU), ca.DM.zeros(NW)
    xdot = sym.f(x, u0, p, w0)
    full_res = xdot[6:9] - ca.cross(Omega * _EZ, omega)
    margins = sym.margins(x, u0, p, w0)
    residual = ca.Function("quasi_residual", [z, ca.vertcat(omega0, p)], [_closed_form(z, omega0, p)])
    newton = ca.rootfinder("quasi_newton", "newton", residual,
                           {"abstol": 1e-13, "max_iter": 60, "error_on_fail": False,
                            "show_eval_warnings": False})
    zg, w_in, p_in = ca.MX.sym("z", 3), ca.MX.sym("omega0"), ca.MX.sym("p", len(PARAM_VECTOR_FIELDS))
    solve = ca.Function("quasi_solve", [zg, w_in, p_in], [newton(zg, ca.vertcat(w_in, p_in))],
                        ["z_guess", "omega0", "p"], ["z"])
    outputs = ca.Function(
        "quasi_outputs", [z, omega0, p],
        [ca.vertcat(Omega, R0, omega0 * ParamView(p).R * ca.sin(z[2]), margins, sym.motor_torque(x, u0, p, w0))],
        ["z", "omega0", "p"], ["out"])
    return QuasiSymbolic(
        ca.Function("quasi_residual", [z, omega0, p], [_closed_form(z, omega0, p)], ["z", "omega0", "p"], ["res"]),
        ca.Function("quasi_state", [z, omega0, p], [x], ["z", "omega0", "p"], ["x"]),
        ca.Function("quasi_full_residual", [z, omega0, p], [full_res], ["z", "omega0", "p"], ["res"]),
        solve, outputs)


def _start(branch: str, params: RollbotParams) -> np.ndarray:
    """The analytic limit at omega0 = 0 of each branch, ``(kappa, theta0, xi)``.

    Slow: at rest with the pendulum straight down, ``xi = phi``.  Fast: the
    inverted rest state, pendulum straight up, motor axis pointing down
    (``xi = pi - phi``), revolving the other way (``kappa = -cos(phi)``).
    """
    if branch == "slow":
        return np.array([math.cos(params.phi), 0.0, params.phi])
    if branch == "fast":
        return np.array([-math.cos(params.phi), math.pi, math.pi - params.phi])
    raise ConfigError(f"branch = {branch!r}; valid are {', '.join(BRANCHES)}")


@dataclass(frozen=True)
class QuasiStableState:
    """A quasi-stable (steadily revolving) state of Rollbot on a level floor (SI units, radians).

    Attributes
    ----------
    omega0 : float
        Driving speed, rad/s.
    Omega : float
        Revolving rate about the vertical axis, rad/s (positive counter-clockwise from above).
    theta0 : float
        Motor angle of the pendulum in the paper's frame (0 = on the side of
        the revolution axis' ... see module doc), rad.
    xi : float
        Tilt of the motor axis from the vertical, rad.
    R0 : float
        Signed revolving radius ``omega0 R sin(xi) / Omega``, m; positive when
        the motor axis' horizontal projection points away from the centre of
        curvature (slow branch), negative on the fast branch.
    branch : str
        ``"slow"`` or ``"fast"``.
    converged : bool
        Newton converged and the full equations hold to ``FULL_RESIDUAL_TOL``.
    residual : float
        Largest residual of the closed-form equations.
    full_residual : float
        Largest residual of the full equations of motion at this state, rad/s^2.
    kappa : float
        ``Omega / omega0`` (the solver's unknown; finite at omega0 = 0).
    speed : float
        Speed of the shell centre, m/s.
    normal_force : float
        No-jump margin (normal force), N.
    slide_margin : float
        No-slide margin ``mu N_z - |N_t|``, N.
    motor_torque : float
        Steady motor torque (it balances the damping), N m.
    params : RollbotParams
        The robot (not part of ``to_dict``).
    """

    omega0: float
    Omega: float
    theta0: float
    xi: float
    R0: float
    branch: str
    converged: bool
    residual: float
    full_residual: float
    kappa: float
    speed: float
    normal_force: float
    slide_margin: float
    motor_torque: float
    params: RollbotParams = field(repr=False, compare=False)

    @property
    def unknowns(self) -> np.ndarray:
        """``(kappa, theta0, xi)``, the solver's unknowns."""
        return np.array([self.kappa, self.theta0, self.xi])

    def state(self, centre=(0.0, 0.0), phase: float = 0.0) -> np.ndarray:
        """The full state (11,) of this revolving motion about ``centre`` (m).

        ``phase`` (rad) is the direction from the centre of curvature to the
        robot's reference direction, the paper's gamma: the robot sits at
        ``centre + R0 (cos phase, sin phase)`` with its motor axis' horizontal
        projection along ``(cos phase, sin phase)``.
        """
        x = np.array(quasi_symbolic().state(self.unknowns, self.omega0, level(self.params).vector())).ravel()
        c, s_ = math.cos(phase), math.sin(phase)
        rot = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
        x[POS] = matmul(rot[:2, :2], x[POS]) + np.asarray(centre, float)
        x[QUAT] = quat_multiply_np([math.cos(phase / 2), 0.0, 0.0, math.sin(phase / 2)], x[QUAT])
        x[OMEGA] = matmul(rot, x[OMEGA])
        return x

    def to_dict(self) -> dict:
        """JSON-ready record (the CLI's ``quasi --json`` objects)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "params"}


def _check_speed(omega0, params):
    """Raise for the first driving speed (rad/s; a number or an array) outside [0, max_speed]."""
    speeds = np.atleast_1d(np.asarray(omega0, float))
    bad = ~(np.isfinite(speeds) & (speeds >= 0.0) & (speeds <= params.max_speed))
    if bad.any():
        raise ConfigError(f"omega0 = {float(speeds[np.argmax(bad)])!r} rad/s is out of range: valid is [0, max_speed] = "
                         f"[0, {params.max_speed:.4g}] (raise max_speed in the parameters to go further)")


def _check_damped(params):
    if not params.k0 > 0:
        raise ConfigError(f"k0 = {params.k0!r}: quasi-stable analysis needs damping k0 > 0 N m s; without it the "
                         "revolving states are not isolated (the robot can also roll straight on)")


# The batched route.  A coarse continuation (steps of _COARSE_STEP, tangent predictor, _COARSE_NEWTON Newton
# iterations, all in one mapaccum call) gives z and dz/domega0 on a grid; their cubic Hermite interpolant predicts
# every requested speed; a damped Newton iteration polishes all of them at once.
_COARSE_STEP = 0.25  # rad/s: the continuation's largest step
_COARSE_NEWTON = 4
_COARSE_TOL = 1e-8  # largest closed-form residual of a trusted coarse point
_MAX_JUMP = 0.2  # largest Newton correction of a trusted coarse point (as _continue's max_jump)
_PREDICTOR_TOL = 1e-2  # largest |z - predictor| of an accepted point: more is another branch
_NEWTON_ITER = 8
_STEP_TOL = 1e-8  # a Newton step this small (inf-norm) ends the iteration: the error after it is about its square
_TRUST = 0.1  # damping: largest Newton step (inf-norm)


def quasi_stable_curve(omegas, params: RollbotParams | None = None, branch: str = "slow") -> list[QuasiStableState]:
    """Quasi-stable states along a branch, followed from omega0 = 0.

    All speeds are solved at once (batched Newton, see ``_solve_batched``);
    a speed that fails there is reached by adaptive continuation from the
    last good state below it, so the result is the continuation's.

    Parameters
    ----------
    omegas : array_like
        Driving speeds, rad/s, in [0, max_speed]; returned in the order given.
    params : RollbotParams, optional
        The robot (the slope is ignored: see module doc).
    branch : {"slow", "fast"}

    Returns
    -------
    list of QuasiStableState
        One per speed; a state that could not be solved has ``converged``
        False and its residuals say by how much.
    """
    params = params or RollbotParams()
    omegas, Z, rows, ok = _curve(omegas, params, branch)
    return _states(omegas, Z, rows, ok, params, branch)


def _curve(omegas, params: RollbotParams, branch: str, batched: bool = True):
    """Solve a branch at ``omegas`` (rad/s): ``(omegas, Z, rows, ok)`` aligned with the speeds given.

    ``Z`` (n, 3) holds the unknowns, ``rows`` (n, 12) the ``check`` outputs
    (closed-form residual, full residual, Omega, R0, speed, N_z, slide margin,
    motor torque) and ``ok`` (n,) says which converged.  ``batched=False`` is
    the continuation route alone (speed by speed, kept for comparison).
    """
    omegas = np.asarray(omegas, float).ravel()
    _check_speed(omegas, params)
    _check_damped(params)
    z_start = _start(branch, params)
    speeds, inverse = np.unique(omegas, return_inverse=True)
    Z, rows, ok = np.full((speeds.size, 3), np.nan), np.full((speeds.size, 12), np.nan), np.zeros(speeds.size, bool)
    if batched:
        _solve_batched(speeds, Z, rows, ok, z_start, params)
    _follow(speeds, Z, rows, ok, z_start, params)
    return omegas, Z[inverse], rows[inverse], ok[inverse]


def _states(omegas, Z, rows, ok, params: RollbotParams, branch: str) -> list[QuasiStableState]:
    """``QuasiStableState`` objects from the arrays of ``_curve``."""
    residual, full = np.abs(rows[:, 0:3]).max(axis=1), np.abs(rows[:, 3:6]).max(axis=1)
    return [QuasiStableState(w, out[0], z[1], z[2], out[1], branch, good, res, fres, z[0], *out[2:], params)
            for w, z, out, good, res, fres in zip(omegas.tolist(), Z.tolist(), rows[:, 6:].tolist(), ok.tolist(),
                                                   residual.tolist(), full.tolist())]


def _converged(Z, rows) -> np.ndarray:
    """Which solutions (``Z`` and ``rows`` as in ``_curve``) are finite and satisfy the closed form and the full
    equations."""
    return (np.all(np.isfinite(Z), axis=-1) & (np.abs(rows[..., 0:3]).max(axis=-1) < 1e-9)
            & (np.abs(rows[..., 3:6]).max(axis=-1) <= FULL_RESIDUAL_TOL))


def _follow(speeds, Z, rows, ok, z_start, params: RollbotParams) -> None:
    """Continuation to every speed not solved yet, from the last good state below it (fills the arrays in place).

    ``speeds`` are increasing; a failed speed keeps the continuation's last
    attempt (``ok`` False) and the next one starts again from the last good state.
    """
    if ok.all():
        return
    check, p = _batched().check, level(params).vector()
    z, w_prev = z_start, 0.0
    for i, w in enumerate(speeds.tolist()):
        if not ok[i]:
            Z[i], solved = _continue(z, w_prev, w, params)
            rows[i] = np.array(check(Z[i], w, p)).ravel()
            ok[i] = solved and _converged(Z[i], rows[i])
        if ok[i]:
            z, w_prev = Z[i], w


def _continue(z, w_from, w_to, params, max_step: float = _COARSE_STEP, max_jump: float = _MAX_JUMP,
              min_step: float = 1e-4):
    """Follow the branch from ``w_from`` to ``w_to`` (rad/s) with adaptive steps.

    Each step predicts from the secant through the last two solutions and
    corrects with Newton; a step that fails or jumps (a different branch) is
    halved, down to ``min_step``.  Returns ``(z, ok)``.
    """
    w, h, z_prev, w_prev = w_from, max_step, None, None
    while w < w_to:
        w_try = min(w + h, w_to)
        guess = z if z_prev is None else z + (z - z_prev) * (w_try - w) / (w - w_prev)
        z_new, ok = _newton(guess, w_try, params)
        if ok and np.abs(z_new - z).max() <= max_jump and np.abs(_residual(z_new, w_try, params)).max() < 1e-9:
            z_prev, w_prev, z, w = z, w, z_new, w_try
            h = min(1.5 * h, max_step)
        elif h > min_step:
            h /= 2
        else:
            return z_new, False
    return z, True


def _newton(z_guess, omega0, params) -> tuple[np.ndarray, bool]:
    z = np.array(quasi_symbolic().solve(z_guess, omega0, level(params).vector())).ravel()
    return z, bool(np.all(np.isfinite(z)))


def _residual(z, omega0, params) -> np.ndarray:
    return np.array(quasi_symbolic().residual(z, omega0, level(params).vector())).ravel()


@dataclass(frozen=True)
class _BatchFunctions:
    """SX Functions of the batched route, all ``(z, omega0, p) -> ...`` except ``coarse``."""

    newton: ca.Function  # the Newton step -J^-1 res
    tangent: ca.Function  # dz/domega0 along the branch (implicit differentiation)
    coarse: ca.Function  # ([z; omega0], omega0_next, p) -> ([z; omega0]_next, [tangent; |res|; |correction|])
    check: ca.Function  # [res (3); full residual (3); Omega, R0, speed, N_z, slide margin, motor torque]
    slope: ca.Function  # dR0/domega0 along the branch, m s/rad


@functools.lru_cache(maxsize=None)
def _batched() -> _BatchFunctions:
    """Build (once per process) the Functions of the batched route from ``quasi_symbolic``."""
    q = quasi_symbolic()
    z, w, w_next = ca.SX.sym("z", 3), ca.SX.sym("omega0"), ca.SX.sym("omega0_next")
    p = ca.SX.sym("p", len(PARAM_VECTOR_FIELDS))
    res = q.residual(z, w, p)
    jac = ca.jacobian(res, z)
    cse = {"cse": True}  # common subexpressions once: fewer instructions per point
    newton = ca.Function("quasi_newton_step", [z, w, p], [-ca.solve(jac, res)], ["z", "omega0", "p"], ["step"], cse)
    tangent = ca.Function("quasi_tangent", [z, w, p], [-ca.solve(jac, ca.jacobian(res, w))],
                          ["z", "omega0", "p"], ["dz"], cse)
    guess = z + (w_next - w) * tangent(z, w, p)
    z_next = guess
    for _ in range(_COARSE_NEWTON):
        z_next = z_next + newton(z_next, w_next, p)
    info = ca.vertcat(tangent(z_next, w_next, p), ca.norm_inf(q.residual(z_next, w_next, p)),
                      ca.norm_inf(z_next - guess))
    coarse = ca.Function("quasi_coarse_step", [ca.vertcat(z, w), w_next, p], [ca.vertcat(z_next, w_next), info],
                         ["zw", "omega0_next", "p"], ["zw_next", "info"], cse)
    check = ca.Function("quasi_check", [z, w, p], [ca.vertcat(res, q.full_residual(z, w, p), q.outputs(z, w, p))],
                        ["z", "omega0", "p"], ["out"], cse)
    R0 = ParamView(p).R * ca.sin(z[2]) / z[0]
    slope = ca.Function("quasi_slope", [z, w, p], [ca.mtimes(ca.jacobian(R0, z), tangent(z, w, p))],
                        ["z", "omega0", "p"], ["dR0"], cse)
    return _BatchFunctions(newton, tangent, coarse, check, slope)


@functools.lru_cache(maxsize=64)
def _coarse_run(steps: int) -> ca.Function:
    return _batched().coarse.mapaccum(steps)


def _coarse(w_max: float, z_start, p):
    """The coarse continuation over ``[0, w_max]`` (rad/s): ``(w_trusted, spline)``.

    ``spline`` is the cubic Hermite spline of z(omega0) through the grid
    points (values and AD tangents) up to the last trusted one, at
    ``w_trusted``; ``(0.0, None)`` if there is none beyond omega0 = 0.
    """
    steps = math.ceil(w_max / _COARSE_STEP)
    if steps == 0:
        return 0.0, None
    grid = np.linspace(0.0, w_max, steps + 1)  # the first step, 0 to 0, gives the tangent at the start
    zw, info = (np.array(v) for v in _coarse_run(steps + 1)(np.append(z_start, 0.0), grid, p))
    trusted = np.all(np.isfinite(info), axis=0) & (info[3] <= _COARSE_TOL) & (info[4] <= _MAX_JUMP)
    last = steps if trusted.all() else int(np.argmin(trusted)) - 1  # trusted grid points: 0..last
    if last < 1:
        return 0.0, None
    return grid[last], CubicHermiteSpline(grid[:last + 1], zw[:3, :last + 1].T, info[:3, :last + 1].T, axis=0)


def _solve_batched(speeds, Z, rows, ok, z_start, params: RollbotParams) -> None:
    """All ``speeds`` (increasing, rad/s) at once, filling ``Z``, ``rows`` and ``ok`` (as in ``_curve``) in place.

    Predictor from ``_coarse``; speeds beyond its last trusted point (a fold)
    are left unsolved (``ok`` False) for ``_follow``.  A point is accepted if
    Newton converged, both residuals are small and it stayed within
    ``_PREDICTOR_TOL`` of its predictor (else it jumped to another branch).
    """
    if speeds.size == 0:
        return
    p = level(params).vector()
    w_trusted, spline = _coarse(float(speeds[-1]), z_start, p)
    reach = speeds <= w_trusted
    W = speeds[reach]
    m = W.size
    if m == 0:
        return
    predicted = spline(W) if spline is not None else np.tile(z_start, (m, 1))  # speeds 0 only
    z, done = predicted.copy(), np.zeros(m, bool)
    newton = fast_map(_batched().newton, m, shared=(2,))
    for _ in range(_NEWTON_ITER):
        step = newton(z.ravel(), W, p)[0].reshape(m, 3)
        size = np.abs(step).max(axis=1)
        z += step * np.minimum(1.0, _TRUST / np.maximum(size, _TRUST))[:, None]
        done = size <= _STEP_TOL
        if done.all():
            break
    out = fast_map(_batched().check, m, shared=(2,))(z.ravel(), W, p)[0].reshape(m, 12).copy()
    Z[reach], rows[reach] = z, out
    ok[reach] = done & _converged(z, out) & (np.abs(z - predicted).max(axis=1) <= _PREDICTOR_TOL)


def quasi_stable_state(omega0: float, params: RollbotParams | None = None, branch: str = "slow") -> QuasiStableState:
    """The quasi-stable state at one driving speed ``omega0`` (rad/s) on ``branch``.

    Raises
    ------
    ConfigError
        If ``omega0`` is out of [0, max_speed], the branch is unknown or ``k0`` is 0.
    """
    return quasi_stable_curve([omega0], params, branch)[0]


class RadiusMap:
    """The slow branch's revolving radius ``R0(omega0)``, its slope and its inverse, as fast callables.

    Built once from the slow branch at the knots (``quasi_stable_curve``'s
    batched solve) with the exact slope ``dR0/domega0`` at every knot
    (implicit differentiation of the quasi-stable equations, AD), then evaluated by cubic Hermite
    interpolation: fourth-order accurate between knots and a few microseconds
    per call, which is what a 100 Hz controller needs.

    Parameters
    ----------
    params : RollbotParams, optional
        The robot; the prototype by default.
    omega_max : float, optional
        Upper end of the map, rad/s; ``params.max_speed`` by default.
    knots : int
        Number of knots.

    Raises
    ------
    ConfigError
        If ``k0`` is zero, or ``R0`` is not increasing along the slow branch
        for these parameters (then no inverse map exists).
    NumericalFailure
        If the slow branch cannot be followed to ``omega_max``.
    """

    def __init__(self, params: RollbotParams | None = None, omega_max: float | None = None, knots: int = 121):
        self.params = params or RollbotParams()
        self.omega_max = float(self.params.max_speed if omega_max is None else omega_max)
        _check_speed(self.omega_max, self.params)
        _check_damped(self.params)
        omegas = np.linspace(0.0, self.omega_max, knots)
        _, Z, rows, ok = _curve(omegas, self.params, "slow")
        if not ok.all():
            raise NumericalFailure(f"radius map: the slow branch could not be followed to omega0 = "
                                   f"{omegas[np.argmin(ok)]:.4g} rad/s", "continuation failed")
        radii, kappas, p = rows[:, 7], Z[:, 0], level(self.params).vector()
        slopes = fast_map(_batched().slope, knots, shared=(2,))(Z.ravel(), omegas, p)[0].copy()
        if np.any(np.diff(radii) <= 0):
            bad = omegas[1:][np.diff(radii) <= 0][0]
            raise ConfigError(f"radius map: R0 stops increasing with omega0 at {bad:.4g} rad/s for these parameters; "
                             "no one-to-one map from radius to driving speed exists")
        self.omegas, self.radii, self.slopes, self.kappas = omegas, radii, slopes, kappas
        self._spline = CubicHermiteSpline(omegas, radii, slopes)
        self._dspline = self._spline.derivative()
        # per-interval cubic coefficients (highest power first) for the fast scalar inverse
        self._coeffs = [tuple(col) for col in self._spline.c.T]
        self._widths = list(np.diff(omegas))
        self._radii_list, self._omega_list = list(radii), list(omegas)

    @property
    def R_min(self) -> float:
        """Smallest revolving radius (at omega0 = 0, ``R tan(phi)``), m."""
        return float(self.radii[0])

    @property
    def R_max(self) -> float:
        """Largest revolving radius (at ``omega_max``), m."""
        return float(self.radii[-1])

    def radius(self, omega0):
        """Revolving radius ``R0`` (m) at driving speed ``omega0`` (rad/s), clipped to the map's range."""
        if isinstance(omega0, float):
            return self._cubic(omega0, 0)
        return self._spline(np.clip(omega0, 0.0, self.omega_max))

    def _cubic(self, omega0: float, derivative: int) -> float:
        """Scalar Hermite-spline value (0) or slope (1) with plain floats (fast path for controllers)."""
        w = min(max(omega0, 0.0), self.omega_max)
        i = min(bisect.bisect_right(self._omega_list, w) - 1, len(self._omega_list) - 2)
        c3, c2, c1, c0 = self._coeffs[i]
        t = w - self._omega_list[i]
        if derivative:
            return (3 * c3 * t + 2 * c2) * t + c1
        return ((c3 * t + c2) * t + c1) * t + c0

    def rate(self, omega0):
        """Revolving rate ``Omega`` (rad/s) at driving speed ``omega0`` (rad/s), interpolated."""
        w = np.clip(omega0, 0.0, self.omega_max)
        return w * np.interp(w, self.omegas, self.kappas)

    def slope(self, omega0):
        """``dR0/domega0`` (m s/rad) at driving speed ``omega0`` (rad/s)."""
        if isinstance(omega0, float):
            return self._cubic(omega0, 1)
        return self._dspline(np.clip(omega0, 0.0, self.omega_max))

    def omega(self, radius):
        """Driving speed (rad/s) whose quasi-stable radius is ``radius`` (m).

        Raises
        ------
        ConfigError
            If a radius is outside ``[R_min, R_max]``.
        """
        R = np.asarray(radius, float)
        if np.any(~np.isfinite(R)) or np.any(R < self.R_min - 1e-12) or np.any(R > self.R_max + 1e-12):
            raise ConfigError(f"radius = {radius!r} m is out of range: valid is [{self.R_min:.4f}, {self.R_max:.4f}] m "
                             f"(driving speeds 0 to {self.omega_max:.4g} rad/s)")
        if R.ndim == 0:
            return self._omega_scalar(float(R))
        return np.array([self._omega_scalar(float(r)) for r in R.ravel()]).reshape(R.shape)

    def _omega_scalar(self, R: float) -> float:
        """Invert the Hermite cubic of the knot interval holding ``R``: safeguarded Newton, pure floats."""
        i = min(max(bisect.bisect_right(self._radii_list, R) - 1, 0), len(self._radii_list) - 2)
        c3, c2, c1, c0 = self._coeffs[i]
        lo, hi = 0.0, self._widths[i]
        t = hi * (R - self._radii_list[i]) / (self._radii_list[i + 1] - self._radii_list[i])
        for _ in range(30):
            f = ((c3 * t + c2) * t + c1) * t + c0 - R
            if abs(f) <= 1e-14:
                break
            lo, hi = (t, hi) if f < 0 else (lo, t)
            d = (3 * c3 * t + 2 * c2) * t + c1
            t_new = t - f / d if d > 0 else 0.5 * (lo + hi)
            t = t_new if lo < t_new < hi else 0.5 * (lo + hi)
        return self._omega_list[i] + t

    def exact(self, omega0: float) -> tuple[float, float]:
        """``(R0, dR0/domega0)`` at ``omega0`` solved directly (Newton plus implicit differentiation)."""
        _, Z, rows, _ = _curve([omega0], self.params, "slow")
        return float(rows[0, 7]), float(_batched().slope(Z[0], omega0, level(self.params).vector()))
