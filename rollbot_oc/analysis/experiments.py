"""The paper's open-loop experiment, in simulation, and how a steady circle is measured.

Section "Open-loop Motion": Rollbot starts at rest with the mass at the
bottom, the motor is brought slowly to a constant driving speed ``omega0``,
and once the motion has settled the revolving radius ``R0``, revolving rate
``Omega`` and tilt ``xi`` of the motor axis are measured, as the paper did
with its motion capture.  These numbers come from the full nonlinear
simulation only; comparing them with the quasi-stable theory is the job of
the tests and of ``quasi_stable``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

from rollbot_oc.model.dynamics import rest_state
from rollbot_oc.core.errors import ConfigError, NumericalFailure
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.simulation.plant import SimulationResult, simulate

__all__ = ["fit_circle", "CircleFit", "OpenLoopMeasurement", "open_loop_run", "open_loop_experiment", "damped_modes",
           "check_open_loop"]


@dataclass(frozen=True)
class CircleFit:
    """Least-squares circle through planar points.

    Attributes
    ----------
    centre : numpy.ndarray (2,)
        Centre, m.
    radius : float
        Radius, m.
    rms : float
        Root-mean-square distance of the points from the circle, m.
    """

    centre: np.ndarray
    radius: float
    rms: float


def fit_circle(points) -> CircleFit:
    """Fit a circle to points (2, n) by algebraic least squares (Kasa), m.

    Exact for points on a circle; the bias of the algebraic fit under noise is
    of second order in the noise, negligible for simulated trajectories.
    """
    x, y = np.asarray(points, float)
    if x.size < 3:
        raise ValueError(f"fit_circle: needs at least 3 points, got {x.size}")
    A = np.column_stack([x, y, np.ones_like(x)])
    (D, E, F), *_ = np.linalg.lstsq(A, -(x**2 + y**2), rcond=None)
    centre = np.array([-D / 2, -E / 2])
    radius = math.sqrt(max(centre @ centre - F, 0.0))
    rms = float(np.sqrt(np.mean((np.hypot(x - centre[0], y - centre[1]) - radius) ** 2)))
    return CircleFit(centre, radius, rms)


@dataclass(frozen=True)
class OpenLoopMeasurement:
    """Steady revolving motion measured in a simulated open-loop run (SI units).

    Attributes
    ----------
    omega0 : float
        Driving speed, rad/s.
    R0 : float
        Radius of the circle fitted to the shell-centre path, m.
    Omega : float
        Revolving rate of the shell centre about the fitted centre, rad/s
        (positive counter-clockwise seen from above).
    xi : float
        Mean tilt of the motor axis from the floor normal, rad.
    settled : bool
        True if circles fitted to the two halves of the measuring window agree
        (radius within 0.5 %, centre within 1 % of the radius).
    drift : float
        Speed at which the fitted centre moves between the two halves, m/s
        (non-zero on a slope without feedback).
    centre : list of float
        Centre of the fitted circle, m.
    window : float
        Length of the measuring window, s.
    """

    omega0: float
    R0: float
    Omega: float
    xi: float
    settled: bool
    drift: float
    centre: list
    window: float

    def to_dict(self) -> dict:
        """The measurement as JSON-ready numbers."""
        return asdict(self)

    @classmethod
    def failed_dict(cls, omega0: float, reason: str) -> dict:
        """The JSON record of a run that could not be measured: nulls, ``settled`` False and the ``error``."""
        record = dict.fromkeys(f.name for f in fields(cls))
        return {**record, "omega0": float(omega0), "settled": False, "error": reason}


def _measure(result: SimulationResult, start: int, omega0: float) -> OpenLoopMeasurement:
    t, s = result.t[start:], result.position[:, start:]
    half = len(t) // 2
    whole, first, second = fit_circle(s), fit_circle(s[:, :half]), fit_circle(s[:, half:])
    angle = np.unwrap(np.arctan2(s[1] - whole.centre[1], s[0] - whole.centre[0]))
    omega_rev = float(np.polyfit(t, angle, 1)[0])
    shift = float(np.linalg.norm(second.centre - first.centre))
    settled = abs(first.radius - second.radius) <= 5e-3 * whole.radius and shift <= 1e-2 * whole.radius
    return OpenLoopMeasurement(
        omega0=float(omega0), R0=whole.radius, Omega=omega_rev, xi=float(np.mean(result.tilt[start:])),
        settled=bool(settled), drift=shift / (t[half] - t[0]), centre=whole.centre.tolist(), window=float(t[-1] - t[0]),
    )


def open_loop_run(omega0: float, params: RollbotParams | None = None, *, ramp_rate: float = 0.5,
                  settle: float = 40.0, duration: float | None = None,
                  dt: float = 0.01) -> tuple[OpenLoopMeasurement, SimulationResult]:
    """Ramp the driving speed from rest to ``omega0``, let it settle, and measure the circle.

    Parameters
    ----------
    omega0 : float
        Target driving speed, rad/s, in [0, max_speed]; must be > 0 to revolve.
    params : RollbotParams, optional
        Plant parameters (slope included); the prototype by default.
    ramp_rate : float
        Driving-speed ramp, rad/s^2 (slow, so the robot stays near the
        quasi-stable state).
    settle : float
        Time after the ramp before measuring, s (several recovery times).
    duration : float, optional
        Total run length, s.  By default the measuring window covers at least
        two revolutions (estimated from the motion itself), and 20 s at least.
    dt : float
        Control period, s.

    Returns
    -------
    (OpenLoopMeasurement, SimulationResult)

    Raises
    ------
    ConfigError
        On settings out of range (see ``check_open_loop``).
    NumericalFailure
        If the robot leaves the no-slip model (loses contact or slides); its
        ``status`` is the event and its ``result`` the run up to it.
    """
    params = params or RollbotParams()
    lead = check_open_loop(omega0, params, ramp_rate=ramp_rate, settle=settle, duration=duration)
    profile = lambda t: min(omega0, ramp_rate * t)  # noqa: E731
    first = duration if duration is not None else lead + 20.0
    result = simulate(rest_state(params), first, params=params, speed=profile, dt=dt)
    start = int(round(lead / dt))
    if duration is None and result.completed:
        # Extend the window to two revolutions at the measured rate (at most 300 s more).
        rate = abs(_measure(result, start, omega0).Omega)
        needed = min(4 * math.pi / max(rate, 1e-9), 300.0) - 20.0
        if needed > 0:
            more = simulate(result.x[:, -1], needed, params=params, speed=omega0, dt=dt)
            result = _concatenate(result, more)
    if not result.completed:
        event = result.events[0]
        raise NumericalFailure(f"open loop at omega0 = {omega0} rad/s: the robot left the no-slip model "
                               f"({event.kind} at t = {event.time:.2f} s)", event.kind, result)
    return _measure(result, start, omega0), result


def check_open_loop(omega0: float, params: RollbotParams, *, ramp_rate: float = 0.5, settle: float = 40.0,
                    duration: float | None = None) -> float:
    """Check the settings of ``open_loop_run`` before running it; returns the ramp and settling time, s.

    Raises
    ------
    ConfigError
        If ``omega0`` is not in (0, max_speed] rad/s, ``ramp_rate`` is not
        > 0 rad/s^2, or ``duration`` does not exceed the ramp and settling
        time by 5 s.
    """
    if not (math.isfinite(omega0) and 0 < omega0 <= params.max_speed):
        raise ConfigError(f"open loop: omega0 = {omega0!r} rad/s is out of range: valid is (0, {params.max_speed:.4g}]")
    if not (math.isfinite(ramp_rate) and ramp_rate > 0):
        raise ConfigError(f"open loop: ramp_rate = {ramp_rate!r} must be > 0 rad/s^2")
    lead = omega0 / ramp_rate + settle
    if duration is not None and not (math.isfinite(duration) and duration > lead + 5.0):
        raise ConfigError(f"open loop: duration = {duration!r} s is too short: it must exceed the ramp and "
                          f"settling time {lead:.1f} s by 5 s at least")
    return lead


def _concatenate(a: SimulationResult, b: SimulationResult) -> SimulationResult:
    return SimulationResult(
        a.params, a.dt, np.concatenate([a.t, a.t[-1] + b.t[1:]]), np.hstack([a.x, b.x[:, 1:]]),
        np.concatenate([a.command, b.command]), np.concatenate([a.speed_command, b.speed_command]),
        np.hstack([a.diag, b.diag]), a.events + b.events, np.concatenate([a.step_times, b.step_times]), a.info)


def open_loop_experiment(omegas, params: RollbotParams | None = None, **kwargs) -> list[OpenLoopMeasurement]:
    """``open_loop_run`` for each driving speed in ``omegas`` (rad/s); returns the measurements."""
    return [open_loop_run(float(w), params, **kwargs)[0] for w in omegas]


def damped_modes(signal, dt: float, order: int) -> np.ndarray:
    """Complex rates ``s = sigma + i omega`` (1/s) of the damped exponentials that make up a signal.

    The matrix-pencil method: the samples of a sum of ``order`` damped
    exponentials ``exp(s t)`` span a Hankel matrix of rank ``order``; the
    rates follow from the shift-invariance of its dominant right singular
    vectors.  Used to read decay rates and frequencies off a simulated
    response without any initial guess (so without knowing the answer).

    Parameters
    ----------
    signal : array_like (n,)
        Uniformly sampled real signal.
    dt : float
        Sampling period, s.
    order : int
        Number of exponentials to fit (a real damped oscillation counts twice).

    Returns
    -------
    numpy.ndarray (order,) complex
        The rates, sorted by decreasing real part.
    """
    y = np.asarray(signal, float).ravel()
    n = y.size
    if not 1 <= order < n // 3:
        raise ValueError(f"damped_modes: order = {order} must be in [1, {n // 3 - 1}] for {n} samples")
    L = n // 2
    hankel = np.lib.stride_tricks.sliding_window_view(y, L + 1)
    _, _, vh = np.linalg.svd(hankel, full_matrices=False)
    V = vh[:order].conj().T
    z = np.linalg.eigvals(np.linalg.pinv(V[:-1]) @ V[1:])
    rates = np.log(z.astype(complex)) / dt
    return rates[np.argsort(-rates.real, kind="stable")]
