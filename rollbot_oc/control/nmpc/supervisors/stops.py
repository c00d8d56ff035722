"""The supervisor of a course of stops: legs planned as the robot moves, holds, recoveries (``StopsMode``).

The first leg starts at once on its quasi-stable guess (``RIDE``): a simulation of the model, a fraction of
a second.  Once the tilt estimate has settled (``filter.settle``) minimum-time legs are refined from where
the tracking step predicts the robot will be each of ``planner.handovers`` later; the one ready in time that
arrives first takes over where it starts (``TRACK``).  The next ``planner.legs_ahead`` legs are planned
ahead, each from the rest state the leg before it ends in, and each is used only once its compute time has
passed.  Past a leg's end near its stop the robot is held where it arrived (``HOLD``).  A stop is left once
reached (``StopRule``), onto the leg planned ahead if it starts where the robot is.  A robot off its plan,
at rest away from its stop, or whose step gave up, is brought to rest (``BRAKE``) and held there
(``REST``) while a new leg is planned from rest (the fastest of ``planner.starts``; to a stepping stone if
the stop cannot be planned).  After the last stop it is held ``arrival.finish_hold`` (``FINISH``; ``FINISH_AT_REST`` if it
reached the stop while being brought to rest, or its step gave up meanwhile).
"""

from __future__ import annotations

import functools
import math
import time
from enum import Enum

import numpy as np

from rollbot_oc.control.nmpc.modes import StopsMode
from rollbot_oc.control.nmpc.reference import Reference
from rollbot_oc.control.nmpc.step import Window
from rollbot_oc.control.nmpc.supervisors.base import Supervisor, _turned
from rollbot_oc.planning.min_time import OCPSettings, Plan, RestToRest, quasi_stable_guess, quasi_stable_guesses
from rollbot_oc.model.dynamics import REDUCED, to_reduced
from rollbot_oc.missions import StopMonitor
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.core.reproducible import norm

__all__ = ["StopsSupervisor", "LegKind"]

M = StopsMode
MOVING = (M.RIDE, M.TRACK, M.HOLD)
BRAKING = (M.BRAKE, M.REST)
FINISHING = (M.FINISH, M.FINISH_AT_REST)


class LegKind(Enum):
    """What a segment of the reference is."""

    GUESS = "guess"  # a quasi-stable guess, ridden while its leg is planned
    REST = "rest"  # rest where the robot is at a new stop, until its leg is planned
    PLAN = "plan"  # a minimum-time leg to the stop
    STONE = "stone"  # a minimum-time leg to a stepping stone towards the stop


