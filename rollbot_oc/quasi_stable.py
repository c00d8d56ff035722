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

from rollbot_oc.dynamics import NU, NW, OMEGA, POS, QUAT, symbolic_model
from rollbot_oc.errors import ConfigError, NumericalFailure
from rollbot_oc.params import PARAM_VECTOR_FIELDS, RollbotParams
from rollbot_oc.rotations import quat_multiply_np

__all__ = [
    "BRANCHES", "FULL_RESIDUAL_TOL", "QuasiStableState", "quasi_stable_state",
    "quasi_stable_curve", "quasi_symbolic", "RadiusMap", "level",
]

BRANCHES = ("slow", "fast")
FULL_RESIDUAL_TOL = 1e-9  # rad/s^2, residual of the full equations at a returned state
_EX, _EY, _EZ = ca.DM([1, 0, 0]), ca.DM([0, 1, 0]), ca.DM([0, 0, 1])
_P = {name: i for i, name in enumerate(PARAM_VECTOR_FIELDS)}


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
    R, r0, phi = p[_P["R"]], p[_P["r0"]], p[_P["phi"]]
    T = ca.vertcat(ca.horzcat(ca.cos(xi), 0, ca.sin(xi)), ca.horzcat(0, 1, 0), ca.horzcat(-ca.sin(xi), 0, ca.cos(xi)))
    r_body = r0 * ca.vertcat(ca.sin(phi) * ca.cos(theta0), ca.sin(phi) * ca.sin(theta0), -ca.cos(phi))
    u = R * _EZ + ca.mtimes(T, r_body)
    z_axis = ca.mtimes(T, _EZ)
    R0 = R * ca.sin(xi) / kappa
    return kappa, theta0, xi, T, u, z_axis, R0


def _closed_form(z, omega0, p):
    """Regularised paper eqn 'quasi' (see module doc)."""
    kappa, theta0, xi, T, u, z_axis, R0 = _geometry(z, omega0, p)
    m, M, I, k0, g, R = (p[_P[k]] for k in ("m", "M", "I", "k0", "g", "R"))
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
        [ca.vertcat(Omega, R0, omega0 * p[_P["R"]] * ca.sin(z[2]), margins, sym.motor_torque(x, u0, p, w0))],
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
        x[POS] = rot[:2, :2] @ x[POS] + np.asarray(centre, float)
        x[QUAT] = quat_multiply_np([math.cos(phase / 2), 0.0, 0.0, math.sin(phase / 2)], x[QUAT])
        x[OMEGA] = rot @ x[OMEGA]
        return x

    def to_dict(self) -> dict:
        """JSON-ready record (the CLI's ``quasi --json`` objects)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "params"}


def _evaluate(z, omega0: float, params: RollbotParams, branch: str, solved: bool) -> QuasiStableState:
    q = quasi_symbolic()
    p = level(params).vector()
    residual = float(np.abs(np.array(q.residual(z, omega0, p))).max())
    full = float(np.abs(np.array(q.full_residual(z, omega0, p))).max())
    Omega, R0, speed, normal, slide, torque = np.array(q.outputs(z, omega0, p)).ravel()
    ok = bool(solved and np.all(np.isfinite(z)) and residual < 1e-9 and full <= FULL_RESIDUAL_TOL)
    return QuasiStableState(float(omega0), float(Omega), float(z[1]), float(z[2]), float(R0), branch, ok, residual,
                            full, float(z[0]), float(speed), float(normal), float(slide), float(torque), params)


def _check_speed(omega0, params):
    if not (math.isfinite(omega0) and 0.0 <= omega0 <= params.max_speed):
        raise ConfigError(f"omega0 = {float(omega0)!r} rad/s is out of range: valid is [0, max_speed] = "
                         f"[0, {params.max_speed:.4g}] (raise max_speed in the parameters to go further)")


def _check_damped(params):
    if not params.k0 > 0:
        raise ConfigError(f"k0 = {params.k0!r}: quasi-stable analysis needs damping k0 > 0 N m s; without it the "
                         "revolving states are not isolated (the robot can also roll straight on)")


def _newton(z_guess, omega0, params) -> tuple[np.ndarray, bool]:
    z = np.array(quasi_symbolic().solve(z_guess, omega0, level(params).vector())).ravel()
    return z, bool(np.all(np.isfinite(z)))


def quasi_stable_curve(omegas, params: RollbotParams | None = None, branch: str = "slow") -> list[QuasiStableState]:
    """Quasi-stable states along a branch, by continuation from omega0 = 0.

    Parameters
    ----------
    omegas : array_like
        Driving speeds, rad/s, in [0, max_speed]; solved in increasing order
        and returned in the order given.
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
    omegas = np.asarray(omegas, float).ravel()
    for w in omegas:
        _check_speed(w, params)
    _check_damped(params)
    z = _start(branch, params)
    w_prev, results = 0.0, {}
    for w in np.sort(omegas):
        z_new, solved = _continue(z, w_prev, w, params)
        results[w] = _evaluate(z_new, w, params, branch, solved)
        if results[w].converged:  # otherwise keep following from the last good state
            z, w_prev = z_new, w
    return [results[w] for w in omegas]


