"""The plant: full nonlinear simulation of Rollbot with a motor's limits and a sloped floor.

The plant advances in control periods ``dt`` (default 0.01 s, the 100 Hz of
the paper's motion capture).  Within a period the commanded motor
acceleration is held (zero-order hold) and the full equations of motion
(``dynamics``) are integrated by fixed-step RK4 with ``substeps`` steps, or by
CVODES for reference accuracy.  RK4 is the default because the right-hand side
is smooth within a period (the command is held), so the method keeps its
fourth order, and a fixed step makes a period one cheap, deterministic CasADi
call; ``tests/test_simulate.py`` checks it against CVODES at tight tolerance.

Motor model.  The controller commands either a driving speed or an
acceleration.  A speed command ``v`` becomes the acceleration that reaches it
by the end of the period, ``(v - theta_dot) / dt`` (a stiff speed loop, as a
BLDC driver has).  The acceleration is then clipped so the driving speed
stays within ``max_speed`` at the end of the period and within
``max_accel``, and, continuously inside the period, to what ``max_torque``
can deliver (``SymbolicModel.accel_bounds``): the motor saturates, it does
not fail.

Sensing.  The controller sees either measurements (``Sensor``: motion
capture, a gyroscope and the encoder with noise and latency) or, with
onboard sensing (``onboard.OnboardSensing``), the estimate of a filter fed by
an IMU sampled inside each period, the encoder and optional motion capture
(``plant_step(..., samples=m)`` gives the noise-free sensor signals).

Contact.  The equations assume the shell stays on the floor without slipping.
The simulator evaluates the no-jump margin (normal force) and the no-slide
margin (friction cone) at every step; where one turns negative the model no
longer describes the robot, so the event is recorded and, by default, the run
stops there rather than returning a wrong trajectory.
"""

from __future__ import annotations

import functools
import json
import math
import time
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from rollbot_oc.control.protocol import Command, Controller, ControllerBase, Observation  # noqa: F401 (the loop's protocol)
from rollbot_oc.model.dynamics import (
    NU, NW, NX, OMEGA, POS, QUAT, STATE_NAMES, THETA, THETA_DOT, RollbotModel, heading, motor_axis, motor_speed_clip, rk4,
    symbolic_model, tilt,
)
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.core.fastcall import FastFunction
from rollbot_oc.simulation.onboard import EstimationRecord, OnboardSensing
from rollbot_oc.core.outputs import save_npz
from rollbot_oc.model.params import ParamView, RollbotParams
from rollbot_oc.core.reproducible import norm
from rollbot_oc.simulation.sensors import body_signals, rotate_randomly

__all__ = ["Sensor", "Kick", "Event", "SimulationResult", "plant_step", "simulate"]

# Layout of the per-step diagnostics the plant returns with each step.
DIAG_NAMES = ("theta_ddot", "motor_torque", "Nx", "Ny", "Nz", "no_jump_margin", "no_slide_margin")
NDIAG = len(DIAG_NAMES)


