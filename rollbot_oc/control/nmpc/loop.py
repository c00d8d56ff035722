"""The NMPC controller: plans legs as the robot moves, tracks them, recovers, and falls back (see the package doc)."""

from __future__ import annotations

import functools
import math
import time
from dataclasses import replace

import numpy as np

from rollbot_oc.control.nmpc.estimation import TiltEstimator
from rollbot_oc.control.nmpc.gates import plan_gates
from rollbot_oc.control.nmpc.reference import Reference
from rollbot_oc.control.nmpc.settings import NMPCSettings
from rollbot_oc.control.nmpc.tracking import RTISolver, TrackingSolver
from rollbot_oc.control.ocp import (OCPSettings, OrbitEntry, Plan, RestToRest, SolveFailed, orbit_guess, orbit_phase,
                                    quasi_stable_guess, quasi_stable_guesses)
from rollbot_oc.dynamics import REDUCED, rest_attitude, to_reduced
from rollbot_oc.missions import PassMonitor, StopMonitor
from rollbot_oc.params import RollbotParams
from rollbot_oc.reproducible import dot, norm
from rollbot_oc.simulate import Command, ControllerBase, Observation

__all__ = ["NMPC", "GATE_REPLANS"]

GATE_REPLANS = 3  # plans through the gates left after the first, when the robot missed one


