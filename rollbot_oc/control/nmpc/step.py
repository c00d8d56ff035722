"""The NMPC's control step: the work of one control period, given what the supervisor wants followed.

The step is the three Functions of ``control.nmpc.period`` over one memory vector: ``measure`` (the tilt and
model filter's update and the delay compensation), ``solve`` (one real-time iteration of the tracking problem on
the window the supervisor gives: ``Window``) and ``commit`` (the step's mode and the command).  ``TrackingStep``
holds the memory, calls them each period, and turns the supervisor's requests (``restart``, ``cold``,
``stop_motor``, ``hold_until``, ``finish``) into edits of the memory, as a robot's host would send them.  The
step's mode (``StepMode``) says what commands the motor:

* ``SOLVE``: the solution's acceleration for the current interval;
* ``SHIFTED``: a solve failed or was late (judged by the compute-time model, or the wall clock with
  ``timing.realtime``): the previous solution, for up to ``max_failures - 1`` solves;
* ``RAMP``: the motor's speed ramped to zero at ``brake_accel`` and held there until the fallback's time is
  over: the fallback of a course of stops (``recovery.fallback = "brake"``), or a supervisor stopping the
  motor (gates);
* ``PID``: the paper's PID on the current goal for ``pid_time`` (its speed computed here, on the host): the
  fallback of circles, gates and stops with ``recovery.fallback = "pid"``;
* ``OFF``: the mission is done.

With ``horizon.solver = "ipopt"`` the solve stage is IPOPT to convergence (``TrackingSolver``), evaluated in
Python with the same inputs and outputs; that route has no C.

A ``recorder`` (``TrackingStep.recorder``, None by default) is told, each period, what the step received and
gave: the memory before and after ``measure`` with its inputs, and the memory, the window solved on and the
inputs and outputs of ``commit`` (``export.replay.StepRecorder`` keeps them for the C replay of ``export-c``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from rollbot_oc.model.codegen import compiler
from rollbot_oc.control.nmpc.modes import ModeMachine, StepMode
from rollbot_oc.control.nmpc.period import EVENTS, MODE_CODES, step_functions
from rollbot_oc.control.nmpc.settings import NMPCSettings
from rollbot_oc.control.nmpc.source import NAMES, compiled_step, load_library
from rollbot_oc.control.nmpc.telemetry import Telemetry
from rollbot_oc.control.nmpc.tracking import TrackingSolver
from rollbot_oc.control.pid import QuasiStablePID
from rollbot_oc.model.dynamics import REDUCED
from rollbot_oc.core.fastcall import FastFunction
from rollbot_oc.model.params import PARAM_INDEX, TILT, RollbotParams
from rollbot_oc.control.protocol import Command, Observation

__all__ = ["Window", "TrackingStep", "Estimate"]

MODES = list(StepMode)
REASONS = {  # why the step's mode changed, by what ``commit`` did (``period.EVENTS``)
    "solved": {StepMode.SHIFTED: "a solve succeeded in time", StepMode.RAMP: "the fallback's time is over",
               StepMode.PID: "the fallback's time is over"},
    "shifted": "a solve failed or was late",
    "brake": "failed or late with nothing to follow (none, or max_failures in a row): brake",
    "pid": "failed or late with nothing to follow (none, or max_failures in a row): PID",
    "off": "the mission is done",
}


@dataclass
class Window:
    """What one solve follows: the supervisor's reference over the horizon and its weights.

    Attributes
    ----------
    Zr : numpy.ndarray (10, N+1)
        Reference reduced states at the nodes.
    Ur : numpy.ndarray (N,)
        Reference motor accelerations, rad/s^2.
    diag : numpy.ndarray or None
        Weights of every decision variable (``TrackingWeights.diagonal``); None: the mission's default.
    mission_weights : numpy.ndarray or None
        Weights of the mission's residuals at the nodes (a circle's distance from it); None: none.
    """

    Zr: np.ndarray
    Ur: np.ndarray
    diag: np.ndarray | None = None
    mission_weights: np.ndarray | None = None


class Estimate:
    """The filter's estimate, read from the step's memory: the floor's tilt and the learned scale factors."""

    def __init__(self, step: "TrackingStep"):
        self._step = step

    @property
    def tilt(self) -> np.ndarray:
        """The floor's tilt vector (in-plane gravity per g) (2,)."""
        return self._step.part("x_f")[:2].copy()

    def params(self) -> np.ndarray:
        """The model parameter vector with the estimated tilt and the learned factors."""
        f = self._step.functions
        x_f = self._step.part("x_f")
        p = self._step.params.vector()
        p[TILT] = x_f[:2]
        for i, name in enumerate(f.learn):
            p[PARAM_INDEX[name]] *= x_f[2 + i]
        return p

    def learned(self) -> dict:
        """The learned scale factors by parameter name."""
        x_f = self._step.part("x_f")
        return {name: float(x_f[2 + i]) for i, name in enumerate(self._step.functions.learn)}


