"""The plant on a floor the shell can slide on: stick and slide with their transitions located in time.

``simulate(..., floor=Floor(...))`` comes here for any floor that is not
the rigid no-slip one (``Floor.rigid``); the no-slip plant stays
``simulate``'s own path, untouched.

Integration.  A control period ``dt`` holds the motor command (as in the
no-slip plant: speed commands through the motor's speed loop, the speed,
acceleration and torque limits) and is integrated by ``substeps`` RK4 steps
(at least ``MIN_SUBSTEPS``: the regularised rolling resistance is stiff
below ``contact.ROLL_EPS``) of the mode in force, ``contact.STICK`` or
``contact.SLIDE``.  At the end of each RK4 step the mode's event function
is checked (``ContactModel.step``):

* stick -> slide where the no-slide margin ``mu N_z - |N_t|`` turns
  negative; sliding starts opposite to the friction force the contact
  needed there;
* slide -> stick where the slip velocity's component along the step's
  starting slip direction reaches zero, in the step (friction held along
  that direction, ``ContactModel.step``'s ``hold``) whose RK4 stages reach
  the slip's end.  The slip velocity is then set to exactly zero: on a
  straight slip the change is of the root finder's tolerance; a slip that
  turns as it ends leaves a residual across the direction, stopped by a
  friction impulse whose energy is recorded (``ContactRecord.stick_losses``).
  If sticking would need more friction than the cone holds, the contact
  slides on at once, in the direction its slip accelerates.

The event time inside the step is found by regula falsi (Illinois) on the
RK4 step's length to ``EVENT_TOL`` s, and the step is completed from there in
the new mode.  Transitions are recorded (``ContactRecord``), never failures;
a loss of contact (normal force <= 0 at a period's start) is an event that
ends the run, as in the no-slip plant.

The floor under the contact point (``Floor.values_at``: patches by
point-in-polygon) is looked up at the start of each period and held over it.

Onboard sensing (IMU) is not simulated on these floors yet: its sensor
model assumes rolling.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from rollbot_oc.model.contact import NXC, SLIDE, SLIP_TINY, STICK, VEL, contact_model
from rollbot_oc.model.dynamics import NW, NX, OMEGA, POS, THETA_DOT
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.core.fastcall import FastFunction
from rollbot_oc.simulation.floor import Floor
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.simulation import plant
from rollbot_oc.simulation.onboard import OnboardSensing
from rollbot_oc.simulation.plant import (Event, Sensor, SimulationResult, _check_state, _controller_info, _observe,
                                         _run_times, _schedule)

__all__ = ["ContactRecord", "simulate", "simulate_on_floor", "MIN_SUBSTEPS", "EVENT_TOL"]

MIN_SUBSTEPS = 8
EVENT_TOL = 1e-12  # s: the located transition time's bracket
_MAX_SWITCHES = 8  # mode changes within one RK4 step before the contact is left as it is


@dataclass
class ContactRecord:
    """What the contact did during a run on a floor that can slip.

    Attributes
    ----------
    floor : Floor
    mode : numpy.ndarray (K+1,) of int
        Contact mode at each state (``contact.STICK`` 0, ``contact.SLIDE`` 1).
    centre_velocity : numpy.ndarray (2, K+1)
        Shell centre's velocity along the floor, m/s.
    slip : numpy.ndarray (2, K+1)
        Slip velocity of the contact point, m/s.
    floor_values : numpy.ndarray (3, K)
        Friction coefficient, rolling resistance (m) and damping (N m s) under
        the contact point in each period.
    transitions : list of (float, str)
        Time (s) and new mode (``"slide"``, ``"stick"``) of each transition.
    stick_losses : list of (float, float)
        Time (s) of each return to sticking and the kinetic energy (J) taken by
        stopping the slip left there (across the slip's direction; see
        ``floor_plant``).
    time_sliding : float
        Total time spent sliding, s (transition times located inside the steps).
    max_slip_speed : float
        Largest slip speed at the end of any RK4 step, m/s.
    """

    floor: Floor
    mode: np.ndarray
    centre_velocity: np.ndarray
    slip: np.ndarray
    floor_values: np.ndarray
    transitions: list = field(default_factory=list)
    stick_losses: list = field(default_factory=list)
    time_sliding: float = 0.0
    max_slip_speed: float = 0.0

    def metrics(self) -> dict:
        """The run JSON's slip keys: ``max_slip_speed`` (m/s), ``time_sliding`` (s), ``slide_starts``."""
        return {"max_slip_speed": float(self.max_slip_speed), "time_sliding": float(self.time_sliding),
                "slide_starts": sum(1 for _, kind in self.transitions if kind == "slide")}


