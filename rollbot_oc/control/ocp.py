"""Offline trajectory optimisation: minimum-time driving-speed profiles over the full dynamics.

Problems (all direct multiple shooting in CasADi, solved by IPOPT):

* ``RestToRest``: from a state (at rest, or moving) to rest at a goal point in
  minimum time;
* ``OrbitEntry``: from a state onto the quasi-stable orbit of a target circle
  (the phase on the orbit is free), in minimum time;
* ``plan_waypoints``: a chain of rest-to-rest legs through a list of stops.

Transcription.  The prediction model is the reduced (pendulum-frame, 10-state)
form of the full equations of motion (``dynamics.reduced_model``); the control
is the motor acceleration, piecewise constant on ``N`` intervals of length
``T / N`` with ``T`` a decision variable; each interval is integrated by RK4
with ``substeps`` steps.  The stage Function (gap, torque, contact margins) is
built in SX once and mapped over the horizon (``Function.map``), which keeps
the NLP small to build (a fraction of a second) and lets CasADi's AD give
exact Jacobians.  Constraints at every node: driving speed within
``speed_margin * max_speed``, motor acceleration within ``max_accel``, motor
torque within ``torque_margin * max_torque``, normal force at least
``normal_margin`` times the weight (no jump) and tangential force within
``friction_margin * mu`` times the normal force (no slide).  The margins leave
room for what the plan's 5 to 15 cm/s of prediction error and the plant's
slope will ask of the feedback.

Initial guesses come from the quasi-stable theory, never zeros: a search over
trapezoidal driving-speed profiles (ramp up, hold, ramp down) whose
quasi-stable kinematics (revolving rate and radius from ``RadiusMap``) end
nearest the goal, then the best few simulated in the full plant, whose
trajectory seeds every node.

IPOPT uses a limited-memory Hessian here: on these problems each iteration
costs a fraction of an exact-Hessian one and it needs no more of them (a
1.2 m leg: 2.3 s and 54 iterations, against 8.1 s and 80 with the exact
Hessian; ``benchmarks/bench_nmpc.py``).
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from rollbot_oc.codegen import compiled
from rollbot_oc.errors import NotConverged, interruptible
from rollbot_oc.dynamics import NW, NZ, from_reduced, imbalance, reduced_model, rk4, to_reduced
from rollbot_oc.params import NP, TILT, ParamView, RollbotParams
from rollbot_oc.quasi_stable import RadiusMap, quasi_stable_state
from rollbot_oc.rotations import quat_multiply
from rollbot_oc.simulate import simulate

__all__ = ["OCPSettings", "Plan", "RestToRest", "OrbitEntry", "plan_waypoints", "interval_function",
           "stage_function", "quasi_stable_guess", "quasi_stable_guesses", "orbit_state", "SolveFailed"]

_W0 = ca.DM.zeros(NW)


class SolveFailed(NotConverged):
    """An optimisation did not converge; carries its solver status and the failed plan."""

    def __init__(self, what: str, status: str, plan=None):
        super().__init__(what, status, plan)
        self.plan = plan


@dataclass(frozen=True)
class OCPSettings:
    """Transcription and safety margins of the optimal-control problems.

    Attributes
    ----------
    N : int
        Shooting intervals.
    substeps : int
        RK4 steps per interval.
    torque_margin, speed_margin : float
        Fractions of the motor's torque and speed limits the plan may use.
    normal_margin : float
        Least normal force, as a fraction of the robot's weight.
    friction_margin : float
        Largest tangential force, as a fraction of ``mu`` times the normal force.
    goal_tolerance : float
        Half-width of the box around the goal the plan must end in, m.
    effort_weight : float
        Weight of the integral of the squared motor acceleration (regularisation), s^3/rad^2.
    T_min, T_max : float
        Bounds on the plan's duration, s.
    max_iter : int
        IPOPT iteration limit.
    hessian : {"limited-memory", "exact"}
        IPOPT's Hessian of the Lagrangian (see module doc).
    accel_margin : float
        Fraction of the motor's acceleration limit the plan may use (the rest
        is left to a feedback that tracks it).
    expand : bool
        Build the NLP from scalar expressions (CasADi's ``expand``): slower to
        build once, faster to solve.
    compiled : bool
        Evaluate the stage constraints and their Jacobian as compiled C
        (``rollbot_oc.codegen``, built once and cached on disk): the fastest
        solves; without a C compiler, the same as ``expand``.
    """

    N: int = 60
    substeps: int = 2
    torque_margin: float = 0.9
    speed_margin: float = 0.95
    normal_margin: float = 0.3
    friction_margin: float = 0.8
    goal_tolerance: float = 0.005
    effort_weight: float = 1e-4
    T_min: float = 0.5
    T_max: float = 60.0
    max_iter: int = 400
    hessian: str = "limited-memory"
    accel_margin: float = 1.0
    expand: bool = False
    compiled: bool = False


@functools.lru_cache(maxsize=None)
def interval_function(substeps: int) -> ca.Function:
    """``(z, u, h, p) -> z(h)``: RK4 over one interval of the reduced model, input held, no external wrench."""
    red = reduced_model()
    z, u, h, p = ca.SX.sym("z", NZ), ca.SX.sym("u"), ca.SX.sym("h"), ca.SX.sym("p", NP)
    z_next = rk4(red.f, z, h, substeps, u, p, _W0)
    return ca.Function("rk4_interval", [z, u, h, p], [z_next], ["z", "u", "h", "p"], ["z_next"])


@functools.lru_cache(maxsize=None)
def stage_function(substeps: int, friction_margin: float) -> ca.Function:
    """``(z, u, z_next, h, p) -> (gap (10), torque, normal force, friction slack)`` of one interval.

    The friction slack ``friction_margin * mu * N_z - |N_t|`` is written smoothly as
    ``(friction_margin mu N_z)^2 - |N_t|^2`` (with ``N_z > 0`` imposed alongside).
    """
    red, F = reduced_model(), interval_function(substeps)
    z, u, zn, h, p = ca.SX.sym("z", NZ), ca.SX.sym("u"), ca.SX.sym("zn", NZ), ca.SX.sym("h"), ca.SX.sym("p", NP)
    N = red.reaction(z, u, p, _W0)
    slack = (friction_margin * ParamView(p).mu * N[2]) ** 2 - N[0] ** 2 - N[1] ** 2
    return ca.Function("stage", [z, u, zn, h, p],
                       [ca.vertcat(zn - F(z, u, h, p), red.motor_torque(z, u, p, _W0), N[2], slack)],
                       ["z", "u", "z_next", "h", "p"], ["g"])


@functools.lru_cache(maxsize=None)
def _compiled_stage(substeps: int, friction_margin: float) -> ca.Function | None:
    """``stage_function`` and its AD Jacobian as compiled C (loaded once per process), or None without a compiler."""
    stage = stage_function(substeps, friction_margin)
    fast = compiled(stage, jacobian=True)
    return fast if fast is not stage else None


def orbit_state(qs_reduced, centre, phase):
    """The reduced quasi-stable state ``qs_reduced`` (revolving about the origin) turned by ``phase`` about ``centre``.

    Works on CasADi symbols and on numbers.
    """
    c, s = ca.cos(phase), ca.sin(phase)
    rot = ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))
    pos = ca.mtimes(rot[0:2, 0:2], qs_reduced[0:2]) + centre
    quat = quat_multiply(ca.vertcat(ca.cos(phase / 2), 0, 0, ca.sin(phase / 2)), qs_reduced[2:6])
    return ca.vertcat(pos, quat, ca.mtimes(rot, qs_reduced[6:9]), qs_reduced[9])


@dataclass
class Plan:
    """A solved trajectory (SI units): node times, reduced states and the motor-acceleration profile.

    Attributes
    ----------
    t : numpy.ndarray (N+1,)
        Node times, s (from 0).
    z : numpy.ndarray (10, N+1)
        Reduced states at the nodes.
    u : numpy.ndarray (N,)
        Motor acceleration on each interval, rad/s^2.
    T : float
        Duration, s.
    status : str
        Solver status.
    success : bool
    iterations : int
    solve_time : float
        Wall-clock time of the solve, s.
    extra : dict
        Problem-specific results (for example the orbit phase).
    """

    t: np.ndarray
    z: np.ndarray
    u: np.ndarray
    T: float
    status: str
    success: bool
    iterations: int
    solve_time: float
    extra: dict = field(default_factory=dict)

    def accel(self, t: float) -> float:
        """Planned motor acceleration at time ``t`` (s), rad/s^2; 0 after the end."""
        if t >= self.T or t < 0:
            return 0.0
        # a time on a node belongs to the interval it starts (guard against 0.3 / 0.1 = 2.999...)
        return float(self.u[min(int(math.floor(t / (self.T / len(self.u)) + 1e-9)), len(self.u) - 1)])

    def state(self, t) -> np.ndarray:
        """Planned reduced state at time(s) ``t`` (s), linear between nodes (quaternions renormalised)."""
        t = np.clip(np.asarray(t, float), 0.0, self.T)
        out = np.array([np.interp(t, self.t, row) for row in self.z])
        q = out[2:6]
        out[2:6] = q / np.linalg.norm(q, axis=0)
        return out

    def resample(self, N: int) -> "Plan":
        """The same trajectory on ``N`` equal intervals (states interpolated, accelerations at interval midpoints)."""
        return self.tail(0.0, N)

    def tail(self, t0: float, N: int) -> "Plan":
        """The rest of the trajectory from time ``t0`` (s) on, on ``N`` equal intervals, its time from 0."""
        t0 = min(max(float(t0), 0.0), self.T)
        T = max(self.T - t0, 1e-3)
        t = np.linspace(0.0, T, N + 1)
        u = np.array([self.accel(t0 + tm) for tm in 0.5 * (t[1:] + t[:-1])])
        return Plan(t, self.state(t0 + t), u, T, self.status, self.success, self.iterations, self.solve_time,
                    dict(self.extra))

    @property
    def driving_speed(self) -> np.ndarray:
        """Planned driving speed at the nodes, rad/s."""
        return self.z[9]

    def to_dict(self) -> dict:
        """Summary for JSON."""
        return {"T": self.T, "status": self.status, "success": self.success, "iterations": self.iterations,
                "solve_time": self.solve_time, "end": self.z[:2, -1].tolist(), **self.extra}


class _MinTimeOCP:
    """Shared machinery of the minimum-time problems: variables, stage constraints, bounds, solve."""

    name = "ocp"

    def __init__(self, params: RollbotParams, settings: OCPSettings | None = None):
        self.params = params
        self.settings = s = settings or OCPSettings()
        N = s.N
        stage = _compiled_stage(s.substeps, s.friction_margin) if s.compiled else None
        self.compiled = stage is not None
        stage = (stage or stage_function(s.substeps, s.friction_margin)).map(N)
        self.Z, self.U, self.Tv = ca.MX.sym("Z", NZ, N + 1), ca.MX.sym("U", 1, N), ca.MX.sym("T")
        self.z0, self.pp = ca.MX.sym("z0", NZ), ca.MX.sym("p", NP)
        gs = stage(self.Z[:, :-1], self.U, self.Z[:, 1:], self.Tv / N, self.pp)
        weight = params.total_mass * params.g
        tau = s.torque_margin * params.max_torque
        self.g = [self.Z[:, 0] - self.z0, ca.vec(gs)]
        self.lbg = [np.zeros(NZ), np.tile(np.concatenate([np.zeros(NZ), [-tau, s.normal_margin * weight, 0.0]]), N)]
        self.ubg = [np.zeros(NZ), np.tile(np.concatenate([np.zeros(NZ), [tau, np.inf, np.inf]]), N)]
        self.extra_vars, self.extra_params = [], []
        self.cost = self.Tv + s.effort_weight * ca.sumsqr(self.U) * self.Tv / N

    def _finish(self):
        """Assemble and build the solver (once)."""
        s, N, params = self.settings, self.settings.N, self.params
        x = ca.vertcat(ca.vec(self.Z), ca.vec(self.U), self.Tv, *self.extra_vars)
        n = x.shape[0]
        lbx, ubx = np.full(n, -np.inf), np.full(n, np.inf)
        speed = s.speed_margin * params.max_speed
        lbx[9:NZ * (N + 1):NZ], ubx[9:NZ * (N + 1):NZ] = -speed, speed
        iu = NZ * (N + 1)
        accel = s.accel_margin * params.max_accel
        lbx[iu:iu + N], ubx[iu:iu + N] = -accel, accel
        lbx[iu + N], ubx[iu + N] = s.T_min, s.T_max
        self.bounds = dict(lbx=lbx, ubx=ubx, lbg=np.concatenate(self.lbg), ubg=np.concatenate(self.ubg))
        nlp = {"x": x, "p": ca.vertcat(self.z0, self.pp, *self.extra_params), "f": self.cost, "g": ca.vertcat(*self.g)}
        opts = {"ipopt": {"max_iter": s.max_iter, "print_level": 0, "sb": "yes", "tol": 1e-6, "acceptable_tol": 1e-4,
                          "hessian_approximation": s.hessian}, "print_time": False,
                "expand": s.expand or (s.compiled and not self.compiled)}
        self.solver = ca.nlpsol(self.name, "ipopt", nlp, opts)
        self.n_extra = n - (iu + N + 1)

    def _solve(self, z0, p_extra, guess: Plan, guess_extra=(), duration: float | None = None, tilt=None,
               motor_scale: float = 1.0) -> Plan:
        """Solve from a guess; ``duration`` (s) fixes the time (then the effort is what is minimised);
        ``tilt`` (2,) replaces the parameters' floor tilt vector (an estimated slope); ``motor_scale`` in
        (0, 1] scales the plan's driving-speed and acceleration limits."""
        N = self.settings.N
        if guess.u.size != N:
            guess = guess.resample(N)
        x0 = np.concatenate([np.asarray(guess.z).T.ravel(), guess.u, [duration or guess.T], guess_extra])
        bounds = dict(self.bounds)
        bounds["lbx"], bounds["ubx"] = bounds["lbx"].copy(), bounds["ubx"].copy()
        if duration is not None:
            i_T = NZ * (N + 1) + N
            bounds["lbx"][i_T] = bounds["ubx"][i_T] = duration
        if motor_scale != 1.0:
            if not 0.0 < motor_scale <= 1.0:
                raise ValueError(f"motor_scale = {motor_scale!r} must be in (0, 1]")
            motor = np.r_[9:NZ * (N + 1):NZ, NZ * (N + 1):NZ * (N + 1) + N]  # driving speeds, accelerations
            bounds["lbx"][motor] *= motor_scale
            bounds["ubx"][motor] *= motor_scale
        p = self.params.vector()
        if tilt is not None:
            p[TILT] = tilt
        start = time.perf_counter()
        with interruptible(self.name):
            sol = self.solver(x0=x0, p=np.concatenate([z0, p, p_extra]), **bounds)
        elapsed = time.perf_counter() - start
        stats = self.solver.stats()
        x = np.array(sol["x"]).ravel()
        z = x[:NZ * (N + 1)].reshape(N + 1, NZ).T
        u = x[NZ * (N + 1):NZ * (N + 1) + N]
        T = float(x[NZ * (N + 1) + N])
        status = stats["return_status"]
        success = bool(stats["success"]) or status == "Solved_To_Acceptable_Level"
        return Plan(np.linspace(0.0, T, N + 1), z, u, T, status, success, int(stats["iter_count"]), elapsed,
                    {"extra": x[NZ * (N + 1) + N + 1:].tolist()})


class RestToRest(_MinTimeOCP):
    """Minimum time from a state to rest at a goal point (pendulum down, shell and motor still).

    Built once per parameter set and settings; ``solve`` is called per leg.
    """

    name = "rest_to_rest"

    def __init__(self, params: RollbotParams | None = None, settings: OCPSettings | None = None):
        super().__init__(params or RollbotParams(), settings)
        s = self.settings
        self.goal = ca.MX.sym("goal", 2)
        zN = self.Z[:, -1]
        self.g += [zN[0:2] - self.goal, zN[6:10], imbalance(zN[2:6], self.pp)]
        tol = s.goal_tolerance
        self.lbg += [np.full(2, -tol), np.zeros(4), np.zeros(2)]
        self.ubg += [np.full(2, tol), np.zeros(4), np.zeros(2)]
        self.extra_params = [self.goal]
        self._finish()

    def solve(self, start, goal, guess: Plan | None = None, duration: float | None = None, tilt=None,
              motor_scale: float = 1.0) -> Plan:
        """Plan from ``start`` (full state (11,) or reduced (10,)) to rest at ``goal`` (m).

        Minimum time, or with ``duration`` (s) given, the least motor effort in that time.  ``tilt``
        (2,), the floor's tilt vector (in-plane gravity per g), replaces the parameters' slope: the plan
        then ends balanced on that floor.  ``motor_scale`` in (0, 1] scales the plan's driving-speed and
        acceleration limits (a gentler plan, more margin for the feedback).

        Raises
        ------
        SolveFailed
            If IPOPT does not converge (the failed plan and status are attached).
        """
        z0 = _reduced(start)
        goal = np.asarray(goal, float)
        guess = guess or quasi_stable_guess(z0, goal, self.params, self.settings.N)
        plan = self._solve(z0, goal, guess, duration=duration, tilt=tilt, motor_scale=motor_scale)
        plan.extra = {"goal": goal.tolist()}
        if not plan.success:
            raise SolveFailed(f"rest-to-rest plan to {goal.tolist()}", plan.status, plan)
        return plan


    def fastest(self, start, goal, starts: int = 3, tilt=None, motor_scale: float = 1.0) -> Plan:
        """The fastest of the minimum-time plans found from the ``starts`` best quasi-stable guesses.

        A minimum-time leg has local optima, and the guess decides which one
        IPOPT finds; a few starts make the result much less a matter of luck.
        The plan's ``iterations`` and ``solve_time`` are the totals over the
        starts; ``tilt`` and ``motor_scale`` as for ``solve``.

        Raises
        ------
        SolveFailed
            If no start converges (the last failure's status).
        """
        z0 = _reduced(start)
        goal = np.asarray(goal, float)
        best, failure, iterations, seconds = None, None, 0, 0.0
        for guess in quasi_stable_guesses(z0, goal, self.params, self.settings.N, starts):
            try:
                plan = self.solve(z0, goal, guess=guess, tilt=tilt, motor_scale=motor_scale)
            except SolveFailed as exc:
                failure, plan = exc, exc.plan
            iterations += plan.iterations if plan is not None else 0
            seconds += plan.solve_time if plan is not None else 0.0
            if plan is not None and plan.success and (best is None or plan.T < best.T):
                best = plan
        if best is None:
            failure.plan.iterations, failure.plan.solve_time = iterations, seconds
            raise failure
        best.iterations, best.solve_time = iterations, seconds
        return best


class OrbitEntry(_MinTimeOCP):
    """Minimum time from a state onto the quasi-stable orbit of a circle (free phase on the orbit).

    Parameters
    ----------
    radius : float
        Target revolving radius, m (on the slow branch).
    params, settings : optional
    """

    name = "orbit_entry"

    def __init__(self, radius: float, params: RollbotParams | None = None, settings: OCPSettings | None = None):
        params = params or RollbotParams()
        super().__init__(params, settings)
        self.radius_map = RadiusMap(params.replace(slope=0.0))
        self.omega0 = float(self.radius_map.omega(radius))
        self.quasi = quasi_stable_state(self.omega0, params.replace(slope=0.0))
        self.qs_reduced = to_reduced(self.quasi.state())
        self.phase = ca.MX.sym("phase")
        self.centre = ca.MX.sym("centre", 2)
        target = orbit_state(ca.DM(self.qs_reduced), self.centre, self.phase)
        zN = self.Z[:, -1]
        # attitude: the vector part of the relative rotation vanishes (3 independent conditions; equating
        # all four quaternion components would be redundant and spoil the constraint Jacobian's rank)
        conj = ca.vertcat(target[2], -target[3:6])
        relative = quat_multiply(conj, zN[2:6])[1:4]
        self.g += [zN[0:2] - target[0:2], relative, zN[6:10] - target[6:10]]
        self.lbg += [np.zeros(9)]
        self.ubg += [np.zeros(9)]
        self.extra_vars, self.extra_params = [self.phase], [self.centre]
        self._finish()

    def solve(self, start, centre, guess: Plan | None = None, duration: float | None = None) -> Plan:
        """Plan from ``start`` onto the orbit about ``centre`` (m); the plan's ``extra['phase']`` (rad) says where.

        Minimum time, or with ``duration`` (s) given, the least motor effort in that time.

        Raises
        ------
        SolveFailed
        """
        z0 = _reduced(start)
        centre = np.asarray(centre, float)
        if guess is None:
            guess, phase = _orbit_guess(z0, centre, self)
        else:
            phase = guess.extra.get("phase", 0.0)
        plan = self._solve(z0, centre, guess, [phase], duration=duration)
        plan.extra = {"phase": plan.extra["extra"][0], "centre": centre.tolist(), "omega0": self.omega0,
                      "Omega": self.quasi.Omega}
        if not plan.success:
            raise SolveFailed(f"orbit entry about {centre.tolist()}", plan.status, plan)
        return plan


def _reduced(state) -> np.ndarray:
    state = np.asarray(state, float).ravel()
    if state.shape == (NZ + 1,):
        return to_reduced(state)
    if state.shape != (NZ,):
        raise ValueError(f"start state has {state.size} entries; expected 11 (full) or 10 (reduced)")
    return state


def _from_simulation(run, N: int, T: float) -> tuple[np.ndarray, np.ndarray]:
    """Node states and interval accelerations of a simulated run, resampled on ``N`` intervals over ``T``."""
    t_nodes = np.linspace(0.0, T, N + 1)
    idx = np.minimum(np.round(t_nodes / run.dt).astype(int), run.x.shape[1] - 1)
    z = np.array([to_reduced(run.x[:, k]) for k in idx]).T
    u = np.array([run.applied_accel[min(k, run.applied_accel.size - 1)] for k in idx[:-1]])
    return z, u


def _trapezoids(accels=(2.0, 4.0, 8.0), speeds=np.linspace(1.0, 9.0, 17), holds=np.linspace(0.0, 12.0, 25)):
    for a in accels:
        for w in speeds:
            for sign in (1.0, -1.0):
                for hold in holds:
                    yield a, sign * w, hold


def _quasi_rest_points(s0, heading, radius_map, dt=0.05):
    """Quasi-stable end points of every trapezoidal speed profile, vectorised over profiles."""
    cands = np.array(list(_trapezoids()))
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


def quasi_stable_guess(z0, goal, params: RollbotParams, N: int, keep: int = 6) -> Plan:
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
    """
    return quasi_stable_guesses(z0, goal, params, N, 1, keep)[0]


def quasi_stable_guesses(z0, goal, params: RollbotParams, N: int, count: int, keep: int = 6) -> list[Plan]:
    """The ``count`` best guesses of ``quasi_stable_guess``, best first: starts for a multi-start solve
    (a minimum-time leg has local optima, and the guess decides which one the solver finds)."""
    from rollbot_oc.simulate import heading as heading_of

    level = params.replace(slope=0.0)
    radius_map = _radius_map(level)
    x0 = from_reduced(z0)
    goal = np.asarray(goal, float)
    cands, ends, totals = _quasi_rest_points(np.asarray(z0[:2], float), float(heading_of(x0)), radius_map)
    score = np.linalg.norm(ends - goal[:, None], axis=0) + 0.01 * totals
    runs = []
    for i in np.argsort(score)[:max(keep, count)]:
        a, w, hold = cands[i]
        ramp = abs(w) / a
        total = 2 * ramp + hold

        def profile(t, a=a, w=w, total=total):
            return math.copysign(max(0.0, min(a * t, abs(w), a * (total - t))), w)

        run = simulate(x0, total + 1.0, params=level, speed=profile, stop_on_event=False)
        runs.append((float(np.linalg.norm(run.position[:, -1] - goal)) + 0.01 * total, run, total + 1.0))
    runs.sort(key=lambda r: r[0])
    plans = []
    for miss, run, T in runs[:count]:
        z, u = _from_simulation(run, N, T)
        plans.append(Plan(np.linspace(0.0, T, N + 1), z, u, T, "guess", True, 0, 0.0, {"miss": miss}))
    return plans


@functools.lru_cache(maxsize=8)
def _radius_map(params: RollbotParams) -> RadiusMap:
    return RadiusMap(params)


def _orbit_guess(z0, centre, ocp: OrbitEntry) -> tuple[Plan, float]:
    """Guess for an orbit entry: ramp the driving speed up to the orbit's speed and look where that lands."""
    level = ocp.params.replace(slope=0.0)
    accel = 4.0
    T = ocp.omega0 / accel + 1.0
    run = simulate(from_reduced(z0), T, params=level, speed=lambda t: min(ocp.omega0, accel * t), stop_on_event=False)
    z, u = _from_simulation(run, ocp.settings.N, T)
    # phase: the orbit point whose position is nearest where the ramp ended
    rel = run.position[:, -1] - centre
    phase = math.atan2(rel[1], rel[0]) - math.atan2(ocp.qs_reduced[1], ocp.qs_reduced[0])
    return Plan(np.linspace(0.0, T, ocp.settings.N + 1), z, u, T, "guess", True, 0, 0.0), phase


def plan_waypoints(start, stops, params: RollbotParams | None = None, settings: OCPSettings | None = None,
                   ocp: RestToRest | None = None, starts: int = 3) -> list[Plan]:
    """Minimum-time rest-to-rest legs through ``stops`` (m), each starting where the previous plan ends,
    each the fastest from ``starts`` guesses (``RestToRest.fastest``).

    Raises
    ------
    SolveFailed
        If a leg cannot be planned (the leg is named).
    """
    ocp = ocp or RestToRest(params, settings)
    z = _reduced(start)
    plans = []
    for stop in stops:
        plan = ocp.fastest(z, stop, starts)
        plans.append(plan)
        z = plan.z[:, -1].copy()
        z[6:10] = 0.0  # the leg ends at rest
    return plans