class TrackingStep:
    """The control step of the NMPC (module doc).

    Parameters
    ----------
    params : RollbotParams
        The robot the controller believes in.
    settings : NMPCSettings
    weights : TrackingWeights
        The mission's default tracking weights.
    mission : Mission
        For the tracking problem's mission terms.
    dt : float
        Control period, s.
    telemetry : Telemetry
    library : str or Path, optional
        A folder written by ``export-c`` and built: the step runs its library (``source.LIBRARY``; the
        Python NMPC's own compiled C otherwise) and ``library_sha256`` says which.
    """

    def __init__(self, params: RollbotParams, settings: NMPCSettings, weights, mission, dt: float,
                 telemetry: Telemetry, library=None):
        s = self.settings = settings
        self.params, self.dt, self.mission = params, dt, mission
        self.every = max(1, int(round(s.horizon.h / dt)))
        if abs(self.every * dt - s.horizon.h) > 1e-9:
            raise ValueError(f"NMPC h = {s.horizon.h} s must be a whole number of control periods dt = {dt} s")
        self.functions = f = step_functions(params, s, weights, mission, dt)
        self.solver = f.solver if s.horizon.solver == "rti" else TrackingSolver(params, s, weights, mission=mission)
        self.memory = f.memory
        self.diag = weights.diagonal(s.horizon.N)
        self._values = np.concatenate([np.ravel(np.atleast_2d(v), order="F")
                                       for v in f.solver._mission_values.values()] or [np.zeros(0)])
        use_c = s.horizon.compiled if s.horizon.compiled is not None else compiler() is not None
        self.library_sha256 = None
        if library is not None:
            library, self.library_sha256 = load_library(library, f)
        else:
            library = compiled_step(f) if use_c else None  # the step's C, as export-c writes it
        funs = (f.measure, f.solve, f.commit) if library is None else (library[name] for name in NAMES)
        measure, solve, commit = (FastFunction(fun) for fun in funs)
        self._measure, self._commit = measure, commit
        self._solve = solve if s.horizon.solver == "rti" else None
        self.estimator = Estimate(self)
        self.telemetry = telemetry
        self.radius_map = None  # the PID fallback's (set by the NMPC with its plans)
        self._pid = None
        self.recorder = None  # told each period's inputs and outputs (module doc)
        self.reset(telemetry)

    def reset(self, telemetry: Telemetry) -> None:
        """Forget the run."""
        self.telemetry = telemetry
        self.modes = ModeMachine(StepMode.SOLVE)
        self.mem = self.functions.initial_memory.copy()
        self.prediction = None  # (Z (10, N+1), solve instant, s): the states the last solve predicts
        self._pid_fresh = True
        self._pid_goal = None

    def part(self, name: str) -> np.ndarray:
        """A part of the memory (a view)."""
        return self.mem[self.memory[name]]

    @property
    def current(self) -> bool:
        """Whether a solution is followed."""
        return bool(self.part("current")[0])

    # -- what the supervisor asks ------------------------------------------------------------------
    def restart(self) -> None:
        """A new reference: its first solve starts from it (the warm start solved the one replaced), and
        nothing of the previous solution is followed."""
        self.part("warm")[:] = 0.0
        self.part("current")[:] = 0.0

    def cold(self) -> None:
        """The next solve starts from its reference (a new plan takes over; what is followed stays)."""
        self.part("warm")[:] = 0.0

    def stop_motor(self, k: int, speed: float, until: float) -> None:
        """Ramp the motor's speed from ``speed`` (rad/s) to zero and hold it there until ``until`` (s)."""
        self.mem[self.memory["ramp_t0"]], self.mem[self.memory["ramp_speed"]] = k * self.dt, speed
        self.mem[self.memory["ramped"]], self.mem[self.memory["until"]] = 1.0, until
        self.restart()
        self._go(StepMode.RAMP, k, "the supervisor stops the motor")

    def hold_until(self, k: int, until: float) -> None:
        """Keep the motor held by the last fallback (its speed ramp, or the PID) until ``until``, s."""
        self.mem[self.memory["until"]] = until
        if self.modes.mode not in (StepMode.RAMP, StepMode.PID):
            target = StepMode.RAMP if self.part("ramped")[0] else StepMode.PID
            self._go(target, k, "the supervisor holds the motor until its plan starts")

    def _go(self, mode: StepMode, k: int, reason: str) -> None:
        self.modes.go(mode, k, reason)
        self.mem[self.memory["mode"]] = MODE_CODES[mode]

    def in_fallback(self, t_now: float) -> bool:
        """Whether a fallback (RAMP or PID) commands the motor at ``t_now``, s."""
        return t_now < self.part("until")[0]

    # -- every period ------------------------------------------------------------------------------
    def measure(self, obs: Observation, k: int):
        """The filter's update and the delay compensation: the reduced state (10,) at tick ``k``."""
        meas = np.concatenate([[obs.t], obs.state])
        z, mem = self._measure(self.mem, meas, k)
        if self.recorder is not None:
            self.recorder.measured(k, meas, self.mem, mem)
        self.mem = mem.copy()
        return z.copy()

    def act(self, k: int, obs: Observation, z, supervisor, keep=None) -> Command:
        """The command of tick ``k`` from the delay-compensated state ``z``: at a solve instant (or with
        nothing to follow, outside a fallback) one solve on the supervisor's window, then ``commit``;
        ``keep(k, window)``, if given, is told each window solved on (the run's log)."""
        t_now = k * self.dt
        done = supervisor.done
        solving = not done and self.modes.mode is not StepMode.OFF and not self.in_fallback(t_now) \
            and (k % self.every == 0 or not self.current)
        n, m = self.memory["w"], self.memory["lam_g"]
        self._packed = None  # the window solved on, packed (for the recorder)
        if solving:
            window = supervisor.window(z, k)
            if keep is not None:
                keep(k, window)
            mem_in = self.mem.copy() if self.recorder is not None else None  # the host's edits made
            w, lam_w, lam_g, ok, late = self._solve_window(window, z, k)
        else:
            mem_in = self.mem.copy() if self.recorder is not None else None
            w, lam_w, lam_g, ok, late = self.mem[n], self.mem[self.memory["lam_w"]], self.mem[m], 0.0, 0.0
        args = [self.mem, z, k, w, lam_w, lam_g, ok, late, float(solving), float(done),
                float(supervisor.fallback != "brake")]
        accel, speed, by_speed, mem, event = (a.copy() for a in self._commit(*args, np.nan))
        if by_speed[0] and MODES[int(mem[self.memory["mode"]][0])] is StepMode.PID:  # the PID's speed, here
            pid = self._pid_speed(obs, z, supervisor.goal, EVENTS[int(event[0])] == "pid")
            accel, speed, by_speed, mem, event = (a.copy() for a in self._commit(*args, pid))
        else:
            pid = np.nan
        if self.recorder is not None:
            self.recorder.committed(k, mem_in, self._packed, (late, float(solving), float(done),
                                                              float(supervisor.fallback != "brake"), pid),
                                    (accel[0], speed[0], by_speed[0], event[0]), mem)
        self.mem = mem
        event = EVENTS[int(event[0])]
        self._record(event, k)
        if event == "brake":
            supervisor.on_give_up(z, k)
        return Command(speed=float(speed[0])) if by_speed[0] else Command(accel=float(accel[0]))

    def _solve_window(self, window: Window, z, k: int):
        """One solve on ``window`` at tick ``k``: ``(w, lam_w, lam_g, ok, late)``, its telemetry kept."""
        s, log = self.settings, self.telemetry
        f = self.functions
        diag = self.diag if window.diag is None else window.diag
        mission = np.zeros(f.window.terms) if window.mission_weights is None else window.mission_weights
        start = time.perf_counter()
        if s.horizon.solver == "rti":
            packed = self._packed = f.window.pack(window.Zr, window.Ur, diag, mission, self._values)
            w, lam_w, lam_g, ok, retried = (a.copy() for a in self._solve(self.mem, z, packed))
            ok, retried = bool(ok[0]), bool(retried[0])
            modelled = (1 + retried) * s.timing.rti_step
        else:
            w, lam_w, lam_g, ok, retried, modelled = self._solve_ipopt(window, z, diag, mission)
        seconds = time.perf_counter() - start
        compute = seconds if s.timing.realtime else modelled
        late = compute > (s.horizon.h if s.timing.max_solve_time is None else s.timing.max_solve_time)
        log.cold_retries += retried
        status = "success" if ok else "failed"
        log.solve_times.append(seconds)
        log.statuses.append(f"cold after failed: {status}" if retried else status)
        log.tilt.append(self.estimator.tilt.tolist())
        if ok and not late:
            self.prediction = (self.solver.split(w)[0], k * self.dt)
        if ok:
            log.late += late
        else:
            log.failed += 1
        return w, lam_w, lam_g, float(ok), float(late)

    def _solve_ipopt(self, window: Window, z, diag, mission):
        """The solve stage by IPOPT to convergence (``horizon.solver = "ipopt"``): ``period``'s ``solve`` in
        Python, with the compute-time model of its iterations."""
        solver, p = self.solver, self.estimator.params()
        Zr = np.array(window.Zr, float)
        if float(np.dot(Zr[REDUCED.quaternion, 0], z[REDUCED.quaternion])) < 0:
            Zr[REDUCED.quaternion] *= -1.0
        warm = (self.part("w").copy(), self.part("lam_w").copy(), self.part("lam_g").copy()) \
            if self.part("warm")[0] else None
        x, lam, _status, ok, _seconds = solver.solve(z, Zr, window.Ur, p, warm, mission, diag)
        modelled, retried = solver.modelled_time(), False
        if not ok and warm is not None:
            retried = True
            x, lam, _status, ok, _seconds = solver.solve(z, Zr, window.Ur, p, None, mission, diag)
            modelled += solver.modelled_time()
        return x, lam[0], lam[1], ok, retried, modelled

    def _record(self, event: str, k: int) -> None:
        """The telemetry and the mode timeline of what ``commit`` did at tick ``k``."""
        log = self.telemetry
        if event in ("brake", "pid"):
            self.prediction = None  # no solution acts now: a refinement starts from the guess's own state
            setattr(log, f"fallback_{event}", getattr(log, f"fallback_{event}") + 1)
        elif event == "shifted":
            log.fallback_shifted += 1  # keep following the previous solution (its index moves on)
        mode = MODES[int(self.part("mode")[0])]
        if mode is not self.modes.mode or event in ("shifted", "brake", "pid"):  # each fallback taken is a change
            reason = REASONS[event][self.modes.mode] if event == "solved" else REASONS[event]
            self.modes.go(mode, k, reason)

    def _pid_speed(self, obs: Observation, z, goal: int, fresh: bool) -> float:
        """The paper's PID on the mission's target ``goal``, taking over smoothly from the current driving speed
        (``fresh``: the fallback starts now)."""
        self._pid_fresh |= fresh
        if self._pid is None or self._pid_goal != goal:
            self._pid, self._pid_goal, self._pid_fresh = QuasiStablePID(
                self.mission.leg(goal), self.params, dt=self.dt, radius_map=self.radius_map), goal, True
        if self._pid_fresh:
            self._pid.reset()
            self._pid.omega_cmd = max(float(z[REDUCED.theta_dot]), 0.0)
            self._pid_fresh = False
        return self._pid(obs).speed