def _rolling_velocity(X, R: float) -> np.ndarray:
    """The centre velocity (2,) that rolling without slip gives: ``omega x R z``."""
    w = X[OMEGA]
    return np.array([w[1] * R, -w[0] * R])


class _Plant:
    """One run's plant: the mode, the transitions, and a period at a time."""

    def __init__(self, params: RollbotParams, floor: Floor, dt: float, substeps: int, w: np.ndarray):
        model = contact_model()
        self.step = [FastFunction(f) for f in model.step]
        self.diag = [FastFunction(f) for f in model.diag]
        self.rhs_slide = FastFunction(model.rhs[SLIDE])
        self.energy = FastFunction(model.energy)
        self.stick_losses = []
        self.params, self.floor, self.dt, self.w = params, floor, dt, w
        self.p = params.vector()
        self.h = dt / max(substeps, MIN_SUBSTEPS)
        self.n = int(round(dt / self.h))
        self.mode = STICK
        self.direction = np.array([1.0, 0.0])
        self.t = 0.0
        self.transitions = []
        self.time_sliding = 0.0
        self.max_slip = 0.0

    def slip(self, X) -> np.ndarray:
        return X[VEL] - _rolling_velocity(X, self.params.R)

    def start(self, X, a, fl) -> np.ndarray:
        """Diagnostics (7,) at a period's start, first switching to slide if sticking needs too much friction."""
        u, tau, N, margins, _ = (np.array(v) for v in self.diag[self.mode](X, a, self.p, self.w, fl,
                                                                           self.direction))
        if self.mode == STICK and margins[1] < 0 and margins[0] > 0:
            self._to_slide(X, a, fl, N, self.t)
            u, tau, N, margins, _ = (np.array(v) for v in self.diag[SLIDE](X, a, self.p, self.w, fl,
                                                                           self.direction))
        return np.concatenate([u, tau, N, margins])

    def _to_slide(self, X, a, fl, N, t):
        """Start sliding: the slip grows along ``d``, the direction in which friction along ``-d`` accelerates it.

        From the direction opposite to the friction force sticking needed, a fixed-point iteration
        ``d <- slip acceleration / |slip acceleration|`` (the contact's effective mass need not be isotropic).
        """
        tangential = np.asarray(N[:2], float)
        size = math.hypot(*tangential)
        d = -tangential / size if size > 0 else self.direction
        R = self.params.R
        for _ in range(8):
            Xdot = np.array(self.rhs_slide(X, a, self.p, self.w, fl, d)[0])
            slip_accel = Xdot[VEL] - np.array([Xdot[OMEGA.start + 1] * R, -Xdot[OMEGA.start] * R])
            size = math.hypot(*slip_accel)
            if size == 0:
                break
            new = slip_accel / size
            if np.abs(new - d).max() < 1e-12:
                d = new
                break
            d = new
        self.direction = d
        self.mode = SLIDE
        self.transitions.append((t, "slide"))

    def _to_stick(self, X, a, fl, t) -> np.ndarray:
        """Stick: the slip left where its component along the step's direction vanished is stopped at once.

        That residual (across the direction, from the slip's turning within the step) is stopped by a
        friction impulse at the contact; the kinetic energy it takes is recorded in ``stick_losses``.
        """
        before = float(self.energy(X, self.p)[0][0])
        X = X.copy()
        X[VEL] = _rolling_velocity(X, self.params.R)
        self.stick_losses.append((t, before - float(self.energy(X, self.p)[0][0])))
        self.mode = STICK
        self.transitions.append((t, "stick"))
        _, _, N, margins, _ = self.diag[STICK](X, a, self.p, self.w, fl, self.direction)
        if margins[1] < 0 and margins[0] > 0:  # sticking needs more than the cone holds: slide on
            self._to_slide(X, a, fl, np.array(N), t)
        return X

    def _event(self, X, a, fl, tau, hold=0.0):
        X_end, events = self.step[self.mode](X, a, self.p, self.w, fl, self.direction, tau, hold)
        return np.array(X_end), float(events[1])

    def _locate(self, X, a, fl, h, g_end, hold):
        """The time ``tau`` in (0, h] where the mode's event function crosses zero (Illinois), and the state there."""
        lo, g_lo, hi, g_hi = 0.0, self._event(X, a, fl, 0.0, hold)[1], h, g_end
        if g_lo <= 0:  # already at the transition
            return 0.0, X.copy()
        side = 0
        X_hi = None
        for _ in range(200):
            tau = (lo * g_hi - hi * g_lo) / (g_hi - g_lo)
            if not lo < tau < hi:
                tau = 0.5 * (lo + hi)
            X_tau, g = self._event(X, a, fl, tau, hold)
            if g > 0:
                lo, g_lo = tau, g
                if side == 1:
                    g_hi /= 2
                side = 1
            else:
                hi, g_hi, X_hi = tau, g, X_tau
                if side == -1:
                    g_lo /= 2
                side = -1
            if hi - lo <= EVENT_TOL or g == 0:
                break
        if X_hi is None:
            X_hi = self._event(X, a, fl, hi, hold)[0]
        return hi, X_hi

    def period(self, X, a, fl) -> np.ndarray:
        """The state after one control period from ``X`` (13,) with motor acceleration ``a`` held."""
        X = np.array(X, float)
        for _ in range(self.n):
            left, switches = self.h, 0
            while left > 0:
                length, hold = left, 0.0
                if self.mode == SLIDE:
                    slip = self.slip(X)
                    speed = math.hypot(*slip)
                    if speed > SLIP_TINY:
                        self.direction = slip / speed
                X_end, events = self.step[self.mode](X, a, self.p, self.w, fl, self.direction, length, hold)
                X_end, g = np.array(X_end), float(events[1])
                if self.mode == SLIDE and min(g, float(events[2])) <= 0:
                    # the slip ends in this step: friction held along the start's direction, the end located
                    hold = 1.0
                    X_end, events = self.step[SLIDE](X, a, self.p, self.w, fl, self.direction, length, hold)
                    X_end, g = np.array(X_end), float(events[1])
                crossed = g < 0 if self.mode == STICK else g <= 0
                if not crossed or switches >= _MAX_SWITCHES:
                    self._advance(length)
                    X = X_end
                    left -= length
                    continue
                tau, X = self._locate(X, a, fl, length, g, hold)
                self._advance(tau)
                left -= tau
                switches += 1
                if self.mode == STICK:
                    _, _, N, _, _ = self.diag[STICK](X, a, self.p, self.w, fl, self.direction)
                    self._to_slide(X, a, fl, np.array(N), self.t)
                else:
                    X = self._to_stick(X, a, fl, self.t)
                self.max_slip = max(self.max_slip, float(np.hypot(*self.slip(X))))
            self.max_slip = max(self.max_slip, float(np.hypot(*self.slip(X))))
        q = X[2:6]
        X[2:6] = q / np.linalg.norm(q)
        return X

    def _advance(self, tau):
        if self.mode == SLIDE:
            self.time_sliding += tau
        self.t += tau