def _continue(z, w_from, w_to, params, max_step: float = 0.25, max_jump: float = 0.2, min_step: float = 1e-4):
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


def _residual(z, omega0, params) -> np.ndarray:
    return np.array(quasi_symbolic().residual(z, omega0, level(params).vector())).ravel()


def quasi_stable_state(omega0: float, params: RollbotParams | None = None, branch: str = "slow") -> QuasiStableState:
    """The quasi-stable state at one driving speed ``omega0`` (rad/s) on ``branch``.

    Raises
    ------
    ConfigError
        If ``omega0`` is out of [0, max_speed], the branch is unknown or ``k0`` is 0.
    """
    return quasi_stable_curve([omega0], params, branch)[0]


@functools.lru_cache(maxsize=None)
def _radius_with_slope() -> ca.Function:
    """``(z_guess, omega0, p) -> (R0, dR0/domega0, z)``; the slope by implicit differentiation through Newton."""
    q = quasi_symbolic()
    zg, w, p = ca.MX.sym("z", 3), ca.MX.sym("omega0"), ca.MX.sym("p", len(PARAM_VECTOR_FIELDS))
    z = q.solve(zg, w, p)
    R0 = p[_P["R"]] * ca.sin(z[2]) / z[0]
    return ca.Function("quasi_radius", [zg, w, p], [R0, ca.jacobian(R0, w), z], ["z_guess", "omega0", "p"],
                       ["R0", "dR0", "z"])


class RadiusMap:
    """The slow branch's revolving radius ``R0(omega0)``, its slope and its inverse, as fast callables.

    Built once from a continuation over ``[0, omega_max]`` with the exact slope
    ``dR0/domega0`` at every knot (implicit differentiation of the quasi-stable
    equations through CasADi's Newton solver), then evaluated by cubic Hermite
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
        fun = _radius_with_slope()
        p = level(self.params).vector()
        omegas = np.linspace(0.0, self.omega_max, knots)
        radii, slopes, kappas = np.empty(knots), np.empty(knots), np.empty(knots)
        z = _start("slow", self.params)
        for i, w in enumerate(omegas):
            z, ok = _continue(z, omegas[i - 1] if i else 0.0, w, self.params)
            R0, dR0, _ = fun(z, w, p)
            radii[i], slopes[i], kappas[i] = float(R0), float(dR0), z[0]
            if not ok or not _evaluate(z, w, self.params, "slow", ok).converged:
                raise NumericalFailure(f"radius map: the slow branch could not be followed to omega0 = {w:.4g} rad/s",
                                       "continuation failed")
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
        _check_speed(omega0, self.params)
        z, ok = _continue(_start("slow", self.params), 0.0, omega0, self.params)
        R0, dR0, _ = _radius_with_slope()(z, omega0, level(self.params).vector())
        return float(R0), float(dR0)
