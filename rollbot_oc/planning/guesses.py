"""Initial guesses from the quasi-stable theory, never zeros: for rest-to-rest legs and orbit entries.

A leg's guess comes from a search over trapezoidal driving-speed profiles (ramp up, hold, ramp down) whose
quasi-stable kinematics (revolving rate and radius from ``RadiusMap``) end nearest the goal, then the best
few simulated in the full plant, whose trajectory seeds every node.  An orbit entry's guess ramps the
driving speed up to the orbit's speed.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from rollbot_oc.planning.plan import Plan
from rollbot_oc.model.dynamics import from_reduced, to_reduced
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.analysis.quasi_stable import RadiusMap
from rollbot_oc.core.reproducible import norm
from rollbot_oc.model.dynamics import heading as heading_of
from rollbot_oc.simulation.plant import simulate

__all__ = ["GUESS_ACCELS", "quasi_stable_guess", "quasi_stable_guesses", "orbit_phase", "orbit_guess"]


def _from_simulation(run, N: int, T: float) -> tuple[np.ndarray, np.ndarray]:
    """Node states and interval accelerations of a simulated run, resampled on ``N`` intervals over ``T``."""
    t_nodes = np.linspace(0.0, T, N + 1)
    idx = np.minimum(np.round(t_nodes / run.dt).astype(int), run.x.shape[1] - 1)
    z = np.array([to_reduced(run.x[:, k]) for k in idx]).T
    u = np.array([run.applied_accel[min(k, run.applied_accel.size - 1)] for k in idx[:-1]])
    return z, u


GUESS_ACCELS = (2.0, 4.0, 8.0)  # ramp rates of the quasi-stable guesses' speed profiles, rad/s^2


def _trapezoids(accels=GUESS_ACCELS, speeds=np.linspace(1.0, 9.0, 17), holds=np.linspace(0.0, 12.0, 25)):
    for a in accels:
        for w in speeds:
            for sign in (1.0, -1.0):
                for hold in holds:
                    yield a, sign * w, hold


def _quasi_rest_points(s0, heading, radius_map, dt=0.05, accels=GUESS_ACCELS):
    """Quasi-stable end points of every trapezoidal speed profile (ramping at ``accels``, rad/s^2), vectorised
    over profiles."""
    cands = np.array(list(_trapezoids(tuple(accels))))
    acc, wc, hold = cands.T
    ramp = np.abs(wc) / acc
    total = 2 * ramp + hold
    t = np.arange(0.0, total.max() + dt, dt)[None, :]
    speed = np.clip(np.minimum(acc[:, None] * t, (acc * (total))[:, None] - acc[:, None] * t), 0.0, None)
    speed = np.minimum(speed, np.abs(wc)[:, None])
    rate = np.sign(wc)[:, None] * radius_map.rate(speed)
    vel = rate * radius_map.radius(speed)
    angle = heading + np.cumsum(rate, axis=1) * dt
    pos = s0[:, None] + np.stack([np.sum(-vel * np.sin(angle), axis=1), np.sum(vel * np.cos(angle), axis=1)]) * dt
    return cands, pos, total


def quasi_stable_guess(z0, goal, params: RollbotParams, N: int, keep: int = 6, accels=GUESS_ACCELS) -> Plan:
    """An initial guess for a rest-to-rest plan, from the quasi-stable theory (see module doc).

    Parameters
    ----------
    z0 : array_like (10,)
        Reduced start state (at rest or nearly).
    goal : array_like (2,)
        Goal point, m.
    params : RollbotParams
    N : int
        Intervals of the plan.
    keep : int
        How many of the best quasi-stable candidates to simulate in the full plant.
    accels : sequence of float
        Ramp rates of the trapezoidal driving-speed profiles tried, rad/s^2 (``GUESS_ACCELS``).
    """
    return quasi_stable_guesses(z0, goal, params, N, 1, keep, accels)[0]


def quasi_stable_guesses(z0, goal, params: RollbotParams, N: int, count: int, keep: int = 6,
                         accels=GUESS_ACCELS, quick: float | None = None) -> list[Plan]:
    """The ``count`` best guesses of ``quasi_stable_guess``, best first: starts for a multi-start solve
    (a minimum-time leg has local optima, and the guess decides which one the solver finds).

    ``quick`` (m), if given and ``count`` is at least 2: the last of the guesses is instead the shortest
    of the other simulated ones whose score (miss plus 0.01 m per second of profile) is within ``quick``
    of the best's.  Ranked by score, the best few are often long profiles that revolve on the way, from
    which the solver finds slow local optima; a quick profile that misses by more often converges to a
    much faster leg.
    """
    level = params.replace(slope=0.0)
    radius_map = _radius_map(level)
    x0 = from_reduced(z0)
    goal = np.asarray(goal, float)
    cands, ends, totals = _quasi_rest_points(np.asarray(z0[:2], float), float(heading_of(x0)), radius_map,
                                             accels=accels)
    score = np.linalg.norm(ends - goal[:, None], axis=0) + 0.01 * totals
    runs = []
    for i in np.argsort(score)[:max(keep, count)]:
        a, w, hold = cands[i]
        ramp = abs(w) / a
        total = 2 * ramp + hold

        def profile(t, a=a, w=w, total=total):
            return math.copysign(max(0.0, min(a * t, abs(w), a * (total - t))), w)

        run = simulate(x0, total + 1.0, params=level, speed=profile, stop_on_event=False)
        runs.append((float(norm(run.position[:, -1] - goal)) + 0.01 * total, run, total + 1.0))
    runs.sort(key=lambda r: r[0])
    if quick is not None and count >= 2:
        others = [r for r in runs[count - 1:] if r[0] <= runs[0][0] + quick]
        if others:
            runs[count - 1] = min(others, key=lambda r: r[2])
    plans = []
    for miss, run, T in runs[:count]:
        z, u = _from_simulation(run, N, T)
        plans.append(Plan(np.linspace(0.0, T, N + 1), z, u, T, "guess", True, 0, 0.0, {"miss": miss}))
    return plans


@functools.lru_cache(maxsize=8)
def _radius_map(params: RollbotParams) -> RadiusMap:
    return RadiusMap(params)


def orbit_phase(position, centre, qs_reduced) -> float:
    """The phase (rad) of the orbit point about ``centre`` (m) nearest ``position`` (m), for the quasi-stable
    state ``qs_reduced`` (10,) that ``orbit_state`` turns."""
    rel = np.asarray(position, float) - np.asarray(centre, float)
    return math.atan2(rel[1], rel[0]) - math.atan2(qs_reduced[1], qs_reduced[0])


def orbit_guess(z0, centre, ocp, hold: float = 1.0) -> tuple[Plan, float]:
    """Guess for an orbit entry: ramp the driving speed up to the orbit's speed (4 rad/s^2), hold it ``hold``
    seconds (a simulation of the model), and the orbit phase nearest where that ends (rad).  ``ocp``: the
    ``OrbitEntry`` the guess is for."""
    level = ocp.params.replace(slope=0.0)
    accel = 4.0
    T = ocp.omega0 / accel + hold
    run = simulate(from_reduced(z0), T, params=level, speed=lambda t: min(ocp.omega0, accel * t), stop_on_event=False)
    z, u = _from_simulation(run, ocp.settings.N, T)
    plan = Plan(np.linspace(0.0, T, ocp.settings.N + 1), z, u, T, "guess", True, 0, 0.0)
    return plan, orbit_phase(run.position[:, -1], centre, ocp.qs_reduced)