def _check_floor_state(x0, R: float) -> np.ndarray:
    """The contact plant's start (13,): a state (11,) rolling without slip, or (13,) with its centre velocity."""

    x0 = np.asarray(x0, float).ravel()
    if x0.shape == (NXC,):
        if not np.all(np.isfinite(x0[VEL])):
            raise ValueError("simulate: x0's centre velocity holds non-finite values")
        return np.concatenate([_check_state(x0[:NX]), x0[VEL]])
    x = _check_state(x0)
    return np.concatenate([x, _rolling_velocity(x, R)])


def simulate_on_floor(x0, duration: float, *, params: RollbotParams, floor: Floor, controller=None, speed=None,
                      accel=None, dt: float = 0.01, substeps: int = MIN_SUBSTEPS, method: str = "rk4", sensor=None,
                      wrench=None, stop_on_event: bool = True, progress=None, kicks=()):
    """``simulate`` on a floor with Coulomb contact (see the module doc and ``simulate.simulate``).

    ``x0`` may hold 13 entries: the state (11) and the shell centre's
    velocity along the floor (m/s), for a start that slides; 11 entries
    start rolling without slip.  The result's ``contact`` is a
    ``ContactRecord``; its ``events`` hold only losses of contact ("jump").
    """

    if method != "rk4":
        raise ValueError(f"simulate: method = {method!r} on a floor that can slip; valid is 'rk4' "
                         "(the stick/slip transitions are located inside its steps)")
    if isinstance(sensor, OnboardSensing):
        raise ConfigError("onboard sensing (IMU) is not simulated on a floor that can slip yet: its sensor model "
                          "assumes rolling; use sensor mode 'mocap'")
    X0 = _check_floor_state(x0, params.R)
    times = _run_times(duration, dt, controller, speed, accel)
    steps = times.size - 1
    w = np.zeros(NW) if wrench is None else np.asarray(wrench, float).reshape(NW)
    plant = _Plant(params, floor, dt, substeps, w)
    if np.hypot(*plant.slip(X0)) > SLIP_TINY:  # a start that slides
        plant.mode = SLIDE
    X = np.empty((NXC, steps + 1))
    X[:, 0] = X0
    modes = np.zeros(steps + 1, dtype=np.int8)
    diag = np.empty((7, steps))
    floor_values = np.empty((3, steps))
    command = np.empty(steps)
    speed_cmd = np.full(steps, np.nan)
    step_times = np.zeros(steps)
    kicks = {int(round(kick.time / dt)): kick for kick in kicks}
    closed = controller is not None
    if closed:
        sensor = sensor or Sensor()
        controller.reset()
    elif speed is not None:
        speed_cmd = _schedule(speed, times[:-1], "speed")
    else:
        command = _schedule(0.0 if accel is None else accel, times[:-1], "accel")
    report_every = max(1, int(round(0.5 / dt)))
    end, events = steps, []
    vmax = params.max_speed
    for k in range(steps):
        if closed and k in kicks:
            kicked = kicks[k].apply(X[:NX, k])
            X[VEL, k] += _rolling_velocity(kicked, params.R) - _rolling_velocity(X[:NX, k], params.R)
            X[:NX, k] = kicked
        if closed:
            obs = _observe(sensor, k, dt, X[:NX], None, command[k - 1] if k else 0.0)
            start = time.perf_counter()
            cmd = controller(obs)
            step_times[k] = time.perf_counter() - start
            if cmd.speed is not None:
                speed_cmd[k] = cmd.speed
            command[k] = cmd.acceleration(X[THETA_DOT, k], dt)
        elif speed is not None:
            command[k] = (speed_cmd[k] - X[THETA_DOT, k]) / dt
        theta_dot = X[THETA_DOT, k]
        a = min(max(command[k], (-vmax - theta_dot) / dt), (vmax - theta_dot) / dt)
        plant.t = times[k]
        fl = floor.values_at(X[POS, k], params.mu)
        floor_values[:, k] = fl
        diag[:, k] = plant.start(X[:, k], a, fl)
        modes[k] = plant.mode
        if diag[5, k] <= 0:
            events.append(Event("jump", float(times[k]), float(diag[5, k])))
            if stop_on_event:
                end = k + 1
                X[:, k + 1] = X[:, k]
                break
        X[:, k + 1] = plant.period(X[:, k], a, fl)
        modes[k + 1] = plant.mode
        if closed and controller.done:
            end = k + 1
            break
        if closed and progress is not None and (k + 1) % report_every == 0:
            progress((k + 1) * dt, _controller_info(controller))
    R = params.R
    rolling = np.array([X[OMEGA.start + 1, :end + 1] * R, -X[OMEGA.start, :end + 1] * R])
    record = ContactRecord(floor, modes[:end + 1], X[VEL, :end + 1].copy(), X[VEL, :end + 1] - rolling,
                           floor_values[:, :end], plant.transitions, plant.stick_losses, plant.time_sliding,
                           plant.max_slip)
    if not closed and speed is None:
        speed_cmd = np.full(steps, np.nan)
    info = _controller_info(controller) if closed else {}
    return SimulationResult(params, dt, times[:end + 1], X[:NX, :end + 1].copy(), command[:end], speed_cmd[:end],
                            diag[:, :end], events[:1] if stop_on_event else events, step_times[:end], info,
                            None, contact=record)


def simulate(x0, duration: float, *, floor: Floor | None = None, params: RollbotParams | None = None, **options):
    """``simulation.plant.simulate`` on ``floor``: the rigid floor of the no-slip model (None or ``Floor()``) by
    the plant's own path, any other with Coulomb contact (``simulate_on_floor``); ``options`` as the plant's."""
    if floor is None or floor.rigid:
        return plant.simulate(x0, duration, params=params, **options)
    return simulate_on_floor(x0, duration, params=params or RollbotParams(), floor=floor, **options)