class NMPC(ControllerBase):
    """Tracking NMPC with minimum-time plans (see module doc); a ``Controller`` for ``simulate``.

    Parameters
    ----------
    mission : Mission
        Stops (``mission.stops``), an orbit (``mission.orbit``) or gates (``mission.gates``).
    params : RollbotParams, optional
        The robot the controller believes in (level floor by default: the slope is estimated).
    dt : float
        Control period of the loop, s (the plant's 100 Hz).
    settings : NMPCSettings, optional
    """

    def __init__(self, mission, params: RollbotParams | None = None, dt: float = 0.01,
                 settings: NMPCSettings | None = None):
        if mission.orbit is None and not mission.stops and not mission.gates:
            raise ValueError(f"mission {mission.kind!r}: the NMPC needs stops, an orbit or gates")
        if not mission.gates and any(not w.stop for w in mission.waypoints):
            raise ValueError("the NMPC plans stops; pass-through waypoints are for the PID's waypoint layer")
        self.mission = mission
        self._rule = mission.stop_rule
        self.params = params or RollbotParams()
        self.dt = dt
        self.settings = s = settings or NMPCSettings()
        self.every = max(1, int(round(s.h / dt)))
        if abs(self.every * dt - s.h) > 1e-9:
            raise ValueError(f"NMPC h = {s.h} s must be a whole number of control periods dt = {dt} s")
        self.weights = s.circle_weights if mission.orbit is not None else s.waypoint_weights
        solver = TrackingSolver if s.solver == "ipopt" else RTISolver
        self.solver = solver(self.params, s, self.weights, mission=mission)
        self._hold_diag = s.hold_weights.diagonal(s.N)
        self._track_diag = self.weights.diagonal(s.N)
        self._brake_diag = s.brake_weights.diagonal(s.N)
        self.estimator = TiltEstimator(self.params, dt, s.tilt_process_noise, s.gyro_sigma,
                                       s.tilt_model_error, s.learn if s.estimate_tilt else (), s.learn_sigma,
                                       s.attitude_gain)
        # the legs' planner, built once (its floor tilt is set per plan from the estimate)
        level = self.params.replace(slope=0.0)
        self._legs = _rest_to_rest(level, s.plan, tuple(s.constraints)) if mission.stops else None
        if self._legs is not None:  # built now, not during the run
            self._legs.build()
        if mission.orbit is not None:  # the entry's route for its first duration (the others if ever needed)
            self._entry(s.entry_times[0]).build(s.entry_times[0])
        self.map = None  # set with the plans (for centre-of-curvature plots)
        self.reference = None
        self.plan_time = 0.0
        self._pid = None
        self.reset()

    # -- planning ---------------------------------------------------------------------------------
    def prepare(self, x0) -> Reference:
        """What to follow first, from the full state ``x0`` (11,); called by ``run_problem`` before the run.

        Stops: the quasi-stable guess of the first leg (a fraction of a second),
        refined while the robot moves (see ``plan_handovers``); the legs after
        it are planned ahead (``legs_ahead``), one after the other.  Circles: a ramp up to the orbit's speed (a simulation
        of the model), and the entry onto the orbit planned from where the
        ramp will be ``entry_handover`` s later (``_advance_entry``).  Gates:
        the minimum-time plan through them (``nmpc.gates``), followed once its
        modelled compute time has passed.  ``plan_time`` is the computation
        before the first command, s (the problems' routes are built with the
        controller, before).
        """
        start = time.perf_counter()
        level = self.params.replace(slope=0.0)
        from rollbot_oc.quasi_stable import RadiusMap

        self.map = RadiusMap(level)
        if self.mission.stops:
            self.reference = Reference([None] * len(self.mission.stops))
            self._follow_guess(to_reduced(x0), 0.0)  # refined while the robot moves (``_refine``)
            self.plan_time = time.perf_counter() - start  # the first command can be given now
            return self.reference
        if self.mission.gates:  # one minimum-time plan through every gate (``nmpc.gates``)
            self._follow_gates(to_reduced(x0), 0.0)
            self.plan_time = time.perf_counter() - start
            return self.reference
        # a circle: up to the orbit's speed at once (a simulation of the model), then tracked onto the orbit;
        # the entry, planned from where that ramp will be, takes over as the robot moves (``_advance_entry``)
        s, orbit = self.settings, self.mission.orbit
        entry = self._entry(s.entry_times[0])
        guess, phase = orbit_guess(to_reduced(x0), orbit.centre, entry, hold=s.tilt_settle + 4 * s.entry_handover)
        self.reference = Reference([(guess, {})], self._orbit(entry, phase))
        self._entry_shift = float(norm(_revolving_centre(guess, entry.quasi.Omega) - orbit.centre))
        self.segment_start, self._refine_at = 0.0, s.tilt_settle
        self.plan_time = time.perf_counter() - start
        return self.reference

    # -- circles: onto the orbit ------------------------------------------------------------------
    def _entry(self, duration: float) -> OrbitEntry:
        """The entry problem onto the mission's orbit in ``duration`` s (least effort; ``entry_interval`` grid)."""
        s = self.settings
        intervals = max(2, int(round(duration / s.entry_interval)))
        return _orbit_entry(self.mission.orbit.radius, self.params.replace(slope=0.0), replace(s.entry, N=intervals),
                            tuple(s.constraints))

    def _entry_times(self) -> list:
        """The entry durations to try, s: those of ``entry_times`` from the shortest long enough to move the
        robot's revolving centre from the ramp's to the orbit's at ``entry_shift_speed`` (the longest if none
        is).  A shorter entry from a ramp far from the orbit seldom converges, and its failed iterations
        delay the one that would have."""
        s = self.settings
        need = self._entry_shift / s.entry_shift_speed
        return [d for d in s.entry_times if d >= need - 1e-9] or [max(s.entry_times)]

    def _orbit(self, entry: OrbitEntry, phase: float) -> dict:
        """The orbit a reference ends on, reached at ``phase`` (rad)."""
        return {"qs": entry.qs_reduced, "centre": self.mission.orbit.centre, "phase": phase, "Omega": entry.quasi.Omega}

    def _advance_entry(self, t_now: float):
        """Plan the entry from the ramp ``tilt_settle`` s after the start, and follow it once it is ready and its
        start has come (a late one is planned again from further along the ramp, while the ramp lasts)."""
        if self._refine_at is not None and t_now >= self._refine_at - 1e-9:
            self._refine_at = None
            self._launch_entry(t_now)
        pending = self._pending.get(0)
        if pending is None or t_now < max(pending["ready"], pending["start"]) - 1e-9:
            return
        del self._pending[0]
        if pending["plan"] is None:  # no entry: the NMPC tracks the orbit from the end of the ramp
            return
        if pending["ready"] > pending["start"] + 1e-9:  # planned again from here, starting from this plan
            self.log["plan_late"] += 1
            self._launch_entry(t_now, pending["plan"])
            return
        plan = pending["plan"]
        self.reference = Reference([(plan, {})], self._orbit(self._entry(plan.T), plan.extra["phase"]))
        self.segment_start = pending["start"]
        self.warm = None  # a new reference: its first step starts from it (see ``_take_pending``)

    def _launch_entry(self, t_now: float, late: Plan | None = None):
        """Plan the entry onto the orbit from where the ramp followed now will be ``entry_handover`` s later, for
        each of the durations of ``_entry_times`` in turn until one converges (first, from a ``late`` entry's
        own duration and solution); it may be used once its modelled compute time has passed.  Nothing is
        planned if the ramp ends before then."""
        s, centre = self.settings, self.mission.orbit.centre
        ramp = self.reference.segments[0][0]
        handover = t_now - self.segment_start + s.entry_handover
        if handover >= ramp.T:
            return
        wall, z_start = time.perf_counter(), ramp.state(handover)

        def attempt(duration, guess):
            entry = self._entry(duration)
            if guess is None:
                guess = ramp.tail(handover, entry.settings.N, duration)
                guess.extra = {"phase": orbit_phase(guess.z[REDUCED.position, -1], centre, entry.qs_reduced)}
            return entry.solve(z_start, centre, guess=guess, duration=duration)

        tries = ([(late.T, late)] if late is not None else []) + [(duration, None) for duration in self._entry_times()]
        plan, iterations, _ = self._first_converged([functools.partial(attempt, *args) for args in tries])
        ready = self._schedule(t_now, time.perf_counter() - wall, iterations * s.plan_iteration_time)
        self._pending[0] = {"plan": plan, "start": self.segment_start + handover, "ready": ready}

    # -- gates: one plan through those left, then brought to rest ----------------------------------
    def _follow_gates(self, z, t_now: float) -> float:
        """Plan from ``z`` through the gates not yet passed (on the estimated floor) and follow the plan
        from the solve instant its modelled compute time has passed; returns that instant, s."""
        s, gates = self.settings, self.mission.gates[self._gates_passed:]
        plan = plan_gates(z, gates, self.params.replace(slope=0.0), s.gates, tilt=self.estimator.tilt.copy(),
                          constraints=tuple(s.constraints))
        self._gate_plans.append(plan.to_dict())
        self.log["plan_solve_times"].append(plan.solve_time)
        compute = plan.solve_time if s.realtime else plan.iterations * s.plan_iteration_time
        start = t_now + s.h * math.ceil(compute / s.h - 1e-9)
        self.reference = Reference([(plan, {"gates": gates})])
        self.segment, self.segment_start = 0, start
        self.warm, self.current = None, None
        return start

    def _gate_diag(self, local: float) -> np.ndarray:
        """Tracking weights with ``gate_weight`` added on the position at the two horizon nodes around
        each planned gate passage (``local``: time on the plan, s)."""
        s = self.settings
        diag = self._track_diag.copy()
        for t_gate in self.reference.segments[0][0].extra["gate_times"]:
            j = int(math.floor((t_gate - local) / s.h))
            for node in (j, j + 1):
                if 0 <= node <= s.N:
                    diag[node * 10:node * 10 + 2] += s.gate_weight
        return diag

    def _watch_gates(self, obs: Observation):
        """Feed the next gate's ``PassMonitor`` with the measured position; count it once passed."""
        gates = self.mission.gates
        if self._gates_passed >= len(gates):
            return
        if self._gate is None:
            self._gate = PassMonitor(gates[self._gates_passed], self.mission.pass_tolerance)
        if self._gate.update(obs.position):
            self._gates_passed += 1
            self._gate = None

    def _advance_gates(self, t_now: float, z):
        """After the last gate, or a plan's end (``hold_time`` past it) with a gate missed, stop the motor:
        its speed ramped to zero at ``brake_accel`` and held there (``_stop_motor``).  With every gate
        passed, done once the robot is at rest (or ``brake_wait`` s later); with gates left, from rest
        (or ``brake_wait`` s later) a new plan through them, followed once its modelled compute time has
        passed (at most ``GATE_REPLANS`` of them)."""
        s = self.settings
        left = self._gates_passed < len(self.mission.gates)
        if self._braking_since is None:
            if not left or t_now - self.segment_start >= self.reference.segments[0][0].T + s.hold_time - 1e-9:
                self._stop_motor(t_now, z)
            return
        at_rest = (self.params.R * float(norm(z[REDUCED.omega])) < s.recover_speed
                   and abs(float(z[REDUCED.theta_dot])) < s.recover_drive)
        settled = at_rest or t_now - self._braking_since >= s.brake_wait - 1e-9
        if not left or self.log["replans"] >= GATE_REPLANS:
            self._done = settled
        elif settled:
            self.log["replans"] += 1
            try:
                self.pid_until = self._follow_gates(z, t_now)  # the motor held still until the plan is ready
                self._braking_since = None
            except SolveFailed as exc:  # reported; the robot stays at rest, and tries again
                self.log["statuses"].append(f"plan failed: {exc.status}")
                self.log["plan_failures"] += 1
                self._braking_since = t_now

    def _stop_motor(self, t_now: float, z):
        """Ramp the motor's speed to zero (``brake_accel``) and hold it there: a robot passing gates
        comes to rest this way (the braking weights, from the speed a minimum-time plan ends at, chatter
        between the motor's limits)."""
        s = self.settings
        self._ramp, self.pid_until = (t_now, float(z[REDUCED.theta_dot])), t_now + s.brake_wait + s.h
        self._braking_since, self._rest_plan = t_now, None
        self.warm, self.current = None, None

    # -- legs: planned while the robot moves --------------------------------------------------------
    def _provisional(self, z, t_now: float):
        """Start the current leg at once on its quasi-stable guess from ``z`` (a simulation of the model),
        refined as it goes (``_refine``)."""
        self._follow_guess(z, t_now)

    def _follow_guess(self, z, t_now: float):
        """Make the current leg the quasi-stable guess from ``z``, to be refined ``tilt_settle`` s later."""
        s, stop = self.settings, self.mission.stops[self.segment]
        guess = quasi_stable_guess(z, np.asarray(stop, float), self.params.replace(slope=0.0), s.plan.N,
                                   accels=s.ride_accels)
        guess.extra = {"goal": list(map(float, stop)), "provisional": True}
        self.reference.segments[self.segment] = (guess, {"stop": stop})
        self.segment_start = t_now
        self._anchor = None
        self._refine_at = t_now + s.tilt_settle

    def _refine(self, t_now: float):
        """Plan the minimum-time leg from where the robot following the guess will be each of ``plan_handovers``
        s later (those within the guess), one after the other; the one ready in time that arrives first takes
        over where it starts (``_take_pending``).  The start is the state the tracking NMPC's last solution
        predicts for that instant (``_predicted``; the guess's own state if beyond its horizon): the robot
        holding to the guess on a plant unlike the model drives its motor off the guess's speed (course 13:
        -7.4 against -3.0 rad/s), and a leg planned from the guess's state then starts where the robot is
        not.  The guess's tail, moved to start at the predicted position, is the solver's initial guess, and
        ``refine_fresh`` fresh quasi-stable guesses from the same start are others."""
        self._refine_at = None
        guess = self.reference.segments[self.segment][0]
        best = None
        for ahead in self.settings.plan_handovers:
            handover = t_now - self.segment_start + ahead
            if handover >= guess.T - ahead:
                continue
            z_start, tail = self._predicted(t_now + ahead), guess.tail(handover, self.settings.plan.N)
            if z_start is None:
                z_start = guess.state(handover)
            else:
                tail.z[REDUCED.position] += (z_start[REDUCED.position] - tail.z[REDUCED.position, 0])[:, None]
            self._launch(self.segment, t_now, self.segment_start + handover, z_start, tail)
            candidates = [self._pending.pop(self.segment)]
            if self.settings.refine_fresh:  # the same leg also from fresh guesses (one set of guesses charged)
                wall = time.perf_counter()
                fresh = quasi_stable_guesses(z_start, np.asarray(self.mission.stops[self.segment], float),
                                             self.params.replace(slope=0.0), self.settings.plan.N,
                                             self.settings.refine_fresh)
                cost = (time.perf_counter() - wall, self.settings.plan_guess_time)
                for start_guess in fresh:
                    self._launch(self.segment, t_now, self.segment_start + handover, z_start, start_guess, cost)
                    candidates.append(self._pending.pop(self.segment))
                    cost = (0.0, 0.0)
            for candidate in candidates:
                if candidate["plan"] is None:
                    continue
                key = (candidate["ready"] > candidate["start"] + 1e-9, candidate["start"] + candidate["plan"].T)
                if best is None or key < best[0]:
                    best = (key, candidate)
        if best is not None:
            self._pending[self.segment] = best[1]
        elif any(t_now - self.segment_start + ahead < guess.T - ahead for ahead in self.settings.plan_handovers):
            self._refine_at = max(self._planner_free, t_now + self.settings.h)  # failed: again once computed

    def _predicted(self, t: float):
        """The reduced state (10,) the tracking NMPC's last successful solve predicts for the time ``t`` (s),
        or None if that is beyond its horizon (or there is none)."""
        if self._prediction is None:
            return None
        Z, solved = self._prediction
        node = int(round((t - solved) / self.settings.h))
        return Z[:, node].copy() if 0 <= node < Z.shape[1] else None

    def _launch(self, segment: int, t_now: float, t_start, z_start, guess=None, guessed=(0.0, 0.0)):
        """Plan leg ``segment`` from ``z_start`` on the estimated floor with the learned model
        (``TiltEstimator``); it may be used once its modelled compute time has passed, and is followed from the
        absolute time ``t_start`` (s; None: from the moment the stop before it is reached).  ``guessed``: the
        wall-clock and modelled time (s) of computing the ``guess`` given, charged to this plan."""
        s, stop = self.settings, self.mission.stops[segment]
        wall = time.perf_counter() - guessed[0]
        model = self.estimator.params()  # the estimated floor and the learned masses and damping
        scale = max(s.caution_floor, s.caution ** self.log["brakes"])  # from rest: gentler after recoveries
        goals = [np.asarray(stop, float)]
        if guess is None:  # from rest: a stepping stone if the stop cannot be planned
            towards = goals[0] - np.asarray(z_start[REDUCED.position], float)
            distance = float(norm(towards))
            if distance > s.stone_distance:
                goals.append(goals[0] - towards * (1.0 - s.stone_distance / distance))

        def attempt(goal):  # a refinement from its guess, or the fastest of several starts
            return self._legs.solve(z_start, goal, guess=guess, model=model) if guess is not None \
                else self._legs.fastest(z_start, goal, s.plan_starts, motor_scale=scale, model=model,
                                        resumes=s.plan_resumes, quick=s.plan_quick)

        plan, iterations, tried = self._first_converged([functools.partial(attempt, goal) for goal in goals])
        goal = goals[tried - 1]
        if plan is not None and goal is not goals[0]:
            plan.extra["stone"] = True  # from its end, the leg is planned again
            self.log["stones"] += 1
        guesses = tried * s.plan_guess_time if guess is None else guessed[1]
        ready = self._schedule(t_now, time.perf_counter() - wall, iterations * s.plan_iteration_time + guesses)
        self._pending[segment] = {"plan": plan, "start": t_start, "ready": ready}

    def _first_converged(self, attempts):
        """Call the plan ``attempts`` (functions of no arguments that solve) in turn until one converges; each
        failure is reported.  Returns the plan (None if every attempt failed), the IPOPT iterations of all of
        them and how many were tried."""
        iterations, tried = 0, 0
        for attempt in attempts:
            tried += 1
            try:
                plan = attempt()
            except SolveFailed as exc:  # reported, never followed
                self.log["statuses"].append(f"plan failed: {exc.status}")
                self.log["plan_failures"] += 1
                iterations += exc.plan.iterations if exc.plan is not None else 0
                continue
            return plan, iterations + plan.iterations, tried
        return None, iterations, tried

    def _schedule(self, t_now: float, wall: float, modelled: float) -> float:
        """When a plan asked for at ``t_now`` may be used (s): at the first solve instant after the one planner
        has finished it, ``modelled`` s after it began (after the plans before it; with ``realtime``, the
        measured ``wall`` s instead).  The wall-clock time is reported."""
        s = self.settings
        self.log["plan_solve_times"].append(wall)
        begin = max(t_now, self._planner_free)
        ready = t_now + s.h * math.ceil((begin - t_now + (wall if s.realtime else modelled)) / s.h - 1e-9)
        self._planner_free = ready
        return ready

    def _plan_ahead(self, t_now: float, plan):
        """Plan the next leg not yet planned, up to ``legs_ahead`` beyond the current one, from the rest state
        the leg before it is planned to end in (once that plan is ready, and not a stepping stone's; the
        current leg's refinement counts once it is ready, before it takes over)."""
        j, base = self.segment, plan
        if j not in self._pending:
            j += 1  # (a provisional guess not being refined ends nowhere planned: refused below)
        while j in self._pending:
            pending = self._pending[j]
            if t_now < pending["ready"] - 1e-9 or pending["plan"] is None:
                return
            j, base = j + 1, pending["plan"]
        if base.extra.get("stone") or base.extra.get("provisional"):
            return  # a stepping stone's end is planned again from rest; a guess's end is not a plan
        if j >= len(self.mission.stops) or j > self.segment + self.settings.legs_ahead \
                or self.reference.segments[j] is not None:
            return
        end = base.z[:, -1].copy()
        end[REDUCED.velocity] = 0.0
        self._launch(j, t_now, None, end)

    def _drop_plans(self, first: int, t_now: float):
        """Forget the legs planned for segments ``first`` on (they chain from one another); a computation
        still running for them is abandoned, so the planner is free from ``t_now``."""
        for j in [j for j in self._pending if j >= first]:
            del self._pending[j]
        self._planner_free = min(self._planner_free,
                                 max([t_now] + [pending["ready"] for pending in self._pending.values()]))

    def _fits(self, pending, z) -> bool:
        """Whether a leg planned ahead starts where the robot is: within ``replan_distance`` and with its
        pendulum frame turned less than ``replan_angle`` from the robot's."""
        if pending is None or pending["plan"] is None:
            return False
        start = pending["plan"].z[:, 0]
        near = norm(start[REDUCED.position] - z[REDUCED.position]) <= self.settings.replan_distance
        return near and _turned(start[REDUCED.quaternion], z[REDUCED.quaternion]) <= self.settings.replan_angle

    def _take_pending(self, t_now: float) -> bool:
        """Follow the planned leg of the current segment if it is ready and meant to start by now."""
        pending = self._pending.get(self.segment)
        if pending is None or t_now < pending["ready"] - 1e-9:
            return False
        start = pending["start"] if pending["start"] is not None else t_now
        if t_now < start - 1e-9:
            return False  # ready before its start: kept until then
        del self._pending[self.segment]
        if pending["plan"] is None:  # the plan failed: the robot goes on with what it follows
            return False
        if pending["start"] is not None and pending["ready"] > pending["start"] + 1e-9:
            # ready after the moment it was planned from: the robot has gone on without it
            self.log["plan_late"] += 1
            if self.reference.segments[self.segment][0].extra.get("provisional"):
                self._refine_at = t_now  # once more, from further along the guess
            return False
        self.reference.segments[self.segment] = (pending["plan"], {"stop": self.mission.stops[self.segment]})
        self.segment_start = start
        self._anchor = None
        # the warm start (iterate and multipliers) solved the reference replaced: the next step starts from this
        # one (warm, its first steps chatter between the motor's limits and the robot leaves the new leg:
        # ``benchmarks/bench_robustness_result.md`` item 20)
        self.warm = None
        return True

    # -- the loop ---------------------------------------------------------------------------------
    def reset(self):
        """Forget the run; a mission prepared (``prepare``) and not yet run is kept."""
        if getattr(self, "k", 0) > 0 or self.reference is None:
            self.reference = None
            self.segment, self.segment_start = 0, 0.0
            self._pending = {}  # legs being planned, by segment
            self._planner_free = 0.0  # when the planner has finished the plans it was given, s
            self._refine_at = None  # when to refine the quasi-stable guess followed
            self._braking_since = None  # when the robot began to be brought to rest
            self._anchor = None
            self._gate_plans = []  # every plan through the gates, for the report
            self.log = {"solve_times": [], "statuses": [], "fallback_shifted": 0, "fallback_pid": 0,
                        "fallback_brake": 0, "late": 0, "failed": 0, "tilt": [], "replans": 0, "plan_solve_times": [],
                        "plan_failures": 0, "plan_wait": 0.0, "stop_wait": 0.0, "brakes": 0, "plan_late": 0,
                        "stones": 0, "unfit": 0, "cold_retries": 0}
        self.k = 0
        self.warm = None
        self.current = None  # (U, index of the interval in use)
        self._prediction = None  # (Z (10, N+1), solve instant, s): the states the last solve predicts
        self.commands: dict[int, float] = {}
        self.previous = None
        self.failures = 0
        self.pid_until = -1.0
        self._ramp = None  # (start time, s; driving speed, rad/s) of the fallback's speed ramp
        self._pid_fresh = True
        self.stops: list[dict] = []
        self._monitor = None
        self._pid_goal = None
        self._done = False
        self._finished_at = None
        self._gates_passed = 0
        self._gate = None  # watches the next gate
        self.estimator.reset()

    @property
    def done(self) -> bool:
        """True ``finish_hold`` seconds after every stop has been reached (never for a circle)."""
        return self._done

    def __call__(self, obs: Observation) -> Command:
        if self.reference is None:
            self.prepare(obs.state)
        k, dt = self.k, self.dt
        self.k += 1
        t_now = k * dt
        z_meas = to_reduced(obs.state)
        seen = int(round(obs.t / dt))
        self._estimate(seen, z_meas)
        z = self._predict_to_now(z_meas, seen, k)
        reached = self._watch_stop(obs)
        self._watch_gates(obs)
        if k % self.every == 0:  # stops are left at the solve instants, so legs start on the grid
            self._advance_mission(t_now, obs, reached, z)
        if self._done:
            return self._issue(k, 0.0)
        if t_now < self.pid_until:
            return self._fallback_command(k, obs, z)
        if k % self.every == 0 or self.current is None:
            self._replan(z, t_now, k)
            if self.current is None:  # the fallback took over
                return self._fallback_command(k, obs, z)
        U, k_solved = self.current
        return self._issue(k, float(U[min((k - k_solved) // self.every, len(U) - 1)]))

    def _issue(self, k: int, accel: float) -> Command:
        self.commands[k] = accel
        self.commands.pop(k - 50, None)
        return Command(accel=accel)

    def _estimate(self, seen: int, z_meas):
        if self.settings.estimate_tilt and self.previous is not None and seen == self.previous[0] + 1:
            u = self.commands.get(self.previous[0], 0.0)
            self.estimator.update(self.previous[1], u, z_meas)
        else:
            self.estimator.lose_track()
        self.previous = (seen, z_meas)

    def _predict_to_now(self, z, seen: int, k: int):
        """Delay compensation: carry a measurement taken at step ``seen`` forward to step ``k``."""
        if seen >= k:
            return z
        p = self.estimator.params()
        predicted = z
        for j in range(seen, k):
            predicted = self.estimator.step(predicted, self.commands.get(j, 0.0), p)[0].copy()
        return predicted if np.all(np.isfinite(predicted)) else z  # never act on a broken prediction

    def _watch_stop(self, obs: Observation) -> bool:
        """Feed the current stop's monitor (``StopRule``: near it and at rest for 0.5 s); True once reached."""
        if self.reference is None or not self.mission.stops or self._done:
            return False
        if self._monitor is None:
            self._monitor = StopMonitor(self.reference.segments[self.segment][1]["stop"], self._rule)
        centre_speed = self.params.R * math.hypot(obs.omega[0], obs.omega[1])
        return self._monitor.update(obs.t, obs.position, centre_speed, obs.theta_dot)

    def _advance_mission(self, t_now: float, obs: Observation, reached: bool, z):
        """Follow refined legs as they become ready, plan the next leg ahead, leave a stop once it is
        reached, and, if the robot was pushed off its plan or came to rest outside its stop's tolerance,
        bring it to rest and plan a new leg to the same stop from there (``_brake``)."""
        if self.reference is not None and self.mission.gates:
            self._advance_gates(t_now, z)
        if self.reference is not None and self.mission.orbit is not None:
            self._advance_entry(t_now)
        if self.reference is None or not self.mission.stops:
            return
        s, i = self.settings, self.segment
        if self._finished_at is not None:  # the last stop is reached: hold there a little longer
            self._done = t_now >= self._finished_at + s.finish_hold - 1e-9
            return
        if self._refine_at is not None and t_now >= self._refine_at - 1e-9:
            self._refine(t_now)
        if self._braking_since is None:
            self._take_pending(t_now)
        plan, info = self.reference.segments[i]
        local = t_now - self.segment_start
        if self._braking_since is None and local >= s.plan_ahead * plan.T and t_now >= s.tilt_settle - 1e-9:
            self._plan_ahead(t_now, plan)  # (on the tilt estimated by then)
        if self._braking_since is None and not reached and local >= plan.T - 1e-9:
            self.log["stop_wait"] += s.h  # the leg has ended, its stop is not reached yet (not at rest, or away)
        if reached and local >= plan.T - 1e-9:
            ahead = self._pending.get(i + 1)
            if ahead is not None and t_now < ahead["ready"] - 1e-9:
                self.log["plan_wait"] += s.h  # the next leg is still being planned: stay at this stop
                return
            self.stops.append(self._monitor.record(obs.position))
            if i + 1 >= len(self.mission.stops):
                self._finished_at = t_now
                return
            self._pending.pop(i, None)
            self.segment += 1
            self.warm, self.current, self._monitor = None, None, None
            self._refine_at = self._braking_since = None
            if not (self._fits(self._pending.get(self.segment), z) and self._take_pending(t_now)):
                self._drop_plans(self.segment, t_now)  # nothing (or nothing that fits) planned ahead: from here
                self._brake(z, t_now, recovery=False)
            return
        at_rest = (self.params.R * float(norm(z[REDUCED.omega])) < s.recover_speed
                   and abs(float(z[REDUCED.theta_dot])) < s.recover_drive)
        if self._braking_since is not None:  # recovering: a new leg from rest, planned while it holds
            pending = self._pending.get(i)
            if (pending is not None and pending["plan"] is not None and t_now >= pending["ready"] - 1e-9
                    and not self._fits(pending, z)):  # it did not stay where its leg starts: brake once more
                del self._pending[i]
                self._braking_since, self._rest_plan = t_now, None
                self.log["unfit"] += 1
                return
            if self._take_pending(t_now):  # the leg from rest is ready: follow it
                self._braking_since = None
            elif i in self._pending:  # still being planned: hold
                return
            elif self._rest_plan is not None:  # it failed (and was dropped): the quasi-stable guess from here
                self._braking_since = None
                self._provisional(z, t_now)
            elif at_rest or t_now - self._braking_since >= s.brake_wait - 1e-9:
                start = self._rest(z)
                self._launch(i, t_now, None, start)
                self._rest_plan = start  # held there (``hold_weights``) until the leg is ready
                return
            else:
                return
            self.warm, self.current = None, None
            return
        anchor = self._anchor if self._anchor is not None else plan.state(local)[REDUCED.position]
        off_course = norm(z[REDUCED.position] - anchor) > s.replan_distance
        away = norm(z[REDUCED.position] - np.asarray(info["stop"], float)) > self._rule.tolerance
        settled_away = local >= plan.T + s.hold_time and at_rest and away
        if settled_away or (off_course and local >= s.replan_interval):
            # never move on from here: a new leg to the same stop from where the robot is, once it is at
            # rest (the next leg, planned from where this one was to end, is planned again)
            # (at rest already if settled away: planned from there at once; a stepping stone is no recovery)
            self._brake(z, t_now, recovery=not (settled_away and plan.extra.get("stone")))
            self.warm, self.current = None, None
            self.log["replans"] += 1

    def _brake(self, z, t_now: float, recovery: bool = True):
        """Bring the robot to rest where it is (``brake_weights``) and hold it there while a new leg is
        planned from rest, the fastest of ``plan_starts`` (``_advance_mission``; if that fails, the
        quasi-stable guess from where it is).  The stop's planned legs are dropped.  ``recovery``: counted
        in ``brakes`` (not for a leg begun at a stop the planned-ahead leg does not fit)."""
        self._drop_plans(self.segment, t_now)
        if self.reference.segments[self.segment] is None:  # a new stop: rest where it is until its leg
            rest = np.tile(np.asarray(z, float)[:, None], (1, 2))
            rest[REDUCED.velocity] = 0.0
            hold = Plan(np.array([0.0, self.settings.h]), rest, np.zeros(1), self.settings.h, "hold", True, 0, 0.0,
                        {"provisional": True})
            self.reference.segments[self.segment] = (hold, {"stop": self.mission.stops[self.segment]})
            self.segment_start = t_now
        self._braking_since = t_now
        self._rest_plan = None  # the rest state the new leg is planned from, once launched
        self._anchor = None
        self._refine_at = None
        self.log["brakes"] += recovery

    def _replan(self, z, t_now: float, k: int):
        s = self.settings
        diag = None
        if self._braking_since is not None:  # rest where the robot is (its motion counts), then hold there
            held = self._rest_plan is not None
            Zr = np.tile((self._rest_plan if held else self._rest(z))[:, None], (1, s.N + 1))
            Ur, diag = np.zeros(s.N), self._hold_diag if held else self._brake_diag
        else:
            Zr, Ur = self.reference.sample(self.segment, t_now - self.segment_start, s.h, s.N, position=z[REDUCED.position])
            self._settle(Zr, t_now, z)
            if self._anchor is not None:  # holding at a stop
                diag = self._hold_diag
            elif self.mission.gates:
                diag = self._gate_diag(t_now - self.segment_start)
            elif self.mission.stops and self.weights.arrives:  # the motor and the shell still on arrival
                ended = self.reference.ended(self.segment, t_now - self.segment_start, s.h, s.N)
                diag = self.weights.diagonal(s.N, ended) if ended.any() else None
        # q and -q are the same attitude: give the (continuous) reference the measurement's sign
        if dot(Zr[REDUCED.quaternion, 0], z[REDUCED.quaternion]) < 0:
            Zr[REDUCED.quaternion] *= -1.0
        mission_weights = None
        if self.mission.orbit is not None:  # the distance from the circle counts once on the orbit
            on_orbit = (t_now - self.segment_start + s.h * np.arange(s.N + 1)) > self.reference.segments[0][0].T
            mission_weights = self.weights.radial * on_orbit
        x, lam, status, ok, seconds = self.solver.solve(z, Zr, Ur, self.estimator.params(), self.warm, mission_weights,
                                                        diag)
        compute = seconds if s.realtime else self.solver.modelled_time()
        if not ok and self.warm is not None:
            # a warm start gone bad (an iterate that diverged linearises to a QP no solver can solve): once
            # more from the reference, in the same interval, its compute time added
            self.log["cold_retries"] += 1
            first = status
            x, lam, status, ok, again = self.solver.solve(z, Zr, Ur, self.estimator.params(), None, mission_weights,
                                                          diag)
            seconds += again
            compute += again if s.realtime else self.solver.modelled_time()
            status = f"cold after {first}: {status}"
            if not ok:
                self.warm = None  # no use starting from it again
        late = compute > (s.h if s.max_solve_time is None else s.max_solve_time)
        self.log["solve_times"].append(seconds)
        self.log["statuses"].append(status)
        self.log["tilt"].append(self.estimator.tilt.tolist())
        if ok and not late:
            Z, U = self.solver.split(x)
            self.current = (U, k)
            self._prediction = (Z, t_now)
            self.warm = (self.solver.shift(x), *lam)  # duals unshifted: the structure repeats every interval
            self.failures = 0
            return
        self.log["late" if ok else "failed"] += 1
        self.failures += 1
        if self.current is not None and self.failures < s.max_failures:
            self.log["fallback_shifted"] += 1  # keep following the previous solution (its index moves on)
            return
        self.warm, self.current, self.failures = None, None, 0
        self._prediction = None  # no solution acts now: a refinement starts from the guess's own state
        if self.mission.stops and s.fallback == "brake":
            # the motor's speed ramped to zero for a moment, then the NMPC brings the robot to rest and
            # plans a new leg from there (``_advance_mission``)
            self.log["fallback_brake"] += 1
            if self._braking_since is None:
                self._brake(z, t_now)
            speed = float(z[REDUCED.theta_dot])
            self._ramp = (t_now, speed)
            self.pid_until = t_now + abs(speed) / s.brake_accel + s.h
            return
        self.log["fallback_pid"] += 1
        self._ramp = None
        self.pid_until = t_now + s.pid_time
        self._pid_fresh = True

    def _rest(self, z) -> np.ndarray:
        """The rest state for the reduced state ``z``: where it is, still; with its attitude if that is within
        ``swung_angle`` of the balanced rest with its motor axis' heading, else (the mass swung up: no state to
        rest in) that rest, on the estimated floor (``dynamics.rest_attitude``)."""
        rest = np.array(z, float)
        rest[REDUCED.velocity] = 0.0
        q = rest[REDUCED.quaternion]
        try:
            balanced = rest_attitude(q, self.estimator.params())
        except ValueError:  # no balance on the floor estimated so far: the level floor's
            balanced = rest_attitude(q, self.params.replace(slope=0.0))
        if _turned(balanced, q) > self.settings.swung_angle:
            rest[REDUCED.quaternion] = balanced
        return rest

    def _settle(self, Zr, t_now: float, z):
        """Past a leg's end within ``hold_radius`` of its stop, hold the robot where it is: the reference
        position becomes the position it had on arriving, so the NMPC damps the motion instead of chasing
        a few centimetres a single motor cannot correct at rest."""
        if self.reference is None or not self.mission.stops:
            return
        plan, info = self.reference.segments[self.segment]
        ended = t_now - self.segment_start + self.settings.h * np.arange(Zr.shape[1]) >= plan.T
        if not ended[0]:
            self._anchor = None
            return
        if self._anchor is None:
            near = norm(z[REDUCED.position] - np.asarray(info["stop"], float)) <= self.settings.hold_radius
            if not near:
                return
            self._anchor = z[REDUCED.position].copy()
        Zr[REDUCED.position, :] = self._anchor[:, None]

    def _fallback_command(self, k: int, obs: Observation, z) -> Command:
        """After ``max_failures`` failed solves: the motor's speed ramped to zero (``fallback = "brake"``),
        or the PID (``"pid"``, and circles), as a speed command."""
        if self._ramp is None:
            return self._pid_command(k, obs, z)
        t0, speed0 = self._ramp
        speed = math.copysign(max(0.0, abs(speed0) - self.settings.brake_accel * (k * self.dt - t0)), speed0)
        limit = self.params.max_accel
        self.commands[k] = float(np.clip((speed - float(z[REDUCED.theta_dot])) / self.dt, -limit, limit))
        self.commands.pop(k - 50, None)
        return Command(speed=speed)

    def _pid_command(self, k: int, obs: Observation, z) -> Command:
        """The paper's PID on the current goal (the stop in progress, or the circle), as a speed command.

        The plant's speed loop turns the speed into an acceleration with the current driving speed; the
        NMPC's own record of the command (for its delay compensation) uses the predicted driving speed.
        """
        goal = self._target_index()
        if self._pid is None or self._pid_goal != goal:
            from rollbot_oc.control.pid import QuasiStablePID

            self._pid, self._pid_goal, self._pid_fresh = QuasiStablePID(
                self.mission.leg(goal), self.params, dt=self.dt, radius_map=self.map), goal, True
        if self._pid_fresh:  # take over smoothly from the current driving speed
            self._pid.reset()
            self._pid.omega_cmd = max(float(z[REDUCED.theta_dot]), 0.0)
            self._pid_fresh = False
        speed = self._pid(obs).speed
        limit = self.params.max_accel  # the plant's motor cannot follow faster either
        self.commands[k] = float(np.clip((speed - float(z[REDUCED.theta_dot])) / self.dt, -limit, limit))
        self.commands.pop(k - 50, None)
        return Command(speed=speed)

    def _target_index(self) -> int:
        """The mission's target in progress: the stop's segment, the next gate, 0 on an orbit."""
        return self.segment if self.mission.stops else self._gates_passed

    def report(self) -> dict:
        """Solve-time statistics (s), solver statuses, fallback counts, stops and plans."""
        times = np.array(self.log["solve_times"]) if self.log["solve_times"] else np.zeros(1)
        statuses = {}
        for st in self.log["statuses"]:
            statuses[st] = statuses.get(st, 0) + 1
        legs = [seg for seg in self.reference.segments if seg is not None] if self.reference else []
        plans = [seg[0].to_dict() for seg in legs] if not self.mission.gates else list(self._gate_plans)
        plan_times = np.array(self.log["plan_solve_times"]) if self.log["plan_solve_times"] else np.zeros(1)
        return {
            "stops": list(self.stops),
            "solver": self.settings.solver,
            "solves": len(self.log["solve_times"]),
            "solve_time_min": float(times.min()),
            "solve_time_median": float(np.median(times)),
            "solve_time_p95": float(np.percentile(times, 95)),
            "solve_time_max": float(times.max()),
            "solver_statuses": statuses,
            "failed_solves": self.log["failed"],
            "cold_retries": self.log["cold_retries"],
            "late_solves": self.log["late"],
            "fallback_shifted": self.log["fallback_shifted"],
            "fallback_pid": self.log["fallback_pid"],
            "fallback_brake": self.log["fallback_brake"],
            "plan_time": self.plan_time,
            "stop_replans": self.log["replans"],
            "brakes": self.log["brakes"],
            "stones": self.log["stones"],
            "plans_unfit": self.log["unfit"],
            "plans": plans,
            "plan_duration": float(sum(seg[0].T for seg in legs)) if legs else None,
            "plan_solves": len(self.log["plan_solve_times"]),
            "plan_failures": self.log["plan_failures"],
            "plan_late": self.log["plan_late"],
            "plan_wait": self.log["plan_wait"],
            "stop_wait": self.log["stop_wait"],
            "plan_solve_time_median": float(np.median(plan_times)),
            "plan_solve_time_max": float(plan_times.max()),
            "tilt_estimate": self.estimator.tilt.tolist(),
            "model_learned": self.estimator.learned(),
        }


@functools.lru_cache(maxsize=8)
def _rest_to_rest(params: RollbotParams, settings: OCPSettings, constraints: tuple) -> RestToRest:
    return RestToRest(params, settings, constraints)


def _turned(a, b) -> float:
    """The angle between the attitudes of the quaternions ``a`` and ``b`` (either sign), rad."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return 2.0 * math.acos(min(abs(dot(a, b)) / (norm(a) * norm(b)), 1.0))


def _revolving_centre(ramp: Plan, Omega: float) -> np.ndarray:
    """The centre a ramp ends revolving about, m: its mean position over its last revolution (``2 pi / Omega``
    s; the whole ramp if it is shorter)."""
    times = np.linspace(max(ramp.T - 2 * math.pi / abs(Omega), 0.0), ramp.T, 200, endpoint=False)
    return ramp.state(times)[REDUCED.position].mean(axis=1)


@functools.lru_cache(maxsize=8)
def _orbit_entry(radius: float, params: RollbotParams, settings: OCPSettings, constraints: tuple) -> OrbitEntry:
    return OrbitEntry(radius, params, settings, constraints)
