"""The supervisor of a circle: a ramp up to the orbit's speed, a planned entry, then the orbit (``OrbitMode``).

At once the robot follows a ramp up to the orbit's speed (a simulation of the model, ``RAMP``).  Once the
tilt estimate has settled (``filter.settle``), the entry onto the quasi-stable orbit of the target circle is
planned from where the ramp will be ``entry.handover`` later, in the shortest of ``entry.times`` in which the
ramp's revolving centre can reach the orbit's at ``entry.shift_speed`` (least effort in that time); it takes
over where it starts if it is ready by then (``ENTRY``), else it is planned again from further along.  Past
the end of what it follows, the robot is on the orbit (``ORBIT``): the distance from the circle is weighed,
and the reference is re-phased to the robot's own angle about the centre.
"""

from __future__ import annotations

import functools
import math
from dataclasses import replace

import numpy as np

from rollbot_oc.control.nmpc.modes import OrbitMode
from rollbot_oc.control.nmpc.reference import Reference
from rollbot_oc.control.nmpc.step import Window
from rollbot_oc.control.nmpc.supervisors.base import Supervisor
from rollbot_oc.planning.min_time import OCPSettings, OrbitEntry, Plan, orbit_guess, orbit_phase
from rollbot_oc.model.dynamics import REDUCED, to_reduced
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.core.reproducible import norm

__all__ = ["OrbitSupervisor"]

M = OrbitMode