def _period_integrator(dt: float, substeps: int, method: str, samples: int = 0) -> ca.Function:
    """``(x, a, p, w) -> x(dt)`` with the acceleration command ``a`` held over the period.

    With ``samples = m > 0`` (RK4 only) the period is integrated in ``m`` equal parts of
    ``ceil(substeps / m)`` steps each and the Function also returns the states at their ends (NX, m).
    """
    sym = symbolic_model()
    npar = sym.f.size1_in(2)
    if method == "rk4":
        x, a, p, w = ca.SX.sym("x", NX), ca.SX.sym("a", NU), ca.SX.sym("p", npar), ca.SX.sym("w", NW)
        if not samples:
            return ca.Function("rk4_period", [x, a, p, w], [rk4(sym.plant_rhs, x, dt, substeps, a, p, w)])
        ends, xi = [], x
        for _ in range(samples):
            xi = rk4(sym.plant_rhs, xi, dt / samples, -(-substeps // samples), a, p, w)
            ends.append(xi)
        return ca.Function("rk4_period_sampled", [x, a, p, w], [xi, ca.horzcat(*ends)])
    if samples:
        raise ValueError(f"plant_step: samples = {samples} needs method 'rk4', not {method!r}")
    if method == "cvodes":
        x, a, p, w = ca.SX.sym("x", NX), ca.SX.sym("a", NU), ca.SX.sym("p", npar), ca.SX.sym("w", NW)
        ode = {"x": x, "p": ca.vertcat(a, p, w), "ode": sym.plant_rhs(x, a, p, w)}
        integ = ca.integrator("cvodes_period", "cvodes", ode, 0.0, dt, {"reltol": 1e-11, "abstol": 1e-11})
        xm, am, pm, wm = ca.MX.sym("x", NX), ca.MX.sym("a", NU), ca.MX.sym("p", npar), ca.MX.sym("w", NW)
        return ca.Function("cvodes_period", [xm, am, pm, wm], [integ(x0=xm, p=ca.vertcat(am, pm, wm))["xf"]])
    raise ValueError(f"plant_step: method = {method!r}; valid are 'rk4', 'cvodes'")


@functools.lru_cache(maxsize=None)
def plant_step(dt: float = 0.01, substeps: int = 4, method: str = "rk4", samples: int = 0) -> ca.Function:
    """The plant over one control period, as a cached CasADi Function.

    Parameters
    ----------
    dt : float
        Control period, s.
    substeps : int
        RK4 steps per period (``method="rk4"``).
    method : {"rk4", "cvodes"}
        Fixed-step RK4, or CVODES with relative and absolute tolerance 1e-11.
    samples : int
        Onboard sensor samples per period (RK4 only; 0: none).  The period is
        then integrated in ``samples`` equal parts (``ceil(substeps / samples)``
        RK4 steps each, the same steps as without samples when ``samples``
        divides ``substeps``) and the noise-free sensor signals at the end of
        each part are returned too (``sensors.body_signals``).

    Returns
    -------
    casadi.Function
        ``(x, a_cmd, p, w) -> (x_next, diag)``: state after ``dt`` for
        commanded motor acceleration ``a_cmd`` (rad/s^2), and diagnostics at
        the start of the period in the order of ``DIAG_NAMES`` (applied
        acceleration, motor torque N m, ground force N, no-jump and no-slide
        margins N); with ``samples`` also ``signals`` (7, samples).
    """
    if not dt > 0 or substeps < 1 or samples < 0:
        raise ValueError(f"plant_step: dt = {dt} must be > 0 s, substeps = {substeps} >= 1 and samples = "
                         f"{samples} >= 0")
    sym = symbolic_model()
    npar = sym.f.size1_in(2)
    integrate = _period_integrator(dt, substeps, method, samples)
    x, a_cmd, p, w = ca.MX.sym("x", NX), ca.MX.sym("a_cmd", NU), ca.MX.sym("p", npar), ca.MX.sym("w", NW)
    a = motor_speed_clip(a_cmd, x[THETA_DOT], ParamView(p).max_speed, dt)
    if samples:
        xk, ends = integrate(x, a, p, w)
    else:
        xk = integrate(x, a, p, w)
    q = xk[QUAT]
    xk = ca.vertcat(xk[POS], q / ca.norm_2(q), xk[OMEGA.start:])
    bounds = sym.accel_bounds(x, p, w)
    a_applied = ca.fmin(ca.fmax(a, bounds[0]), bounds[1])
    diag = ca.vertcat(a_applied, sym.motor_torque(x, a_applied, p, w), sym.reaction(x, a_applied, p, w),
                      sym.margins(x, a_applied, p, w))
    outs, names = [xk, diag], ["x_next", "diag"]
    if samples:
        outs.append(ca.horzcat(*[body_signals()(ends[:, i], a, p, w) for i in range(samples)]))
        names.append("signals")
    step = ca.Function("plant_step", [x, a_cmd, p, w], outs, ["x", "a_cmd", "p", "w"], names)
    return step.expand() if method == "rk4" else step


@functools.lru_cache(maxsize=None)
def _speed_step(dt: float, substeps: int, method: str) -> ca.Function:
    """``plant_step`` driven by a driving-speed command (rad/s) through the motor's speed loop."""
    step = plant_step(dt, substeps, method)
    x, v, p, w = ca.MX.sym("x", NX), ca.MX.sym("v", NU), ca.MX.sym("p", step.size1_in(2)), ca.MX.sym("w", NW)
    x_next, diag = step(x, (v - x[THETA_DOT]) / dt, p, w)
    fun = ca.Function("plant_speed_step", [x, v, p, w], [x_next, diag], ["x", "v_cmd", "p", "w"], ["x_next", "diag"])
    return fun.expand() if method == "rk4" else fun


@dataclass
class Sensor:
    """Measurement model: Gaussian noise and a latency, seeded for reproducibility.

    Parameters
    ----------
    position_noise : float
        Standard deviation of the position noise, m.
    angle_noise : float
        Standard deviation of the orientation noise (a small random rotation), rad.
    gyro_noise : float
        Standard deviation of the angular-velocity noise, rad/s.
    speed_noise : float
        Standard deviation of the driving-speed noise, rad/s.
    latency : int
        Number of control periods between measuring and the controller seeing it.
    seed : int
        Seed of the noise generator.
    """

    position_noise: float = 0.0
    angle_noise: float = 0.0
    gyro_noise: float = 0.0
    speed_noise: float = 0.0
    latency: int = 0
    seed: int = 0

    def __post_init__(self):
        for name in ("position_noise", "angle_noise", "gyro_noise", "speed_noise"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"Sensor: {name} = {value!r} must be finite and >= 0")
        if int(self.latency) != self.latency or self.latency < 0:
            raise ValueError(f"Sensor: latency = {self.latency!r} must be a whole number of periods >= 0")
        self.rng = np.random.default_rng(self.seed)

    def measure(self, t: float, x: np.ndarray) -> Observation:
        """A noisy observation of state ``x`` (11,) at time ``t`` (s)."""
        rng = self.rng
        q = rotate_randomly(x[QUAT], self.angle_noise, rng)
        return Observation(
            t=t,
            position=x[POS] + rng.normal(0.0, self.position_noise, 2) if self.position_noise else x[POS].copy(),
            quaternion=q,
            omega=x[OMEGA] + rng.normal(0.0, self.gyro_noise, 3) if self.gyro_noise else x[OMEGA].copy(),
            theta=float(x[THETA]),
            theta_dot=float(x[THETA_DOT] + (rng.normal(0.0, self.speed_noise) if self.speed_noise else 0.0)),
        )


@dataclass(frozen=True)
class Kick:
    """A sudden disturbance of the robot at ``time`` (s): a push of the shell centre and a spin of the shell.

    Attributes
    ----------
    time : float
        When, s.
    position : tuple of float
        Displacement of the shell centre, m (floor frame).
    omega : tuple of float
        Change of the shell's angular velocity, rad/s (floor frame).
    """

    time: float
    position: tuple = (0.0, 0.0)
    omega: tuple = (0.0, 0.0, 0.0)

    def apply(self, x) -> np.ndarray:
        """The state (11,) after the kick."""
        x = np.array(x, float)
        x[POS] += self.position
        x[OMEGA] += self.omega
        return x


@dataclass(frozen=True)
class Event:
    """A moment where the no-slip rolling model stops describing the robot.

    Attributes
    ----------
    kind : {"jump", "slide"}
        Lost contact (normal force <= 0) or sliding (outside the friction cone).
    time : float
        Time of the first step with the violation, s.
    margin : float
        The violated margin there, N.
    """

    kind: str
    time: float
    margin: float


@dataclass
class SimulationResult:
    """A simulated run: states, commands, contact diagnostics and events (SI units).

    Attributes
    ----------
    params : RollbotParams
        The plant's parameters.
    dt : float
        Control period, s.
    t : numpy.ndarray (K+1,)
        Times of the states, s.
    x : numpy.ndarray (11, K+1)
        States (see ``dynamics``), one column per time.
    command : numpy.ndarray (K,)
        Motor acceleration asked for in each period, before the motor's limits, rad/s^2.
    speed_command : numpy.ndarray (K,)
        Driving-speed command of each period, rad/s (NaN where the command was an acceleration).
    diag : numpy.ndarray (7, K)
        Diagnostics at the start of each period, rows as ``DIAG_NAMES``.
    events : list of Event
        Loss of contact or sliding, in time order (at most the first when the run stopped on it).
    step_times : numpy.ndarray (K,)
        Wall-clock time the controller took in each period, s (zeros in open loop).
    info : dict
        Extra records from the controller (for example solver statistics).
    estimation : onboard.EstimationRecord or None
        With onboard sensing: the estimate at every control step, its
        uncertainty and the sensors' true biases.
    contact : floor_plant.ContactRecord or None
        On a floor that can slip (``floor_plant``): the contact's modes, slip
        and transitions; None on the no-slip plant's rigid floor.
    """

    params: RollbotParams
    dt: float
    t: np.ndarray
    x: np.ndarray
    command: np.ndarray
    speed_command: np.ndarray
    diag: np.ndarray
    events: list = field(default_factory=list)
    step_times: np.ndarray | None = None
    info: dict = field(default_factory=dict)
    estimation: object = None
    contact: object = None

    @property
    def position(self) -> np.ndarray:
        """Shell-centre positions (2, K+1), m."""
        return self.x[POS]

    @property
    def driving_speed(self) -> np.ndarray:
        """Driving speed theta_dot (K+1,), rad/s."""
        return self.x[THETA_DOT]

    @property
    def heading(self) -> np.ndarray:
        """Azimuth of the motor axis' horizontal projection (K+1,), rad (gamma)."""
        return heading(self.x)

    @property
    def tilt(self) -> np.ndarray:
        """Tilt of the motor axis from the floor normal (K+1,), rad (xi)."""
        return tilt(self.x)

    @property
    def applied_accel(self) -> np.ndarray:
        """Motor acceleration actually applied at the start of each period (K,), rad/s^2."""
        return self.diag[0]

    @property
    def motor_torque(self) -> np.ndarray:
        """Motor torque at the start of each period (K,), N m."""
        return self.diag[1]

    @property
    def reaction(self) -> np.ndarray:
        """Ground force on the shell (3, K), N."""
        return self.diag[2:5]

    @property
    def normal_force(self) -> np.ndarray:
        """No-jump margin: normal force (K,), N."""
        return self.diag[5]

    @property
    def slide_margin(self) -> np.ndarray:
        """No-slide margin ``mu N_z - |N_t|`` (K,), N."""
        return self.diag[6]

    @property
    def completed(self) -> bool:
        """True if the run reached its duration without a contact event."""
        return not self.events

    def energy(self) -> np.ndarray:
        """Total mechanical energy of every state (K+1,), J."""
        return RollbotModel(self.params).energy(self.x)

    def save(self, path: str | Path) -> Path:
        """Write the run to a compressed ``.npz`` file atomically."""
        return save_npz(
            path, t=self.t, x=self.x, command=self.command, speed_command=self.speed_command, diag=self.diag,
            step_times=self.step_times if self.step_times is not None else np.zeros_like(self.command),
            dt=self.dt, params=self.params.vector(), state_names=np.array(STATE_NAMES),
            diag_names=np.array(DIAG_NAMES), event_kinds=np.array([e.kind for e in self.events], dtype=str),
            event_times=np.array([e.time for e in self.events]),
            event_margins=np.array([e.margin for e in self.events]),
            params_file=np.array(json.dumps(self.params.to_file_dict())),
            **(self.estimation.to_arrays() if self.estimation is not None else {}),
        )

    @classmethod
    def load(cls, path: str | Path) -> "SimulationResult":
        """Read a run written by ``save``.

        Raises
        ------
        ConfigError
            If the file is missing or unreadable, is not a saved run (not an
            ``.npz``, truncated, keys missing), or its arrays do not fit together.
        """
        try:
            with open(path, "rb") as handle, np.load(handle, allow_pickle=False) as data:
                arrays = {key: data[key] for key in data.files}  # read everything now: a truncated file fails here
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
            raise ConfigError(f"{path}: cannot read a saved run ({exc})") from None
        return cls._from_arrays(arrays, str(path))

    @classmethod
    def _from_arrays(cls, data: dict, source: str) -> "SimulationResult":
        """A run from the arrays of a saved file, checked for the shapes ``save`` writes."""
        missing = {"t", "x", "command", "speed_command", "diag", "dt", "params_file"} - set(data)
        if missing:
            raise ConfigError(f"{source}: not a saved run (missing {', '.join(sorted(missing))})")
        try:
            table = json.loads(str(data["params_file"]))
        except ValueError as exc:
            raise ConfigError(f"{source}: not a saved run (parameters: {exc})") from None
        params = RollbotParams.from_file_dict(table, source=source)
        try:
            t, x = np.asarray(data["t"], float), np.asarray(data["x"], float)
            steps = t.size - 1
            columns = {"command": (steps,), "speed_command": (steps,), "diag": (NDIAG, steps)}
            arrays = {key: np.asarray(data[key], float) for key in columns}
            step_times = np.asarray(data.get("step_times", np.zeros(steps)), float)
            kinds, times = data.get("event_kinds", np.zeros(0, str)), data.get("event_times", np.zeros(0))
            margins = data.get("event_margins", np.zeros(len(times)))
            dt = float(data["dt"])
            events = [Event(str(k), float(e), float(m)) for k, e, m in zip(kinds, times, margins, strict=True)]
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"{source}: not a saved run ({exc})") from None
        shapes_ok = (t.ndim == 1 and steps >= 1 and x.shape == (NX, t.size) and step_times.shape == (steps,)
                     and all(arrays[key].shape == shape for key, shape in columns.items()))
        finite = math.isfinite(dt) and dt > 0 and np.all(np.isfinite(t)) and np.all(np.isfinite(x))
        if not (shapes_ok and finite):
            raise ConfigError(f"{source}: not a saved run (arrays of inconsistent shapes or non-finite values)")
        with np.errstate(over="ignore", invalid="ignore"):
            unit = np.abs(np.linalg.norm(x[QUAT], axis=0) - 1.0).max() <= 1e-3  # loose: RK4 drifts a little
        if not (unit and np.all(np.diff(t) > 0) and np.abs(x[POS]).max() <= 1e7):
            raise ConfigError(f"{source}: not a saved run (times not increasing, quaternions not of unit norm or "
                              "positions beyond 10^7 m)")
        estimation = EstimationRecord.from_arrays(data, source)
        return cls(params, dt, t, x, arrays["command"], arrays["speed_command"], arrays["diag"], events, step_times,
                   estimation=estimation)


def _schedule(value, times: np.ndarray, name: str) -> np.ndarray:
    """Commands at ``times`` from a constant, an array or a callable of time."""
    if callable(value):
        out = np.array([float(value(t)) for t in times])
    else:
        out = np.broadcast_to(np.asarray(value, float), times.shape).copy() if np.ndim(value) == 0 \
            else np.asarray(value, float)
    if out.shape != times.shape:
        raise ValueError(f"simulate: {name} has {out.size} values, expected {times.size} (one per period)")
    if not np.all(np.isfinite(out)):
        raise ValueError(f"simulate: {name} holds non-finite values")
    return out


def _check_state(x0) -> np.ndarray:
    x0 = np.asarray(x0, float).ravel()
    if x0.shape != (NX,):
        raise ValueError(f"simulate: x0 has {x0.size} entries, expected {NX} ({', '.join(STATE_NAMES)})")
    if not np.all(np.isfinite(x0)):
        raise ValueError("simulate: x0 holds non-finite values")
    length = norm(x0[QUAT])
    if not length > 1e-6:
        raise ValueError(f"simulate: x0 quaternion {x0[QUAT]} has norm {length:g}; it must be a unit quaternion")
    x0 = x0.copy()
    x0[QUAT] /= length
    return x0


def _first_events(t: np.ndarray, diag: np.ndarray) -> list[Event]:
    events = []
    for kind, row in (("jump", 5), ("slide", 6)):
        bad = np.flatnonzero(diag[row] < 0) if kind == "slide" else np.flatnonzero(diag[row] <= 0)
        if bad.size:
            events.append(Event(kind, float(t[bad[0]]), float(diag[row, bad[0]])))
    return sorted(events, key=lambda e: e.time)


def _run_times(duration: float, dt: float, controller, speed, accel) -> np.ndarray:
    """The sample times of a run (``duration`` s in periods of ``dt`` s), once its arguments are checked: a finite
    duration and period > 0, and at most one of ``controller``, ``speed`` and ``accel``."""
    if not (math.isfinite(duration) and duration > 0):
        raise ValueError(f"simulate: duration = {duration!r} must be a finite time > 0 s")
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"simulate: dt = {dt!r} must be a finite period > 0 s")
    given = [name for name, v in (("controller", controller), ("speed", speed), ("accel", accel)) if v is not None]
    if len(given) > 1:
        raise ValueError(f"simulate: give one of controller, speed and accel, not {' and '.join(given)}")
    return dt * np.arange(max(1, int(round(duration / dt))) + 1)