class StopsSupervisor(Supervisor):
    """Legs between stops (module doc)."""

    initial = M.RIDE

    def __init__(self, context):
        super().__init__(context)
        s = context.settings
        self.fallback = s.recovery.fallback
        self._rule = context.mission.stop_rule
        level = context.params.replace(slope=0.0)
        self._legs = _rest_to_rest(level, s.planner.legs, tuple(s.limits.constraints))
        self._legs.build()  # now, not during the run
        N = s.horizon.N
        self._hold_diag = s.weights.hold.diagonal(N)
        self._brake_diag = s.weights.brake.diagonal(N)
        self.weights = s.weights.legs
        self.reset()

    def reset(self) -> None:
        super().reset()
        self.kinds: list = []  # LegKind of each segment of the reference
        self.stops: list = []  # what the monitor recorded at each stop reached
        self._monitor = None
        self._anchor = None  # HOLD (and FINISH): the position held, m
        self._rest_state = None  # REST: the rest state its leg is planned from
        self._refine_at = None  # RIDE: when to plan the guess's refinement, s

    @property
    def done(self) -> bool:
        return self.mode is M.DONE

    @property
    def goal(self) -> int:
        return self.segment

    # -- the loop's questions ----------------------------------------------------------------------
    def prepare(self, x0, radius_map) -> Reference:
        stops = self.c.mission.stops
        self.reference = Reference([None] * len(stops))
        self.kinds = [None] * len(stops)
        self._follow_guess(to_reduced(x0), 0.0)
        return self.reference

    def watch(self, obs, k: int) -> bool:
        """Feed the current stop's monitor (``StopRule``: near it and at rest for a while); True once reached."""
        if self.reference is None or self.mode is M.DONE:
            return False
        if self._monitor is None:
            self._monitor = StopMonitor(self.reference.segments[self.segment][1]["stop"], self._rule)
        centre_speed = self.c.params.R * math.hypot(obs.omega[0], obs.omega[1])
        return self._monitor.update(obs.t, obs.position, centre_speed, obs.theta_dot)

    def advance(self, k: int, obs, reached: bool, z) -> None:
        s, log = self.c.settings, self.c.telemetry
        t_now, i = k * self.c.dt, self.segment
        if self.mode is M.DONE:
            return
        if self.mode in FINISHING:  # the last stop is reached: hold there a little longer
            if t_now >= self.modes.since_within(*FINISHING) * self.c.dt + s.arrival.finish_hold - 1e-9:
                self.modes.go(M.DONE, k, "finish_hold has passed")
            return
        if self._refine_at is not None and t_now >= self._refine_at - 1e-9:
            self._refine(t_now)
        braking = self.mode in BRAKING
        if not braking:
            self._take_pending(k, "a refined leg is ready and its start has come")
        plan, info = self.reference.segments[i]
        local = t_now - self.segment_start
        if not braking and local >= s.planner.ahead * plan.T and t_now >= s.filter.settle - 1e-9:
            self._plan_ahead(t_now, plan)  # (on the tilt estimated by then)
        if not braking and not reached and local >= plan.T - 1e-9:
            log.stop_wait += s.horizon.h  # the leg has ended, its stop is not reached yet (not at rest, or away)
        if reached and local >= plan.T - 1e-9:
            self._leave_stop(k, obs, z)
            return
        at_rest = (self.c.params.R * float(norm(z[REDUCED.omega])) < s.recovery.recover_speed
                   and abs(float(z[REDUCED.theta_dot])) < s.recovery.recover_drive)
        if braking:
            self._recover(k, z, at_rest)
            return
        anchor = self._anchor if self._anchor is not None else plan.state(local)[REDUCED.position]
        off_course = norm(z[REDUCED.position] - anchor) > s.recovery.replan_distance
        away = norm(z[REDUCED.position] - np.asarray(info["stop"], float)) > self._rule.tolerance
        settled_away = local >= plan.T + s.arrival.hold_time and at_rest and away
        if settled_away or (off_course and local >= s.recovery.replan_interval):
            # never move on from here: a new leg to the same stop from where the robot is, once it is at
            # rest (at rest already if settled away; a stepping stone's end is no recovery)
            reason = "at rest outside the stop's tolerance hold_time after the leg's end" if settled_away \
                else "off the plan by more than replan_distance"
            self._brake(z, k, reason, recovery=not (settled_away and self.kinds[i] is LegKind.STONE))
            self.c.step.restart()
            log.replans += 1

    def window(self, z, k: int) -> Window:
        s = self.c.settings
        t_now = k * self.c.dt
        if self.mode in BRAKING + (M.FINISH_AT_REST,):  # rest where the robot is (its motion counts), or hold
            # at the rest its leg is planned from (REST; FINISH_AT_REST entered from REST keeps that rest)
            held = self.mode is M.REST or (self.mode is M.FINISH_AT_REST and self._rest_state is not None)
            rest = self._rest_state if held else self._rest(z)
            return Window(np.tile(rest[:, None], (1, s.horizon.N + 1)), np.zeros(s.horizon.N),
                          self._hold_diag if held else self._brake_diag)
        window = self._sample(z, t_now)
        self._settle(window.Zr, k, z)
        if self._anchor is not None:  # holding at a stop
            window.diag = self._hold_diag
        elif self.weights.arrives:  # the motor and the shell still on arrival
            ended = self.reference.ended(self.segment, t_now - self.segment_start, s.horizon.h, s.horizon.N)
            window.diag = self.weights.diagonal(s.horizon.N, ended) if ended.any() else None
        return window

    def on_give_up(self, z, k: int) -> None:
        if self.mode in MOVING:
            self._brake(z, k, "the step gave up: failed with nothing to follow")
        elif self.mode is M.FINISH:  # brought to rest where it is while finishing
            self.c.planner.drop(self.segment, k * self.c.dt)
            self._rest_state, self._anchor = None, None
            self.c.telemetry.brakes += 1
            self.modes.go(M.FINISH_AT_REST, k, "the step gave up: failed with nothing to follow")

    def plans(self) -> list:
        out = []
        for seg, kind in zip(self.reference.segments if self.reference else [], self.kinds):
            if seg is None:
                continue
            flag = {"provisional": True} if kind in (LegKind.GUESS, LegKind.REST) else \
                {"stone": True} if kind is LegKind.STONE else {}
            out.append({**seg[0].to_dict(), **flag})
        return out

    # -- legs ----------------------------------------------------------------------------------------
    def _follow_guess(self, z, t_now: float) -> None:
        """Make the current leg the quasi-stable guess from ``z``, to be refined ``filter.settle`` s later."""
        s, stop = self.c.settings, self.c.mission.stops[self.segment]
        guess = quasi_stable_guess(z, np.asarray(stop, float), self.c.params.replace(slope=0.0), s.planner.legs.N,
                                   accels=s.planner.ride_accels)
        guess.extra = {"goal": list(map(float, stop))}
        self.reference.segments[self.segment] = (guess, {"stop": stop})
        self.kinds[self.segment] = LegKind.GUESS
        self.segment_start = t_now
        self._anchor = None
        self._refine_at = t_now + s.filter.settle

    def _refine(self, t_now: float) -> None:
        """Plan the minimum-time leg from where the robot following the guess will be each of
        ``planner.handovers`` s later (those within the guess), one after the other; the one ready in time
        that arrives first takes over where it starts (``_take_pending``).  The start is the state the
        tracking step's last solution predicts for that instant (the guess's own state if beyond its
        horizon): a robot on a plant unlike the model drives its motor off the guess's speed.  The guess's
        tail, moved to start at the predicted position, is the solver's initial guess, and
        ``planner.fresh`` fresh quasi-stable guesses from the same start are others.  The candidates of one
        handover are alternatives computed side by side (the host's cores): each is ready after its own
        computation, and the planner is free when the last of them is."""
        s, planner = self.c.settings, self.c.planner
        self._refine_at = None
        guess = self.reference.segments[self.segment][0]
        stop = np.asarray(self.c.mission.stops[self.segment], float)
        best = None
        for ahead in s.planner.handovers:
            handover = t_now - self.segment_start + ahead
            if handover >= guess.T - ahead:
                continue
            z_start, tail = self._predicted(t_now + ahead), guess.tail(handover, s.planner.legs.N)
            if z_start is None:
                z_start = guess.state(handover)
            else:
                tail.z[REDUCED.position] += (z_start[REDUCED.position] - tail.z[REDUCED.position, 0])[:, None]
            start = self.segment_start + handover
            free = planner.free  # the candidates are alternatives, computed side by side (one core each)
            candidates = [self._launch(self.segment, t_now, start, z_start, tail)]
            planner.pop(self.segment)  # a candidate: queued below if it is the best
            if s.planner.fresh:  # the same leg also from fresh guesses (one set of guesses charged)
                wall = time.perf_counter()
                fresh = quasi_stable_guesses(z_start, stop, self.c.params.replace(slope=0.0), s.planner.legs.N,
                                             s.planner.fresh)
                cost = (time.perf_counter() - wall, s.timing.plan_guess)
                for start_guess in fresh:
                    planner.free = free
                    candidates.append(self._launch(self.segment, t_now, start, z_start, start_guess, cost))
                    planner.pop(self.segment)
                    cost = (0.0, 0.0)
            planner.free = max(candidate.ready for candidate in candidates)
            for candidate in candidates:
                if candidate.plan is None:
                    continue
                key = (candidate.late, candidate.start + candidate.plan.T)
                if best is None or key < best[0]:
                    best = (key, candidate)
        if best is not None:
            planner.queue[self.segment] = best[1]
        elif any(t_now - self.segment_start + ahead < guess.T - ahead for ahead in s.planner.handovers):
            self._refine_at = max(planner.free, t_now + s.horizon.h)  # failed: again once computed

    def _launch(self, segment: int, t_now: float, t_start, z_start, guess=None, guessed=(0.0, 0.0)):
        """Plan leg ``segment`` from ``z_start`` on the estimated floor with the learned model, to be followed
        from ``t_start`` (s; None: from the moment the stop before it is reached).  From rest (no ``guess``):
        the fastest of ``planner.starts``, gentler after each recovery (``recovery.caution``), and a stepping
        stone if the stop cannot be planned.  ``guessed``: wall-clock and modelled time (s) of the ``guess``."""
        s, log = self.c.settings, self.c.telemetry
        stop = self.c.mission.stops[segment]
        model = self.c.step.estimator.params()  # the estimated floor and the learned masses and damping
        scale = max(s.recovery.caution_floor, s.recovery.caution ** log.brakes)
        goals = [np.asarray(stop, float)]
        if guess is None:  # from rest: a stepping stone if the stop cannot be planned
            towards = goals[0] - np.asarray(z_start[REDUCED.position], float)
            distance = float(norm(towards))
            if distance > s.recovery.stone_distance:
                goals.append(goals[0] - towards * (1.0 - s.recovery.stone_distance / distance))

        def attempt(goal):  # a refinement from its guess, or the fastest of several starts
            return self._legs.solve(z_start, goal, guess=guess, model=model) if guess is not None \
                else self._legs.fastest(z_start, goal, s.planner.starts, motor_scale=scale, model=model,
                                        resumes=s.planner.resumes, quick=s.planner.quick)

        extra = (lambda tried: tried * s.timing.plan_guess) if guess is None else None
        pending, tried = self.c.planner.solve(segment, [functools.partial(attempt, goal) for goal in goals], t_now,
                                              t_start, guessed, extra)
        pending.stone = pending.plan is not None and tried > 1  # (the second goal) planned again from its end
        log.stones += pending.stone
        return pending

    def _plan_ahead(self, t_now: float, plan) -> None:
        """Plan the next leg not yet planned, up to ``planner.legs_ahead`` beyond the current one, from the rest
        state the leg before it is planned to end in (once that plan is ready, and not a stepping stone's;
        the current leg's refinement counts once it is ready, before it takes over)."""
        queue = self.c.planner.queue
        j, base, kind = self.segment, plan, self.kinds[self.segment]
        if j not in queue:
            j += 1  # (a guess not being refined ends nowhere planned: refused below)
        while j in queue:
            pending = queue[j]
            if not pending.is_ready(t_now) or pending.plan is None:
                return
            j, base, kind = j + 1, pending.plan, LegKind.STONE if pending.stone else LegKind.PLAN
        if kind is not LegKind.PLAN:
            return  # a stepping stone's end is planned again from rest; a guess's end is not a plan
        if j >= len(self.c.mission.stops) or j > self.segment + self.c.settings.planner.legs_ahead \
                or self.reference.segments[j] is not None:
            return
        end = base.z[:, -1].copy()
        end[REDUCED.velocity] = 0.0
        self._launch(j, t_now, None, end)

    def _fits(self, pending, z) -> bool:
        """Whether a leg planned ahead starts where the robot is: within ``replan_distance`` and with its
        pendulum frame turned less than ``replan_angle`` from the robot's."""
        if pending is None or pending.plan is None:
            return False
        r = self.c.settings.recovery
        start = pending.plan.z[:, 0]
        near = norm(start[REDUCED.position] - z[REDUCED.position]) <= r.replan_distance
        return near and _turned(start[REDUCED.quaternion], z[REDUCED.quaternion]) <= r.replan_angle

    def _take_pending(self, k: int, reason: str) -> bool:
        """Follow the planned leg of the current segment if it is ready and meant to start by now (``TRACK``)."""
        t_now, planner = k * self.c.dt, self.c.planner
        pending = planner.get(self.segment)
        if pending is None or not pending.is_ready(t_now):
            return False
        start = pending.start if pending.start is not None else t_now
        if t_now < start - 1e-9:
            return False  # ready before its start: kept until then
        planner.pop(self.segment)
        if pending.plan is None:  # the plan failed: the robot goes on with what it follows
            return False
        if pending.late:  # ready after the moment it was planned from: the robot has gone on without it
            self.c.telemetry.plan_late += 1
            if self.kinds[self.segment] is LegKind.GUESS:
                self._refine_at = t_now  # once more, from further along the guess
            return False
        self.reference.segments[self.segment] = (pending.plan, {"stop": self.c.mission.stops[self.segment]})
        self.kinds[self.segment] = LegKind.STONE if pending.stone else LegKind.PLAN
        self.segment_start = start
        self._anchor = None
        self.modes.go(M.TRACK, k, reason)
        # the warm start solved the reference replaced: from it, the first steps chatter between the motor's
        # limits and the robot leaves the new leg; the next step starts from this one
        self.c.step.cold()
        return True

    # -- stops, holds and recoveries -------------------------------------------------------------------
    def _leave_stop(self, k: int, obs, z) -> None:
        """The stop is reached and its leg has ended: on to the next leg, planned ahead if it fits, else
        planned from rest here (after the last stop: ``FINISH``)."""
        s, planner = self.c.settings, self.c.planner
        t_now, i = k * self.c.dt, self.segment
        ahead = planner.get(i + 1)
        if ahead is not None and not ahead.is_ready(t_now):
            self.c.telemetry.plan_wait += s.horizon.h  # the next leg is still being planned: stay at this stop
            return
        self.stops.append(self._monitor.record(obs.position))
        if i + 1 >= len(self.c.mission.stops):
            self.modes.go(M.FINISH_AT_REST if self.mode in BRAKING else M.FINISH, k, "the last stop reached")
            return
        planner.pop(i)
        self.segment += 1
        self.c.step.restart()
        self._monitor = None
        self._refine_at = None
        if not (self._fits(planner.get(self.segment), z)
                and self._take_pending(k, "stop reached: the leg planned ahead fits and takes over")):
            self._brake(z, k, "stop reached: no leg planned ahead fits", recovery=False)  # (its plans dropped)

    def _recover(self, k: int, z, at_rest: bool) -> None:
        """``BRAKE``: once at rest (or after ``brake_wait``), plan a leg from rest (``REST``); ``REST``: follow
        it once ready, brake again if the robot moved off its start, or ride the quasi-stable guess from here if
        it failed."""
        s, planner = self.c.settings, self.c.planner
        t_now, i = k * self.c.dt, self.segment
        if self.mode is M.BRAKE:  # (nothing is planned for this stop while braking: ``_brake`` dropped it)
            if at_rest or t_now - self.modes.since * self.c.dt >= s.recovery.brake_wait - 1e-9:
                start = self._rest(z)
                self._launch(i, t_now, None, start)
                self._rest_state = start  # held there (``weights.hold``) until the leg is ready
                self.modes.go(M.REST, k, "at rest, or brake_wait has passed: its leg is planned")
            return
        pending = planner.get(i)
        if pending is not None and pending.plan is not None and pending.is_ready(t_now) and not self._fits(pending, z):
            planner.pop(i)  # it did not stay where its leg starts: brake once more
            self._rest_state = None
            self.modes.go(M.BRAKE, k, "the leg from rest is ready, but the robot moved off its start")
            self.c.telemetry.unfit += 1
        elif self._take_pending(k, "the leg from rest is ready"):
            self.c.step.restart()
        elif i not in planner.queue:  # it failed (and was dropped): the quasi-stable guess from here
            self._follow_guess(z, t_now)
            self._rest_state = None
            self.modes.go(M.RIDE, k, "the leg from rest failed: the quasi-stable guess from here")
            self.c.step.restart()

    def _brake(self, z, k: int, reason: str, recovery: bool = True) -> None:
        """Bring the robot to rest where it is (``weights.brake``) and hold it there while a new leg is planned
        from rest (``_recover``).  The stop's planned legs are dropped.  ``recovery``: counted in ``brakes``
        (not for a leg begun at a stop the planned-ahead leg does not fit)."""
        t_now = k * self.c.dt
        self.c.planner.drop(self.segment, t_now)
        if self.reference.segments[self.segment] is None:  # a new stop: rest where it is until its leg
            h = self.c.settings.horizon.h
            rest = np.tile(np.asarray(z, float)[:, None], (1, 2))
            rest[REDUCED.velocity] = 0.0
            hold = Plan(np.array([0.0, h]), rest, np.zeros(1), h, "hold", True, 0, 0.0)
            self.reference.segments[self.segment] = (hold, {"stop": self.c.mission.stops[self.segment]})
            self.kinds[self.segment] = LegKind.REST
            self.segment_start = t_now
        self._rest_state = None
        self._anchor = None
        self._refine_at = None
        self.c.telemetry.brakes += recovery
        self.modes.go(M.BRAKE, k, reason)

    def _settle(self, Zr, k: int, z) -> None:
        """Past a leg's end within ``hold_radius`` of its stop, hold the robot where it is (``HOLD``): the
        reference position becomes the position it had on arriving, so that the NMPC damps the motion
        instead of chasing a few centimetres a single motor cannot correct at rest."""
        plan, info = self.reference.segments[self.segment]
        t_now = k * self.c.dt
        ended = t_now - self.segment_start + self.c.settings.horizon.h * np.arange(Zr.shape[1]) >= plan.T
        if not ended[0]:
            self._anchor = None
            return
        if self._anchor is None:
            near = norm(z[REDUCED.position] - np.asarray(info["stop"], float)) <= self.c.settings.arrival.hold_radius
            if not near:
                return
            self._anchor = z[REDUCED.position].copy()
            if self.mode in (M.RIDE, M.TRACK):
                self.modes.go(M.HOLD, k, "the leg has ended within hold_radius of its stop")
        Zr[REDUCED.position, :] = self._anchor[:, None]


@functools.lru_cache(maxsize=8)
def _rest_to_rest(params: RollbotParams, settings: OCPSettings, constraints: tuple) -> RestToRest:
    return RestToRest(params, settings, constraints)