class OrbitSupervisor(Supervisor):
    """A circle (module doc)."""

    initial = M.RAMP

    @staticmethod
    def tracking_weights(settings):
        """A circle's: the distance from it weighed (``weights.circle``)."""
        return settings.weights.circle

    def __init__(self, context):
        super().__init__(context)
        s = context.settings
        self.weights = self.tracking_weights(s)
        first = s.entry.times[0]
        self._entry(first).build(first)  # the entry's route for its first duration, now (the others if needed)
        self.reset()

    def reset(self) -> None:
        super().reset()
        self._plan_entry_at = None  # RAMP: when to plan the entry, s
        self._entry_shift = 0.0  # how far the ramp's revolving centre is from the orbit's, m

    def prepare(self, x0, radius_map) -> Reference:
        s, orbit = self.c.settings, self.c.mission.orbit
        entry = self._entry(s.entry.times[0])
        guess, phase = orbit_guess(to_reduced(x0), orbit.centre, entry, hold=s.filter.settle + 4 * s.entry.handover)
        self.reference = Reference([(guess, {})], self._orbit(entry, phase))
        self._entry_shift = float(norm(_revolving_centre(guess, entry.quasi.Omega) - orbit.centre))
        self.segment_start, self._plan_entry_at = 0.0, s.filter.settle
        return self.reference

    def advance(self, k: int, obs, reached: bool, z) -> None:
        """Plan the entry from the ramp ``filter.settle`` s after the start, and follow it once it is ready and
        its start has come (a late one is planned again from further along the ramp, while the ramp lasts)."""
        t_now, planner = k * self.c.dt, self.c.planner
        if self._plan_entry_at is not None and t_now >= self._plan_entry_at - 1e-9:
            self._plan_entry_at = None
            self._launch_entry(t_now)
        pending = planner.get(0)
        if pending is not None and t_now >= max(pending.ready, pending.start) - 1e-9:
            planner.pop(0)  # (none converged: the orbit from the end of the ramp)
            if pending.plan is not None and pending.late:  # planned again from here, starting from this plan
                self.c.telemetry.plan_late += 1
                self._launch_entry(t_now, pending.plan)
            elif pending.plan is not None:
                plan = pending.plan
                self.reference = Reference([(plan, {})], self._orbit(self._entry(plan.T), plan.extra["phase"]))
                self.segment_start = pending.start
                self.c.step.cold()  # a new reference: its first step starts from it
                self.modes.go(M.ENTRY, k, "the entry is ready and its start has come")
        if self.mode is not M.ORBIT and t_now - self.segment_start > self.reference.segments[0][0].T:
            self.modes.go(M.ORBIT, k, "the ramp has ended" if self.mode is M.RAMP else "the entry has ended")

    def window(self, z, k: int) -> Window:
        s = self.c.settings.horizon
        t_now = k * self.c.dt
        window = self._sample(z, t_now)
        # the distance from the circle counts once on the orbit
        on_orbit = (t_now - self.segment_start + s.h * np.arange(s.N + 1)) > self.reference.segments[0][0].T
        window.mission_weights = self.weights.radial * on_orbit
        return window

    def plans(self) -> list:
        return [seg[0].to_dict() for seg in self.reference.segments if seg is not None] if self.reference else []

    # -- the entry -----------------------------------------------------------------------------------
    def _entry(self, duration: float) -> OrbitEntry:
        """The entry problem onto the mission's orbit in ``duration`` s (least effort; ``entry.interval`` grid)."""
        s = self.c.settings
        intervals = max(2, int(round(duration / s.entry.interval)))
        return _orbit_entry(self.c.mission.orbit.radius, self.c.params.replace(slope=0.0),
                            replace(s.entry.ocp, N=intervals), tuple(s.limits.constraints))

    def _entry_times(self) -> list:
        """The entry durations to try, s: those of ``entry.times`` from the shortest long enough to move the
        robot's revolving centre from the ramp's to the orbit's at ``entry.shift_speed`` (the longest if none
        is).  A shorter entry from a ramp far from the orbit seldom converges, and its failed iterations
        delay the one that would have."""
        e = self.c.settings.entry
        need = self._entry_shift / e.shift_speed
        return [d for d in e.times if d >= need - 1e-9] or [max(e.times)]

    def _orbit(self, entry: OrbitEntry, phase: float) -> dict:
        """The orbit a reference ends on, reached at ``phase`` (rad)."""
        return {"qs": entry.qs_reduced, "centre": self.c.mission.orbit.centre, "phase": phase,
                "Omega": entry.quasi.Omega}

    def _launch_entry(self, t_now: float, late: Plan | None = None) -> None:
        """Plan the entry onto the orbit from where the ramp followed now will be ``entry.handover`` s later, for
        each of the durations of ``_entry_times`` in turn until one converges (first, from a ``late`` entry's
        own duration and solution).  Nothing is planned if the ramp ends before then."""
        s, centre = self.c.settings, self.c.mission.orbit.centre
        ramp = self.reference.segments[0][0]
        handover = t_now - self.segment_start + s.entry.handover
        if handover >= ramp.T:
            return
        z_start = ramp.state(handover)

        def attempt(duration, guess):
            entry = self._entry(duration)
            if guess is None:
                guess = ramp.tail(handover, entry.settings.N, duration)
                guess.extra = {"phase": orbit_phase(guess.z[REDUCED.position, -1], centre, entry.qs_reduced)}
            return entry.solve(z_start, centre, guess=guess, duration=duration)

        tries = ([(late.T, late)] if late is not None else []) + [(duration, None) for duration in self._entry_times()]
        self.c.planner.solve(0, [functools.partial(attempt, *args) for args in tries], t_now,
                             self.segment_start + handover, guessed=(0.0, 0.0))


def _revolving_centre(ramp: Plan, Omega: float) -> np.ndarray:
    """The centre a ramp ends revolving about, m: its mean position over its last revolution (``2 pi / Omega``
    s; the whole ramp if it is shorter)."""
    times = np.linspace(max(ramp.T - 2 * math.pi / abs(Omega), 0.0), ramp.T, 200, endpoint=False)
    return ramp.state(times)[REDUCED.position].mean(axis=1)


@functools.lru_cache(maxsize=8)
def _orbit_entry(radius: float, params: RollbotParams, settings: OCPSettings, constraints: tuple) -> OrbitEntry:
    return OrbitEntry(radius, params, settings, constraints)