def simulate(x0, duration: float, *, params: RollbotParams | None = None, controller: Controller | None = None,
             speed=None, accel=None, dt: float = 0.01, substeps: int = 2, method: str = "rk4",
             sensor: Sensor | None = None, wrench=None, stop_on_event: bool = True,
             progress=None, kicks=()) -> SimulationResult:
    """Simulate Rollbot's full nonlinear dynamics, open loop or under a controller.

    Parameters
    ----------
    x0 : array_like (11,)
        Initial state (see ``dynamics``); the quaternion is normalised.
    duration : float
        Length of the run, s (rounded to whole control periods).
    params : RollbotParams, optional
        Plant parameters, including slope and motor limits; the prototype by default.
    controller : Controller, optional
        Called once per period with an ``Observation``; returns a ``Command``.
        The run ends early once the controller's ``done`` attribute (if it
        has one) turns True.
    speed : float, array_like or callable, optional
        Open-loop driving-speed command (rad/s): a constant, one value per
        period, or a function of time (s).
    accel : float, array_like or callable, optional
        Open-loop motor-acceleration command (rad/s^2), likewise.
    dt : float
        Control period, s.
    substeps : int
        RK4 steps per period (2 gives 5 ms steps at 100 Hz; see module doc).
    method : {"rk4", "cvodes"}
        Integrator.
    sensor : Sensor or OnboardSensing, optional
        What the controller sees: measurements with noise and latency
        (``Sensor``; perfect by default), or the estimate from onboard sensors
        (``onboard.OnboardSensing``, recorded in ``SimulationResult.estimation``).
    wrench : array_like (6,), optional
        Constant external force (N) and torque (N m) on the shell, floor frame.
    stop_on_event : bool
        End the run at the first loss of contact or slide (default).
    progress : callable, optional
        Closed loop: ``progress(t, info)`` is called every 0.5 s of simulated
        time with the time reached, s, and the controller's report so far
        (what becomes ``SimulationResult.info``), for progress displays.
    kicks : sequence of Kick
        Closed loop: sudden disturbances of the true state (a push, a spin),
        applied at the start of the period that holds their time.
    Returns
    -------
    SimulationResult
    """
    params = params or RollbotParams()
    x0 = _check_state(x0)
    times = _run_times(duration, dt, controller, speed, accel)
    steps = times.size - 1
    p = params.vector()
    w = np.zeros(NW) if wrench is None else np.asarray(wrench, float).reshape(NW)
    if controller is None:
        if speed is not None:
            cmd = _schedule(speed, times[:-1], "speed")
            states, diag = _speed_step(dt, substeps, method).mapaccum(steps)(x0, cmd.reshape(1, -1), p, w)
            speed_cmd = cmd
        else:
            cmd = _schedule(0.0 if accel is None else accel, times[:-1], "accel")
            states, diag = plant_step(dt, substeps, method).mapaccum(steps)(x0, cmd.reshape(1, -1), p, w)
            speed_cmd = np.full(steps, np.nan)
        x = np.hstack([x0[:, None], np.array(states)])
        diag = np.array(diag)
        command = cmd if speed is None else (speed_cmd - x[THETA_DOT, :-1]) / dt
        step_times = np.zeros(steps)
        info, estimation = {}, None
    else:
        sensor = sensor or Sensor()
        samples = sensor.samples if isinstance(sensor, OnboardSensing) else 0
        x, command, speed_cmd, diag, step_times, info = _closed_loop(
            x0, steps, dt, controller, plant_step(dt, substeps, method, samples), p, w, sensor, stop_on_event,
            progress, {int(round(kick.time / dt)): kick for kick in kicks})
        estimation = sensor.record() if samples else None
    events = _first_events(times, diag)
    end = diag.shape[1]
    if events and stop_on_event:
        end = int(round(events[0].time / dt)) + 1
        events = [e for e in events if e.time <= events[0].time]
    if estimation is not None:
        estimation = estimation.head(end)
    return SimulationResult(params, dt, times[:end + 1], x[:, :end + 1], command[:end], speed_cmd[:end],
                            diag[:, :end], events, step_times[:end], info, estimation)


