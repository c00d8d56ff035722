"""Offline trajectory optimisation: minimum-time driving-speed profiles over the full dynamics.

Problems (all direct multiple shooting in CasADi, solved by IPOPT):

* ``RestToRest``: from a state (at rest, or moving) to rest at a goal point in
  minimum time;
* ``OrbitEntry``: from a state onto the quasi-stable orbit of a target circle
  (the phase on the orbit is free), in minimum time;
* ``plan_waypoints``: a chain of rest-to-rest legs through a list of stops.

Every problem is an ``OCP`` of the optimal-control layer (``rollbot_oc.ocp``),
the one description the NMPC's tracking problem is also written in: the
reduced (pendulum-frame, 10-state) model, the motor acceleration piecewise
constant on ``N`` intervals of a free (or fixed) duration, and the named
limits of ``planning.rollbot`` with the margins of ``OCPSettings``:
driving speed within ``speed_margin * max_speed``, motor acceleration within
``accel_margin * max_accel``, motor torque within ``torque_margin *
max_torque``, normal force at least ``normal_margin`` times the weight (no
jump) and tangential force within ``friction_margin * mu`` times the normal
force (no slide).  The margins leave room for what the plan's prediction
error and the plant's slope will ask of the feedback.  More constraints
(``constraints``: functions of the ``OCP``) join them in one line.

Initial guesses come from the quasi-stable theory, never zeros
(``planning.guesses``); a solved trajectory is a ``Plan`` (``planning.plan``).

IPOPT uses a limited-memory Hessian here, with the stages and their Jacobians
compiled to C where a compiler exists (``OCPSettings.compiled``): each
iteration costs a fraction of an exact-Hessian one in CasADi's virtual
machine, and it needs no more of them (``benchmarks/bench_nmpc.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from rollbot_oc.model.codegen import compiler
from rollbot_oc.model.dynamics import NZ, REDUCED, to_reduced
from rollbot_oc.model.params import PARAM_INDEX, TILT, RollbotParams
from rollbot_oc.analysis.quasi_stable import RadiusMap, quasi_stable_state
from rollbot_oc.model.rotations import quat_multiply
from rollbot_oc.ocp import OCP, FreeTime, bounded
from rollbot_oc.planning.rollbot import at_rest, robot_limits, rollbot_ocp
from rollbot_oc.planning.guesses import orbit_guess, orbit_phase, quasi_stable_guess, quasi_stable_guesses
from rollbot_oc.planning.plan import Plan, SolveFailed, orbit_state

__all__ = ["OCPSettings", "Plan", "RestToRest", "OrbitEntry", "plan_waypoints",
           "quasi_stable_guess", "quasi_stable_guesses", "orbit_state", "orbit_phase", "orbit_guess", "SolveFailed"]


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
        (``rollbot_oc.model.codegen``, built once and cached on disk): the fastest
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
    expand: bool = True
    compiled: bool = False


class _MinTimeOCP:
    """What the minimum-time problems share, written on the optimal-control layer (``rollbot_oc.ocp``).

    Each problem is one ``OCP``: minimum time plus a little motor effort, the
    named limits of ``planning.rollbot`` with the settings'
    margins, the user's ``constraints``, and the end conditions of the
    subclass (``_end``).  It is transcribed and its IPOPT route built once per
    duration (``None``: free), and solved per leg with the robot's parameter
    vector (the floor's tilt and scaled motor limits in it).
    """

    name = "ocp"

    def __init__(self, params: RollbotParams, settings: OCPSettings | None = None, constraints=()):
        self.params = params
        self.settings = settings or OCPSettings()
        self.constraints = tuple(constraints)
        self._routes = {}  # built when first solved: a circle's entry only ever solves fixed durations

    @property
    def compiled(self) -> bool:
        """Whether the stages are evaluated as compiled C (asked for, and a C compiler exists)."""
        return bool(self.settings.compiled and compiler() is not None)

    def _end(self, ocp: OCP) -> None:
        """Add the problem's end conditions (and its parameters and variables) to ``ocp``."""
        raise NotImplementedError

    def problem(self, duration: float | None = None) -> OCP:
        """The problem as an ``OCP``: free time in ``[T_min, T_max]``, or a fixed ``duration`` (s)."""
        s = self.settings
        ocp = rollbot_ocp(N=s.N, T=FreeTime(guess=min(max(5.0, s.T_min), s.T_max), lower=s.T_min, upper=s.T_max)
                          if duration is None else float(duration), substeps=s.substeps)
        ocp.initial_state()
        ocp.minimize_time()
        ocp.add_cost(s.effort_weight * ocp.control.accel ** 2)
        ocp.subject_to(*robot_limits(ocp, s.torque_margin, s.normal_margin, s.friction_margin, s.speed_margin,
                                     s.accel_margin, self.constraints))
        self._end(ocp)
        return ocp

    def build(self, duration: float | None = None) -> None:
        """Build the IPOPT route of the free-time problem (or of a fixed ``duration``, s) now, instead of at
        its first solve (a controller that must answer quickly builds its routes when it is made)."""
        self._route(duration)

    def _route(self, duration: float | None):
        key = None if duration is None else round(float(duration), 9)
        if key not in self._routes:
            s, compiled = self.settings, self.compiled
            self._routes[key] = self.problem(key).solver(
                "ipopt", hessian="limited-memory" if compiled else s.hessian, max_iter=s.max_iter, tol=1e-6,
                options={"acceptable_tol": 1e-4}, compiled=compiled, expand=s.expand or (s.compiled and not compiled))
        return self._routes[key]

    def _solve(self, z0, parameters: dict, guess: Plan, variables=None, duration: float | None = None, tilt=None,
               motor_scale: float = 1.0, model=None) -> Plan:
        """Solve from a guess; ``duration`` (s) fixes the time (then the effort is what is minimised);
        ``model`` (NP,) is the parameter vector to plan with (a learned model; the parameters' own by default);
        ``tilt`` (2,) replaces its floor tilt vector (an estimated slope); ``motor_scale`` in
        (0, 1] scales the plan's driving-speed and acceleration limits (those of the parameter vector)."""
        if not 0.0 < motor_scale <= 1.0:
            raise ValueError(f"motor_scale = {motor_scale!r} must be in (0, 1]")
        route = self._route(duration)
        layout = route.transcription.layout
        if guess.u.size != self.settings.N:
            guess = guess.resample(self.settings.N)
        w0 = layout.pack(guess.z, guess.u[None, :], [duration or guess.T], variables,
                         template=route.transcription.default_guess())
        p = self.params.vector() if model is None else np.array(model, float)
        if tilt is not None:
            p[TILT] = tilt
        p[PARAM_INDEX["max_speed"]] *= motor_scale
        p[PARAM_INDEX["max_accel"]] *= motor_scale
        sol = route.attempt(w0, x0=z0, p=p, **parameters)
        success = sol.success or sol.status == "Solved_To_Acceptable_Level"
        extra = {name: sol.variable(name).tolist() for name in layout.variables}
        return Plan(sol.times, sol.states, sol.controls[0], sol.T, sol.status, success, sol.iterations,
                    sol.solve_time, extra)


class RestToRest(_MinTimeOCP):
    """Minimum time from a state to rest at a goal point (shell and motor still, balanced on the floor).

    Built once per parameter set, settings and extra constraints; ``solve`` is called per leg.

    Parameters
    ----------
    params : RollbotParams, optional
    settings : OCPSettings, optional
    constraints : sequence of callables
        More path constraints, each a function of the ``OCP`` giving a
        ``Constraint`` (as ``NMPCSettings.constraints``).
    """

    name = "rest_to_rest"

    def __init__(self, params: RollbotParams | None = None, settings: OCPSettings | None = None, constraints=()):
        super().__init__(params or RollbotParams(), settings, constraints)

    def _end(self, ocp: OCP) -> None:
        goal = ocp.parameter("goal", 2)
        tol = self.settings.goal_tolerance
        ocp.subject_to(bounded(-tol, ocp.state.position - goal, tol, "goal"), at="end")
        ocp.subject_to(at_rest(ocp), at="end")

    def solve(self, start, goal, guess: Plan | None = None, duration: float | None = None, tilt=None,
              motor_scale: float = 1.0, model=None) -> Plan:
        """Plan from ``start`` (full state (11,) or reduced (10,)) to rest at ``goal`` (m).

        Minimum time, or with ``duration`` (s) given, the least motor effort in that time.  ``tilt``
        (2,), the floor's tilt vector (in-plane gravity per g), replaces the parameters' slope: the plan
        then ends balanced on that floor.  ``motor_scale`` in (0, 1] scales the plan's driving-speed and
        acceleration limits (a gentler plan, more margin for the feedback).  ``model`` (NP,), the parameter
        vector to plan with (a learned model, with its tilt), replaces the parameters' (``params.vector()``).

        Raises
        ------
        SolveFailed
            If IPOPT does not converge (the failed plan and status are attached).
        """
        z0 = _reduced(start)
        goal = np.asarray(goal, float)
        guess = guess or quasi_stable_guess(z0, goal, self.params, self.settings.N)
        plan = self._solve(z0, {"goal": goal}, guess, duration=duration, tilt=tilt, motor_scale=motor_scale,
                           model=model)
        plan.extra = {"goal": goal.tolist()}
        if not plan.success:
            raise SolveFailed(f"rest-to-rest plan to {goal.tolist()}", plan.status, plan)
        return plan

    def fastest(self, start, goal, starts: int = 3, tilt=None, motor_scale: float = 1.0, model=None,
                resumes: int = 0, quick: float | None = None) -> Plan:
        """The fastest of the minimum-time plans found from the ``starts`` best quasi-stable guesses.

        A minimum-time leg has local optima, and the guess decides which one
        IPOPT finds; a few starts make the result much less a matter of luck.
        If none converges, up to ``resumes`` of them (best guess first, whatever
        their status) are solved again from where their IPOPT stopped, and the
        first of those to converge is the plan: a fresh start from a failed
        iterate (its barrier parameter and quasi-Newton memory reset) often
        converges where the first run stalled with tiny steps
        (``benchmarks/bench_robustness.py`` measures how often).  The plan's
        ``iterations`` and ``solve_time`` are the totals over the starts;
        ``tilt``, ``motor_scale`` and ``model`` as for ``solve``; ``quick`` (m) makes the last start a
        quick profile (``quasi_stable_guesses``).

        Raises
        ------
        SolveFailed
            If no start converges (the last failure's status).
        """
        if starts < 1 or resumes < 0:
            raise ValueError(f"starts = {starts!r} must be at least 1 and resumes = {resumes!r} at least 0")
        z0 = _reduced(start)
        goal = np.asarray(goal, float)
        best, failures, iterations, seconds = None, [], 0, 0.0

        def attempt(guess):
            nonlocal iterations, seconds
            try:
                plan = self.solve(z0, goal, guess=guess, tilt=tilt, motor_scale=motor_scale, model=model)
            except SolveFailed as exc:
                failures.append(exc)
                plan = exc.plan
            iterations += plan.iterations if plan is not None else 0
            seconds += plan.solve_time if plan is not None else 0.0
            return plan if plan is not None and plan.success else None

        for guess in quasi_stable_guesses(z0, goal, self.params, self.settings.N, starts, quick=quick):
            plan = attempt(guess)
            if plan is not None and (best is None or plan.T < best.T):
                best = plan
        if best is None:  # every start failed: resume them, best guess first, until one converges
            for failed in [exc.plan for exc in failures if exc.plan is not None][:resumes]:
                best = attempt(failed)
                if best is not None:
                    break
        if best is None:
            failure = failures[-1]
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
    params, settings, constraints : optional
        As for ``RestToRest``.
    """

    name = "orbit_entry"

    def __init__(self, radius: float, params: RollbotParams | None = None, settings: OCPSettings | None = None,
                 constraints=()):
        params = params or RollbotParams()
        self.radius_map = RadiusMap(params.replace(slope=0.0))
        self.omega0 = float(self.radius_map.omega(radius))
        self.quasi = quasi_stable_state(self.omega0, params.replace(slope=0.0))
        self.qs_reduced = to_reduced(self.quasi.state())
        super().__init__(params, settings, constraints)

    def _end(self, ocp: OCP) -> None:
        phase, centre = ocp.variable("phase"), ocp.parameter("centre", 2)
        target = orbit_state(ca.DM(self.qs_reduced), centre, phase)
        x = ocp.state
        # attitude: the vector part of the relative rotation vanishes (3 independent conditions; equating
        # all four quaternion components would be redundant and spoil the constraint Jacobian's rank)
        q = target[REDUCED.quaternion]
        relative = quat_multiply(ca.vertcat(q[0], -q[1:4]), x.quaternion)[1:4]
        ocp.subject_to(x.position == target[REDUCED.position], relative == 0, x.velocity == target[REDUCED.velocity], at="end",
                       name="on the orbit")

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
            guess, phase = orbit_guess(z0, centre, self)
        else:
            phase = guess.extra.get("phase", 0.0)
        plan = self._solve(z0, {"centre": centre}, guess, {"phase": phase}, duration=duration)
        plan.extra = {"phase": float(np.ravel(plan.extra["phase"])[0]), "centre": centre.tolist(),
                      "omega0": self.omega0, "Omega": self.quasi.Omega}
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


def plan_waypoints(start, stops, params: RollbotParams | None = None, settings: OCPSettings | None = None,
                   ocp: RestToRest | None = None, starts: int = 3, resumes: int = 0) -> list[Plan]:
    """Minimum-time rest-to-rest legs through ``stops`` (m), each starting where the previous plan ends,
    each the fastest from ``starts`` guesses, with up to ``resumes`` failed starts solved again from where
    they stopped if none converges (``RestToRest.fastest``).

    Raises
    ------
    SolveFailed
        If a leg cannot be planned (the leg is named).
    """
    ocp = ocp or RestToRest(params, settings)
    z = _reduced(start)
    plans = []
    for stop in stops:
        plan = ocp.fastest(z, stop, starts, resumes=resumes)
        plans.append(plan)
        z = plan.z[:, -1].copy()
        z[REDUCED.velocity] = 0.0  # the leg ends at rest
    return plans