def _closed_loop(x0, steps, dt, controller, step, p, w, sensor, stop_on_event, progress=None, kicks=None):
    x = np.empty((NX, steps + 1))
    x[:, 0] = x0
    diag = np.empty((NDIAG, steps))
    command = np.empty(steps)
    speed_cmd = np.full(steps, np.nan)
    step_times = np.empty(steps)
    step = FastFunction(step)
    controller.reset()
    onboard = isinstance(sensor, OnboardSensing)
    if onboard:
        sensor.start(x0)
    signals = None
    end = steps
    report_every = max(1, int(round(0.5 / dt)))  # progress: every 0.5 s of simulated time
    for k in range(steps):
        if kicks and k in kicks:
            x[:, k] = kicks[k].apply(x[:, k])
        obs = _observe(sensor, k, dt, x, signals, command[k - 1] if k else 0.0)
        start = time.perf_counter()
        cmd = controller(obs)
        step_times[k] = time.perf_counter() - start
        if cmd.speed is not None:
            speed_cmd[k] = cmd.speed
        command[k] = cmd.acceleration(x[THETA_DOT, k], dt)
        if onboard:
            x[:, k + 1], diag[:, k], signals = step(x[:, k], command[k], p, w)
        else:
            x[:, k + 1], diag[:, k] = step(x[:, k], command[k], p, w)
        if (stop_on_event and (diag[5, k] <= 0 or diag[6, k] < 0)) or controller.done:
            end = k + 1
            break
        if progress is not None and (k + 1) % report_every == 0:
            progress((k + 1) * dt, _controller_info(controller))
    return (x[:, :end + 1], command[:end], speed_cmd[:end], diag[:, :end], step_times[:end],
            _controller_info(controller))


def _observe(sensor, k: int, dt: float, x, signals, a_prev: float) -> Observation:
    """What the controller sees at control step ``k``: a (delayed, noisy) measurement or the onboard estimate."""
    if not isinstance(sensor, OnboardSensing):
        seen = max(0, k - sensor.latency)
        return sensor.measure(seen * dt, x[:, seen])
    est = sensor.observe(k, x[:, k], signals, a_prev)
    s = est.state
    return Observation(est.t, s[POS], s[QUAT], s[OMEGA], float(s[THETA]), float(s[THETA_DOT]), estimate=est)


def _controller_info(controller: Controller) -> dict:
    return controller.report()
