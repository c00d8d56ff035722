"""Nonlinear MPC: track minimum-time plans over the full dynamics, in real time, offset-free on a slope.

Structure (do-mpc's separation: model, controller, simulator over one model):

* **Plans** (``control.ocp``), computed as the robot moves: for stops, the
  first leg starts at once on its quasi-stable guess (a simulation of the
  model, a fraction of a second); once the tilt estimate has settled
  (``tilt_settle``) a minimum-time leg is refined from where the guess will be
  ``plan_handover`` later, and takes over there if it is ready by then (else
  it is planned again from further along).  Every later leg is planned
  during the one before (the fastest of ``plan_starts`` starts, from the rest
  state the leg ends in, on the tilt estimated by then) and is used only once
  its modelled compute time has passed; legs end balanced on the estimated
  floor.
* **Recovery**: a robot pushed off its plan is first brought to rest where
  it is (the tracking NMPC with ``brake_weights``: motion only), then gets a
  new leg from there, as at the start.  For circles, before the run: an entry onto the
  quasi-stable orbit of the target circle in a fixed time (5 s, else 7 or
  10 s) with the least effort, then the orbit itself.
* **Tracking NMPC**: every ``h = 0.1`` s it solves a multiple-shooting
  problem over ``N = 30`` intervals (3 s, about half a revolution period and
  half the 7 s recovery time) that keeps the predicted reduced state near the
  plan, with the motor's torque, speed and acceleration limits and the
  contact margins as constraints.  The first interval's motor acceleration
  is applied (the plant's motor follows it at 100 Hz).
* **Offset-free**: a Kalman filter estimates the floor's tilt vector from the
  mismatch between the measured and the predicted shell angular velocity
  (its Jacobian by AD); the prediction model uses the estimate.  It absorbs
  the slope and, with them, other steady model errors (masses, damping).
* **Delay compensation**: a measurement that is ``L`` periods old is
  predicted forward over the commands applied since.
* **Warm start**: the previous solution shifted by one interval (primal and,
  for IPOPT, dual values).
* **Never crash the loop**: a QP made infeasible by the state (no command
  keeps the torque or contact limits) is solved once more without the path
  constraints (status ``relaxed (...)``); a failed or late solve (longer than
  ``h``) falls back to the shifted previous solution; after ``max_failures``
  consecutive failures the motor's speed is ramped to zero and the robot is
  brought to rest (``fallback = "brake"``, stops) or the paper's PID takes
  over for ``pid_time`` seconds (``"pid"``, circles).  Every solve's status
  and time, and every fallback, is counted in ``report()``.

Measured (what a real Rollbot would know): the pose from motion capture
(position, orientation), the shell angular velocity from a gyroscope and the
motor angle and speed from the encoder; that is the whole state.

Solvers: ``"ipopt"`` (exact Hessian, warm-started; always works) and
``"rti"``, a real-time iteration (one Gauss-Newton SQP step per sample with a
QP solved by CasADi's ``qrqp``), much faster; ``benchmarks/bench_nmpc.py``
measures both and the default is chosen from it.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np

from rollbot_oc.control.missions import Circle, StopMonitor, Waypoints
from rollbot_oc.control.ocp import (
    NP, OCPSettings, OrbitEntry, Plan, RestToRest, SolveFailed, interval_function, quasi_stable_guess, stage_function,
)
from rollbot_oc.codegen import compiled, compiler
from rollbot_oc.errors import interruptible
from rollbot_oc.dynamics import NZ, REDUCED, reduced_model, to_reduced
from rollbot_oc.fastcall import FastFunction
from rollbot_oc.params import PARAM_VECTOR_FIELDS, RollbotParams
from rollbot_oc.simulate import Command, Observation

__all__ = ["NMPCSettings", "TrackingWeights", "NMPC", "TrackingSolver", "RTISolver", "TiltEstimator", "Reference"]

_TILT = [PARAM_VECTOR_FIELDS.index("tilt_x"), PARAM_VECTOR_FIELDS.index("tilt_y")]


@dataclass(frozen=True)
class TrackingWeights:
    """Weights of the NMPC's least-squares tracking cost.

    Attributes
    ----------
    position : float
        Position deviation from the plan, 1/m^2.
    attitude : float
        Pendulum-frame quaternion deviation.
    omega : float
        Shell angular-velocity deviation, s^2/rad^2.
    speed : float
        Driving-speed deviation, s^2/rad^2.
    accel : float
        Motor-acceleration deviation, s^4/rad^4.
    radial : float
        Circles: distance from the target circle, 1/m^2 (0 for waypoints).
    terminal : float
        Factor on the state weights at the end of the horizon.
    """

    position: float = 400.0
    attitude: float = 20.0
    omega: float = 0.2
    speed: float = 0.02
    accel: float = 0.02
    radial: float = 0.0
    terminal: float = 5.0

    @classmethod
    def for_waypoints(cls) -> "TrackingWeights":
        """Stops: a firm hold on position, most of all at the end of the horizon (measured: it keeps
        every stop within 3.5 cm with the plant's masses and damping 10 % off the model)."""
        return cls(position=1500.0, terminal=20.0, omega=40.0)

    @classmethod
    def for_holding(cls) -> "TrackingWeights":
        """At a stop, once its leg has ended: damp the motion and keep the motor quiet rather than chase
        the last centimetres (a firm hold on position turns measurement noise into motor jitter)."""
        return cls(position=200.0, terminal=20.0, omega=40.0, speed=2.0, accel=0.5)

    @classmethod
    def for_braking(cls) -> "TrackingWeights":
        """Recovery: bring the robot to rest wherever that happens (the motion weighted, position and attitude
        only a little, to keep the QP's Hessian regular; the motor's acceleration as at a stop: with less, the
        brake of a heavy pendulum chatters between the motor's limits)."""
        return cls(position=1.0, attitude=0.1, omega=40.0, speed=1.0, accel=0.5, terminal=20.0)

    @classmethod
    def for_circles(cls) -> "TrackingWeights":
        """Circles: the distance from the circle matters, not the point on it (the reference is re-phased)."""
        return cls(position=400.0, radial=4000.0, terminal=5.0)

    def diagonal(self, N: int) -> np.ndarray:
        """Gauss-Newton weights of every decision variable ``(Z (10, N+1) by node, U (N,))``."""
        wz = np.array([self.position] * 2 + [self.attitude] * 4 + [self.omega] * 3 + [self.speed])
        scale = np.ones(N + 1)
        scale[-1] = self.terminal
        return np.concatenate([np.outer(scale, wz).ravel(), np.full(N, self.accel)])


@dataclass(frozen=True)
class NMPCSettings:
    """Horizon, weights, limits and fallbacks of the NMPC (SI units).

    Attributes
    ----------
    N : int
        Shooting intervals of the horizon.
    h : float
        Interval length and replanning period, s.
    substeps : int
        RK4 steps per interval in the prediction.
    solver : {"rti", "ipopt"}
        ``"rti"`` (default, chosen by measurement: 2.6 to 4 ms per solve,
        p95 under 5 ms) or ``"ipopt"`` (converged every period; 0.1 to 0.5 s
        per solve on a 2-core machine, so too slow for 10 Hz replanning there:
        its late solves fall back).
    waypoint_weights, hold_weights, circle_weights : TrackingWeights
        Tracking weights on the way to a stop, holding at it once its leg has
        ended, and on circles (defaults in ``TrackingWeights.for_waypoints``,
        ``for_holding`` and ``for_circles``).
    torque_margin : float
        Fraction of the torque limit the NMPC may use.
    normal_margin : float
        Least normal force as a fraction of the weight.
    friction_margin : float
        Largest tangential force as a fraction of ``mu`` times the normal force.
    max_failures : int
        Consecutive failed or late solves before the PID takes over.
    fallback : {"brake", "pid"}
        What takes over after ``max_failures`` failed solves on a course of
        stops: ``"brake"`` ramps the motor to a stop (the robot comes to rest
        as a ball with a hanging mass, then gets a new leg from there),
        ``"pid"`` the paper's PID towards the current stop for ``pid_time``.
        Circles always fall back to the PID.
    pid_time : float
        How long the PID keeps control after taking over, s.
    estimate_tilt : bool
        Estimate the floor tilt (offset-free); off gives the nominal model.
    tilt_process_noise : float
        Random-walk rate of the tilt estimate, 1/sqrt(s).
    gyro_sigma : float
        Assumed one-step prediction error of the angular velocity, rad/s.
    tilt_model_error : float
        Assumed relative error of the model's one-step change of the angular
        velocity (``TiltEstimator.model_error``).
    hold_time : float
        How long after a leg's plan ends a robot nearly at rest (see
        ``recover_speed``) outside its stop's tolerance waits before it gets a
        new leg to the same stop, s (it never moves on from a stop it has not
        reached).
    replan_distance, replan_interval : float
        A robot pushed more than ``replan_distance`` (m) off its plan gets a
        new leg to its stop from where it is, at most once per
        ``replan_interval`` (s).
    brake_weights : TrackingWeights
        A robot pushed off its plan is first brought to rest: the NMPC tracks
        rest where the robot is with these weights (motion only, no position;
        ``TrackingWeights.for_braking``).  Its new leg is planned once it is at
        rest (shell-centre speed below ``recover_speed``, m/s, driving speed
        below ``recover_drive``, rad/s) or after ``brake_wait`` s: a leg planned
        from rest converges, one from a tumbling robot often does not.
    recover_speed, recover_drive, brake_wait : float
        See ``brake_weights``.
    brake_accel : float
        If the braking solves fail (``max_failures`` in a row), the motor's
        speed is ramped to zero at this rate, rad/s^2, for a moment before
        the NMPC tries again.
    replan_angle : float
        A leg planned ahead is followed only if the robot's attitude at the
        stop is within this angle of the one it was planned from (and its
        position within ``replan_distance``); else the leg is planned from
        where the robot is, rad.
    finish_hold : float
        After the last stop is reached, the NMPC holds the robot there this
        long before it reports ``done`` (the run then ends), s.
    hold_radius : float
        At the end of a leg within this distance of its stop (m), the NMPC holds
        the robot where it arrived (damping its motion) instead of chasing the
        last centimetres.
    plan_handover : float
        A leg planned from where the robot is (the first, or a replan) starts at
        once on the quasi-stable guess (a full-model simulation); the
        minimum-time leg refined from it takes over this long after, from where
        the guess then is, s.
    tilt_settle : float
        The first leg's refinement is planned this long after the start, once
        the floor tilt estimate has settled (a plan on the level floor misses
        a slope's pull), s.
    plan_ahead : float
        The next leg is planned (from the rest state the current leg ends in,
        on the tilt estimated by then) when this fraction of the current leg
        has gone by, so that it is ready at the stop.
    caution, caution_floor : float
        After each recovery (``brakes``) on a run, later legs planned from rest
        (not the refinements of a guess, which start moving) are planned with
        their driving-speed and acceleration limits scaled by ``caution`` once
        more, down to ``caution_floor``: a robot that could not follow its plans
        gets gentler ones.
    plan_starts : int
        A leg planned ahead is solved from this many quasi-stable guesses, and
        the fastest result is kept.
    stone_distance : float
        A leg from rest to a stop farther than this that cannot be planned is
        planned instead to a stepping stone this far towards the stop (a
        shorter leg converges far more often on a robot whose revolving
        radii are small); from the stone, the leg is planned again, m.
    plan_iteration_time, plan_guess_time : float
        Modelled compute time of one IPOPT iteration of a leg's plan, and of
        the quasi-stable guesses of a leg planned ahead, s: a plan is used only
        once that much simulated time has passed after it was started (with
        ``realtime``, its measured wall-clock time instead).
    entry_times : tuple of float
        Circles: durations tried, in order, for the planned entry onto the
        orbit (least effort in that time), s.
    max_solve_time : float or None
        A solve that takes longer counts as late and is not used; ``None``
        means the period ``h`` (real time).  A larger value studies the
        controller without the real-time constraint.
    realtime : bool
        Judge lateness by the wall clock (hardware in the loop).  Off (the
        default), a solve is judged by its modelled compute time
        (``rti_step_time`` per RTI step, ``ipopt_iteration_time`` per IPOPT
        iteration), so a simulated run does not depend on how busy the
        machine is; the measured wall-clock times are still reported.
    rti_step_time, ipopt_iteration_time : float
        The modelled compute times, s (the benchmark's figures on a 2-core
        machine, rounded up).
    compiled : bool or None
        RTI: evaluate the interval linearisation as compiled C
        (``rollbot_oc.codegen``); ``None`` uses it when a C compiler exists.
    plan : OCPSettings
        Settings of the minimum-time legs (a coarser grid than the offline
        default, compiled stage functions, 15 % of the motor's acceleration
        left to the feedback, and at most 150 IPOPT iterations per start: a
        start that has not converged by then seldom does, and the robot waits
        for the plans it gets from rest).
    entry : OCPSettings
        Settings of a circle's entry onto its orbit (its ``N`` follows the entry time).
    """

    N: int = 30
    h: float = 0.1
    substeps: int = 2
    solver: str = "rti"
    waypoint_weights: "TrackingWeights" = None
    hold_weights: "TrackingWeights" = None
    circle_weights: "TrackingWeights" = None
    torque_margin: float = 0.95
    normal_margin: float = 0.1
    friction_margin: float = 0.95
    max_failures: int = 3
    fallback: str = "brake"
    pid_time: float = 2.0
    estimate_tilt: bool = True
    tilt_process_noise: float = 0.01
    gyro_sigma: float = 2e-3
    tilt_model_error: float = 0.1
    hold_time: float = 1.0
    hold_radius: float = 0.05
    replan_distance: float = 0.15
    replan_angle: float = 0.2
    finish_hold: float = 1.0
    replan_interval: float = 1.0
    brake_weights: "TrackingWeights" = None
    brake_accel: float = 15.0
    brake_wait: float = 4.0
    recover_speed: float = 0.02
    recover_drive: float = 0.3
    plan_handover: float = 2.0
    tilt_settle: float = 0.3
    plan_ahead: float = 0.0
    plan_iteration_time: float = 0.015
    plan_starts: int = 3
    stone_distance: float = 0.6
    caution: float = 0.9
    caution_floor: float = 0.7
    plan_guess_time: float = 0.5
    entry_times: tuple = (5.0, 7.0, 10.0)
    max_solve_time: float | None = None
    realtime: bool = False
    rti_step_time: float = 0.01
    ipopt_iteration_time: float = 0.01
    compiled: bool | None = None
    plan: OCPSettings = field(default_factory=lambda: OCPSettings(N=40, accel_margin=0.85, compiled=True, max_iter=150))
    entry: OCPSettings = field(default_factory=OCPSettings)

    def __post_init__(self):
        if self.waypoint_weights is None:
            object.__setattr__(self, "waypoint_weights", TrackingWeights.for_waypoints())
        if self.circle_weights is None:
            object.__setattr__(self, "circle_weights", TrackingWeights.for_circles())
        if self.hold_weights is None:
            object.__setattr__(self, "hold_weights", TrackingWeights.for_holding())
        if self.brake_weights is None:
            object.__setattr__(self, "brake_weights", TrackingWeights.for_braking())
        if self.fallback not in ("brake", "pid"):
            raise ValueError(f"NMPC fallback = {self.fallback!r}; valid are 'brake', 'pid'")
        if self.solver not in ("ipopt", "rti"):
            raise ValueError(f"NMPC solver = {self.solver!r}; valid are 'ipopt', 'rti'")
        if not (isinstance(self.N, int) and self.N >= 2):
            raise ValueError(f"NMPC N = {self.N!r} must be a whole number >= 2")
        if not (math.isfinite(self.h) and 0 < self.h <= 0.5):
            raise ValueError(f"NMPC h = {self.h!r} s is out of range: valid is (0, 0.5]")


class TrackingSolver:
    """The tracking NLP of the NMPC solved to convergence by IPOPT (exact Hessian), built once.

    Parameters of each solve: the initial reduced state, the reference states
    (10, N+1) and accelerations (N,), the model parameter vector and the
    target circle.  ``RTISolver`` solves the same problem by real-time iterations.
    """

    def __init__(self, params: RollbotParams, settings: NMPCSettings, weights: TrackingWeights):
        s = self.settings = settings
        self.params = params
        N = s.N
        stage = stage_function(s.substeps, s.friction_margin).map(N)
        Z, U = ca.MX.sym("Z", NZ, N + 1), ca.MX.sym("U", 1, N)
        z0, Zr, Ur, p = ca.MX.sym("z0", NZ), ca.MX.sym("Zr", NZ, N + 1), ca.MX.sym("Ur", 1, N), ca.MX.sym("p", NP)
        gs = stage(Z[:, :-1], U, Z[:, 1:], s.h, p)
        weight = params.total_mass * params.g
        tau = s.torque_margin * params.max_torque
        g = ca.vertcat(Z[:, 0] - z0, ca.vec(gs))
        self.lbg = np.concatenate([np.zeros(NZ), np.tile(np.concatenate([np.zeros(NZ), [-tau, s.normal_margin * weight,
                                                                                          0.0]]), N)])
        self.ubg = np.concatenate([np.zeros(NZ), np.tile(np.concatenate([np.zeros(NZ), [tau, np.inf, np.inf]]), N)])
        self._path_rows = np.concatenate([np.zeros(NZ, bool), np.tile(np.arange(13) >= NZ, N)])
        # least-squares tracking residuals (Gauss-Newton friendly); the square roots of the weights are
        # a parameter of each solve
        self.diag = weights.diagonal(N)
        root = ca.MX.sym("root", NZ * (N + 1) + N)
        res_state = (Z - Zr) * ca.reshape(root[:NZ * (N + 1)], NZ, N + 1)
        res_input = (U - Ur) * root[NZ * (N + 1):].T
        # circles: the distance from the target circle (only its radial part matters for the mission)
        circle = ca.MX.sym("circle", 3 + N + 1)  # centre (2), radius, square root of each node's weight
        offsets = Z[0:2, :] - ca.repmat(circle[0:2], 1, N + 1)
        radial = circle[3:].T * (ca.sqrt(ca.sum1(offsets**2) + 1e-9) - circle[2])
        residual = ca.vertcat(ca.vec(res_state), ca.vec(res_input), ca.vec(radial))
        x = ca.vertcat(ca.vec(Z), ca.vec(U))
        n = x.shape[0]
        self.lbx, self.ubx = np.full(n, -np.inf), np.full(n, np.inf)
        speed = 0.98 * params.max_speed
        self.lbx[9:NZ * (N + 1):NZ], self.ubx[9:NZ * (N + 1):NZ] = -speed, speed
        self.lbx[NZ * (N + 1):], self.ubx[NZ * (N + 1):] = -params.max_accel, params.max_accel
        par = ca.vertcat(z0, ca.vec(Zr), ca.vec(Ur), p, circle, root)
        self.n_x, self.n_g = n, g.shape[0]
        nlp = {"x": x, "p": par, "f": 0.5 * ca.sumsqr(residual), "g": g}
        opts = {"ipopt": {"print_level": 0, "sb": "yes", "max_iter": 50, "tol": 1e-6,
                          "warm_start_init_point": "yes", "warm_start_bound_push": 1e-6,
                          "warm_start_mult_bound_push": 1e-6, "mu_init": 1e-4},
                "print_time": False}
        self.nlp = ca.nlpsol("nmpc_ipopt", "ipopt", nlp, opts)

    def solve(self, z0, Zr, Ur, p, warm=None, circle=None, diag=None):
        """Solve from ``warm``; returns ``(x, lam, status, success, seconds)``.

        ``circle = (centre (2,), radius, weights (N+1,))`` adds each node's squared distance from a
        target circle, weighted, to the tracking cost (m, 1/m^2).  ``diag``: the tracking weights of
        every decision variable (``TrackingWeights.diagonal``), else those the solver was built with.
        """
        if circle is None:
            circle = (np.zeros(2), 1.0, np.zeros(self.settings.N + 1))
        centre, radius, node_weights = circle
        c = np.concatenate([centre, [radius], np.sqrt(node_weights)])
        root = np.sqrt(self.diag if diag is None else diag)
        par = np.concatenate([z0, np.asarray(Zr).T.ravel(), np.ravel(Ur), p, c, root])
        x_warm, lam_x, lam_g = warm if warm is not None else (None, None, None)
        if x_warm is None:
            x_warm = np.concatenate([np.asarray(Zr).T.ravel(), np.ravel(Ur)])
            x_warm[:NZ] = z0
        start = time.perf_counter()
        args = dict(x0=x_warm, p=par, lbx=self.lbx, ubx=self.ubx, lbg=self.lbg, ubg=self.ubg)
        if lam_x is not None:
            args.update(lam_x0=lam_x, lam_g0=lam_g)
        try:
            with interruptible("NMPC solve"):
                sol = self.nlp(**args)
        except RuntimeError as exc:  # a failed solve, never a crash of the loop
            return x_warm, (lam_x, lam_g), f"error: {str(exc)[:60]}", False, time.perf_counter() - start
        seconds = time.perf_counter() - start
        stats = self.nlp.stats()
        status = str(stats["return_status"])
        x = np.array(sol["x"]).ravel()
        ok = (bool(stats["success"]) or status == "Solved_To_Acceptable_Level") and bool(np.all(np.isfinite(x)))
        return x, (np.array(sol["lam_x"]).ravel(), np.array(sol["lam_g"]).ravel()), status, ok, seconds

    def split(self, x):
        """``(Z (10, N+1), U (N,))`` of a solution vector."""
        N = self.settings.N
        return x[:NZ * (N + 1)].reshape(N + 1, NZ).T, x[NZ * (N + 1):]

    def modelled_time(self) -> float:
        """Modelled compute time of the last solve: its IPOPT iterations times ``ipopt_iteration_time``, s."""
        return self.nlp.stats().get("iter_count", 0) * self.settings.ipopt_iteration_time


@functools.lru_cache(maxsize=None)
def _stage_linearisation(substeps: int, friction_margin: float, h: float) -> ca.Function:
    """``(z, u, p) -> (F, path, dF/d(z,u), dpath/d(z,u))`` of one interval: the end state, the path
    constraints and their Jacobians by AD.

    The path constraints are scaled to be dimensionless and of order one (an active-set QP solver
    needs that): motor torque over the torque limit, normal force over the weight, and the friction
    slack over the squared weight.
    """
    red, F = reduced_model(), interval_function(substeps)
    z, u, p = ca.SX.sym("z", NZ), ca.SX.sym("u"), ca.SX.sym("p", NP)
    P = {name: p[i] for i, name in enumerate(PARAM_VECTOR_FIELDS)}
    zu = ca.vertcat(z, u)
    end = F(z, u, h, p)
    N = red.reaction(z, u, p, ca.DM.zeros(6))
    weight = (P["M"] + P["m"]) * P["g"]
    slack = ((friction_margin * P["mu"] * N[2]) ** 2 - N[0] ** 2 - N[1] ** 2) / weight**2
    path = ca.vertcat(red.motor_torque(z, u, p, ca.DM.zeros(6)) / P["max_torque"], N[2] / weight, slack)
    return ca.Function("stage_linearisation", [z, u, p], [end, path, ca.jacobian(end, zu), ca.jacobian(path, zu)])


class RTISolver:
    """The NMPC's tracking problem solved by real-time iterations (Gauss-Newton SQP), built once.

    Each call takes ``iterations`` SQP steps from the warm start (one, the
    real-time iteration, by default).  A step linearises every interval with
    one mapped CasADi call (RK4 end state, path constraints and their AD
    Jacobians), assembles the structured QP in numpy on a fixed sparsity
    (Gauss-Newton Hessian of the least-squares tracking cost: diagonal, plus a
    2x2 block per node for the distance from a target circle), and solves it
    with CasADi's active-set ``qrqp``.

    Parameters
    ----------
    params : RollbotParams
        The robot the controller believes in (for the limits).
    settings : NMPCSettings
    iterations : int
        SQP steps per call.
    """

    def __init__(self, params: RollbotParams, settings: NMPCSettings, weights: TrackingWeights, iterations: int = 1):
        s = self.settings = settings
        self.params, self.iterations = params, iterations
        N = s.N
        stage = _stage_linearisation(s.substeps, s.friction_margin, s.h)
        use_c = s.compiled if s.compiled is not None else compiler() is not None
        self.stages = (compiled(stage) if use_c else stage).map(N)
        self.compiled = use_c
        self.n_x = NZ * (N + 1) + N
        self.n_g = NZ + 13 * N
        tau = s.torque_margin  # the path constraints are scaled (see _stage_linearisation)
        stage_lower = np.concatenate([np.zeros(NZ), [-tau, s.normal_margin, 0.0]])
        self.lbg = np.concatenate([np.zeros(NZ), np.tile(stage_lower, N)])
        self.ubg = np.concatenate([np.zeros(NZ), np.tile(np.concatenate([np.zeros(NZ), [tau, np.inf, np.inf]]), N)])
        self._path_rows = np.concatenate([np.zeros(NZ, bool), np.tile(np.arange(13) >= NZ, N)])
        self.lbx, self.ubx = np.full(self.n_x, -np.inf), np.full(self.n_x, np.inf)
        speed = 0.98 * params.max_speed
        self.lbx[9:NZ * (N + 1):NZ], self.ubx[9:NZ * (N + 1):NZ] = -speed, speed
        self.lbx[NZ * (N + 1):], self.ubx[NZ * (N + 1):] = -params.max_accel, params.max_accel
        self.diag = weights.diagonal(N)  # Gauss-Newton weights of the tracking residuals
        self._build_patterns()

    def _build_patterns(self):
        """Fixed sparsity of the QP's Hessian and constraint matrix, and where each Jacobian entry goes."""
        N, iu = self.settings.N, NZ * (self.settings.N + 1)
        rows, cols = list(range(NZ)), list(range(NZ))  # z_0 - z_meas
        for k in range(N):
            r0 = NZ + 13 * k
            for i in range(13):  # d/d(z_k, u_k): gap rows carry -dF, path rows dpath
                rows += [r0 + i] * (NZ + 1)
                cols += list(range(NZ * k, NZ * k + NZ)) + [iu + k]
            rows += list(range(r0, r0 + NZ))  # d gap / d z_{k+1} = I
            cols += list(range(NZ * (k + 1), NZ * (k + 2)))
        A = _csc(rows, cols, self.n_g, self.n_x)
        self.A_sparsity, self.A_order = A
        hr, hc = list(range(self.n_x)), list(range(self.n_x))
        for k in range(N + 1):  # the 2x2 position block of each node (circle term)
            hr += [NZ * k, NZ * k + 1]
            hc += [NZ * k + 1, NZ * k]
        self.H_sparsity, self.H_order = _csc(hr, hc, self.n_x, self.n_x)
        self.qp = ca.conic("nmpc_qp", "qrqp", {"h": self.H_sparsity, "a": self.A_sparsity},
                           {"print_iter": False, "print_header": False, "error_on_fail": False, "max_iter": 150})

    def _qp_data(self, x, z0, Zr, Ur, p, circle, diag):
        N = self.settings.N
        Z = x[:NZ * (N + 1)].reshape(N + 1, NZ).T
        U = x[NZ * (N + 1):]
        end, path, J_end, J_path = (np.array(v) for v in self.stages(Z[:, :-1], U[None, :], p))
        gap = Z[:, 1:] - end
        g = np.concatenate([Z[:, 0] - z0, np.vstack([gap, path]).T.ravel()])
        # per stage: the 13 x 11 block on (z_k, u_k) (gap rows -dF, path rows dpath), row by row,
        # then the identity of the gap on z_{k+1}
        blocks = np.vstack([-J_end, J_path])
        stage_blocks = blocks.reshape(13, N, NZ + 1).transpose(1, 0, 2).reshape(N, -1)
        data = np.concatenate([np.ones(NZ), np.hstack([stage_blocks, np.ones((N, NZ))]).ravel()])
        A = ca.DM(self.A_sparsity, data[self.A_order])
        # Gauss-Newton cost: diagonal tracking part plus the circle's radial residuals
        xref = np.concatenate([np.asarray(Zr).T.ravel(), np.ravel(Ur)])
        diff = x - xref
        grad = diag * diff
        hdiag = diag.copy()
        offdiag = np.zeros(N + 1)
        if circle is not None and np.any(circle[2] > 0):
            centre, radius, w_r = circle
            rel = Z[0:2] - np.asarray(centre, float)[:, None]
            dist = np.maximum(np.hypot(rel[0], rel[1]), 1e-9)
            n = rel / dist
            res = dist - radius
            idx = NZ * np.arange(N + 1)
            grad[idx] += w_r * res * n[0]
            grad[idx + 1] += w_r * res * n[1]
            hdiag[idx] += w_r * n[0] ** 2
            hdiag[idx + 1] += w_r * n[1] ** 2
            offdiag = w_r * n[0] * n[1]
        H = ca.DM(self.H_sparsity, np.concatenate([hdiag, np.repeat(offdiag, 2)])[self.H_order])
        return H, grad, g, A

    def solve(self, z0, Zr, Ur, p, warm=None, circle=None, diag=None):
        """``iterations`` SQP steps from ``warm``; returns ``(x, lam, status, success, seconds)``.

        ``circle``, ``diag``: as for ``TrackingSolver.solve``.
        """
        diag = self.diag if diag is None else diag
        x, lam_x, lam_g = warm if warm is not None else (None, None, None)
        if x is None:
            x = np.concatenate([np.asarray(Zr).T.ravel(), np.ravel(Ur)])
            x[:NZ] = z0
        start = time.perf_counter()
        ok, status = True, "success"
        for _ in range(self.iterations):
            H, grad, g, A = self._qp_data(x, np.asarray(z0, float), Zr, Ur, p, circle, diag)
            if not (np.all(np.isfinite(g)) and np.all(np.isfinite(grad)) and np.all(np.isfinite(A.nonzeros()))):
                ok, status = False, "non-finite linearisation"
                break
            args = dict(h=H, g=grad, a=A, lba=self.lbg - g, uba=self.ubg - g, lbx=self.lbx - x, ubx=self.ubx - x)
            sol, ok = self._qp(args, lam_x, lam_g)
            stats = self.qp.stats() if sol is not None else {"return_status": "QP error"}
            status = str(stats.get("return_status", "success" if ok else "failed"))
            if not ok:  # e.g. a state no command keeps within the torque or contact limits: without them
                args.update(lba=np.where(self._path_rows, -np.inf, args["lba"]),
                            uba=np.where(self._path_rows, np.inf, args["uba"]))
                sol, ok = self._qp(args, None, None)
                status = f"relaxed ({status})" if ok else status
            if not ok:
                break
            x = np.clip(x + np.array(sol["x"]).ravel(), self.lbx, self.ubx)  # qrqp may overstep a bound a little
            lam_x, lam_g = np.array(sol["lam_x"]).ravel(), np.array(sol["lam_a"]).ravel()
        seconds = time.perf_counter() - start
        return x, (lam_x, lam_g), status, ok and bool(np.all(np.isfinite(x))), seconds

    def _qp(self, args, lam_x, lam_g):
        """Solve the QP warm-started from the previous active set; once more cold if that fails."""
        try:
            with interruptible("NMPC solve"):
                if lam_x is not None:
                    sol = self.qp(**args, lam_x0=lam_x, lam_a0=lam_g)
                    if self.qp.stats()["success"]:
                        return sol, True
                sol = self.qp(**args)
        except RuntimeError:  # an ill-posed QP is a failed solve, never a crash of the loop
            return None, False
        return sol, bool(self.qp.stats()["success"])

    def split(self, x):
        """``(Z (10, N+1), U (N,))`` of a solution vector."""
        N = self.settings.N
        return x[:NZ * (N + 1)].reshape(N + 1, NZ).T, x[NZ * (N + 1):]

    def modelled_time(self) -> float:
        """Modelled compute time of a solve: ``iterations`` RTI steps of ``rti_step_time``, s."""
        return self.iterations * self.settings.rti_step_time


def _csc(rows, cols, n_rows, n_cols):
    """A CasADi sparsity from coordinate lists, and the permutation from coordinate to column-major order."""
    rows, cols = np.asarray(rows), np.asarray(cols)
    order = np.lexsort((rows, cols))
    sp = ca.Sparsity.triplet(n_rows, n_cols, rows.tolist(), cols.tolist())
    if sp.nnz() != len(rows):
        raise ValueError("duplicate entries in a QP sparsity pattern")
    return sp, order


@functools.lru_cache(maxsize=None)
def _one_step(substeps: int, dt: float) -> ca.Function:
    """``(z, u, p) -> (z_next, d omega_next / d tilt)`` over one control period, for the estimator."""
    F = interval_function(substeps)
    z, u, p = ca.SX.sym("z", NZ), ca.SX.sym("u"), ca.SX.sym("p", NP)
    zn = F(z, u, dt, p)
    return ca.Function("one_step", [z, u, p], [zn, ca.jacobian(zn[6:9], p)[:, _TILT]])


class TiltEstimator:
    """Kalman filter on the floor's tilt vector (in-plane gravity per g) from the shell's angular velocity.

    Parameters
    ----------
    params : RollbotParams
        Nominal model (its tilt is the prior).
    dt : float
        Control period, s.
    process_noise : float
        Random-walk rate of the tilt, 1/sqrt(s).
    gyro_sigma : float
        One-step prediction error of the angular velocity, rad/s.
    model_error : float
        Relative error of the model's predicted change of the angular velocity
        (masses, damping): in motion the prediction error grows with the change,
        so the filter learns the floor at rest and near it, not the model's
        errors in hard manoeuvres.
    """

    def __init__(self, params: RollbotParams, dt: float, process_noise: float = 0.01, gyro_sigma: float = 2e-3,
                 model_error: float = 0.1):
        self.p = params.vector()
        self.dt = dt
        self.q = process_noise**2 * dt
        self.r = gyro_sigma**2
        self.model_error = model_error
        self.step = FastFunction(_one_step(1, dt))
        self.reset()

    def reset(self):
        """Back to the prior (the nominal tilt, a 2 deg standard deviation)."""
        self.tilt = self.p[_TILT].copy()
        self.P = np.eye(2) * math.radians(2.0) ** 2

    def update(self, z_prev, u_prev: float, z_now) -> np.ndarray:
        """Fold in one period: state ``z_prev``, command ``u_prev`` (rad/s^2), then state ``z_now``."""
        p = self.p.copy()
        p[_TILT] = self.tilt
        zn, H = self.step(z_prev, u_prev, p)
        H = H.reshape(2, 3).T  # the buffer is column-major
        residual = np.asarray(z_now)[6:9] - zn[6:9]
        if not (np.all(np.isfinite(residual)) and np.all(np.isfinite(H))):
            return self.tilt  # nothing to learn from a broken prediction
        self.P = self.P + np.eye(2) * self.q
        change = float(np.linalg.norm(zn[6:9] - np.asarray(z_prev)[6:9]))
        S = H @ self.P @ H.T + np.eye(3) * (self.r + (self.model_error * change) ** 2)
        K = np.linalg.solve(S, H @ self.P).T  # S is symmetric positive definite (r > 0)
        self.tilt = np.clip(self.tilt + K @ residual, -0.5, 0.5)
        self.P = (np.eye(2) - K @ H) @ self.P
        return self.tilt

    def params(self) -> np.ndarray:
        """The model parameter vector with the estimated tilt."""
        p = self.p.copy()
        p[_TILT] = self.tilt
        return p


def _orbit_states(qs, centre, phases) -> np.ndarray:
    """``orbit_state`` for many phases at once (numpy): the reduced state (10, n) on the orbit."""
    c, s = np.cos(phases), np.sin(phases)
    out = np.empty((NZ, len(phases)))
    out[0] = centre[0] + c * qs[0] - s * qs[1]
    out[1] = centre[1] + s * qs[0] + c * qs[1]
    hc, hs = np.cos(phases / 2), np.sin(phases / 2)  # rotation about z, then the orbit attitude
    w, x, y, z = qs[2:6]
    out[2], out[3], out[4], out[5] = hc * w - hs * z, hc * x - hs * y, hc * y + hs * x, hc * z + hs * w
    out[6], out[7], out[8] = c * qs[6] - s * qs[7], s * qs[6] + c * qs[7], qs[8]
    out[9] = qs[9]
    return out


def _wrap(angle: float) -> float:
    """Angle wrapped to (-pi, pi], rad."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


class Reference:
    """What the NMPC tracks: a chain of planned legs with holds at the stops, or an entry onto an orbit.

    Parameters
    ----------
    segments : list of (Plan, dict)
        Plans in order with a description (``{"stop": point}`` for a stop).
    orbit : dict, optional
        After the last segment, the quasi-stable orbit to follow (``qs``,
        ``centre``, ``phase``, ``Omega``).
    """

    def __init__(self, segments, orbit=None):
        self.segments, self.orbit = segments, orbit

    def sample(self, index: int, t_local, h: float, N: int, position=None):
        """Reference states (10, N+1) and accelerations (N,) for segment ``index`` from local time ``t_local``.

        On the orbit, ``position`` (m) re-phases the reference to the robot's own angle about the centre:
        only the distance from the circle is the mission, not being at a particular point of it.
        """
        times = t_local + h * np.arange(N + 1)
        plan = self.segments[index][0]
        Z = plan.state(times)
        U = np.array([plan.accel(t) for t in times[:-1]])
        if self.orbit is not None and index == len(self.segments) - 1:
            after = times > plan.T
            if np.any(after):
                o = self.orbit
                phases = o["phase"] + o["Omega"] * (times[after] - plan.T)
                if position is not None and after[0]:
                    rel = np.asarray(position) - o["centre"]
                    own = math.atan2(rel[1], rel[0]) - math.atan2(o["qs"][1], o["qs"][0])
                    phases = phases + _wrap(own - phases[0])
                Z[:, after] = _orbit_states(o["qs"], o["centre"], phases)
        elif np.any(times > plan.T):
            Z[6:10, times > plan.T] = 0.0  # hold the rest state at the stop
        return Z, U


class NMPC:
    """Tracking NMPC with minimum-time plans (see module doc); a ``Controller`` for ``simulate``.

    Parameters
    ----------
    mission : Circle or Waypoints
    params : RollbotParams, optional
        The robot the controller believes in (level floor by default: the slope is estimated).
    dt : float
        Control period of the loop, s (the plant's 100 Hz).
    settings : NMPCSettings, optional
    """

    def __init__(self, mission, params: RollbotParams | None = None, dt: float = 0.01,
                 settings: NMPCSettings | None = None):
        if not isinstance(mission, (Circle, Waypoints)):
            raise ValueError(f"mission must be a Circle or Waypoints, got {type(mission).__name__}")
        if any(not w.stop for w in getattr(mission, "points", ())):
            raise ValueError("the NMPC plans stops; pass-through waypoints are for the PID's waypoint layer")
        self.mission = mission
        self._rule = mission.stop_rule if isinstance(mission, Waypoints) else None
        self.params = params or RollbotParams()
        self.dt = dt
        self.settings = s = settings or NMPCSettings()
        self.every = max(1, int(round(s.h / dt)))
        if abs(self.every * dt - s.h) > 1e-9:
            raise ValueError(f"NMPC h = {s.h} s must be a whole number of control periods dt = {dt} s")
        self.weights = s.circle_weights if isinstance(mission, Circle) else s.waypoint_weights
        solver = TrackingSolver if s.solver == "ipopt" else RTISolver
        self.solver = solver(self.params, s, self.weights)
        self._hold_diag = s.hold_weights.diagonal(s.N)
        self._brake_diag = s.brake_weights.diagonal(s.N)
        self.estimator = TiltEstimator(self.params, dt, s.tilt_process_noise, s.gyro_sigma,
                                       s.tilt_model_error)
        # the legs' planner, built once (its floor tilt is set per plan from the estimate)
        self._legs = _rest_to_rest(self.params.replace(slope=0.0), s.plan) if isinstance(mission, Waypoints) else None
        self.map = None  # set with the plans (for centre-of-curvature plots)
        self.reference = None
        self.plan_time = 0.0
        self._pid = None
        self.reset()

    # -- planning ---------------------------------------------------------------------------------
    def prepare(self, x0) -> Reference:
        """What to follow first, from the full state ``x0`` (11,); called by ``run_problem`` before the run.

        Stops: the quasi-stable guess of the first leg (a fraction of a second),
        refined while the robot moves (see ``plan_handover``); every later leg
        is planned during the one before.  Circles: the entry onto the orbit.
        ``plan_time`` is the computation before the first command, s.

        Raises
        ------
        SolveFailed
            If a circle's entry cannot be planned.
        """
        start = time.perf_counter()
        level = self.params.replace(slope=0.0)
        from rollbot_oc.quasi_stable import RadiusMap

        self.map = RadiusMap(level)
        if isinstance(self.mission, Waypoints):
            self.reference = Reference([None] * len(self.mission.stops))
            self._follow_guess(to_reduced(x0), 0.0)  # refined while the robot moves (``_refine``)
            self.plan_time = time.perf_counter() - start  # the first command can be given now
            return self.reference
        # The minimum-time entry takes hundreds of IPOPT iterations; a fixed entry time a little
        # above it, with the least effort, converges in a fraction of the time.
        settings = self.settings.entry
        for duration in self.settings.entry_times:
            intervals = int(round(duration / self.settings.h))
            entry = _orbit_entry(self.mission.radius, level, replace(settings, N=intervals))
            try:
                plan = entry.solve(x0, self.mission.centre, duration=duration)
                break
            except SolveFailed:
                if duration == self.settings.entry_times[-1]:
                    raise
        orbit = {"qs": entry.qs_reduced, "centre": self.mission.centre, "phase": plan.extra["phase"],
                 "Omega": entry.quasi.Omega}
        self.reference = Reference([(plan, {})], orbit)
        self.plan_time = time.perf_counter() - start
        return self.reference

    # -- legs: planned while the robot moves --------------------------------------------------------
    def _provisional(self, z, t_now: float):
        """Start the current leg at once on its quasi-stable guess from ``z`` (a simulation of the model),
        refined as it goes (``_refine``)."""
        self._follow_guess(z, t_now)

    def _follow_guess(self, z, t_now: float):
        """Make the current leg the quasi-stable guess from ``z``, to be refined ``tilt_settle`` s later."""
        s, stop = self.settings, self.mission.stops[self.segment]
        guess = quasi_stable_guess(z, np.asarray(stop, float), self.params.replace(slope=0.0), s.plan.N)
        guess.extra = {"goal": list(map(float, stop)), "provisional": True}
        self.reference.segments[self.segment] = (guess, {"stop": stop})
        self.segment_start = t_now
        self._anchor = None
        self._refine_at = t_now + s.tilt_settle

    def _refine(self, t_now: float):
        """Plan the minimum-time leg from where the guess followed now will be ``plan_handover`` s later
        (if the guess lasts that long); it takes over there if it is ready by then."""
        self._refine_at = None
        guess = self.reference.segments[self.segment][0]
        handover = t_now - self.segment_start + self.settings.plan_handover
        if handover < guess.T - self.settings.plan_handover:
            self._launch(self.segment, t_now, self.segment_start + handover, guess.state(handover),
                         guess.tail(handover, self.settings.plan.N))

    def _launch(self, segment: int, t_now: float, t_start, z_start, guess=None):
        """Plan leg ``segment`` from ``z_start`` on the estimated floor; it may be used once its modelled
        compute time has passed, and is followed from the absolute time ``t_start`` (s; None: from the
        moment the stop before it is reached)."""
        s, stop = self.settings, self.mission.stops[segment]
        wall = time.perf_counter()
        tilt = self.estimator.tilt.copy()
        scale = max(s.caution_floor, s.caution ** self.log["brakes"])  # from rest: gentler after recoveries
        goals = [np.asarray(stop, float)]
        if guess is None:  # from rest: a stepping stone if the stop cannot be planned
            towards = goals[0] - np.asarray(z_start[REDUCED.position], float)
            distance = float(np.linalg.norm(towards))
            if distance > s.stone_distance:
                goals.append(goals[0] - towards * (1.0 - s.stone_distance / distance))
        plan, iterations, tried = None, 0, 0
        for goal in goals:
            tried += 1
            try:  # a refinement from its guess, or the fastest of several starts
                plan = self._legs.solve(z_start, goal, guess=guess, tilt=tilt) if guess is not None \
                    else self._legs.fastest(z_start, goal, s.plan_starts, tilt=tilt, motor_scale=scale)
                iterations += plan.iterations
                break
            except SolveFailed as exc:  # reported, never followed
                self.log["statuses"].append(f"plan failed: {exc.status}")
                self.log["plan_failures"] += 1
                iterations += exc.plan.iterations if exc.plan is not None else 0
        if plan is not None and goal is not goals[0]:
            plan.extra["stone"] = True  # from its end, the leg is planned again
            self.log["stones"] += 1
        wall = time.perf_counter() - wall
        self.log["plan_solve_times"].append(wall)
        guesses = tried * s.plan_guess_time if guess is None else 0.0
        compute = wall if s.realtime else iterations * s.plan_iteration_time + guesses
        ready = t_now + s.h * math.ceil(compute / s.h - 1e-9)  # used at a solve instant
        self._pending[segment] = {"plan": plan, "start": t_start, "ready": ready}

    def _fits(self, pending, z) -> bool:
        """Whether a leg planned ahead starts where the robot is: within ``replan_distance`` and with its
        pendulum frame turned less than ``replan_angle`` from the robot's."""
        if pending is None or pending["plan"] is None:
            return False
        start = pending["plan"].z[:, 0]
        cos_half = abs(float(start[REDUCED.quaternion] @ z[REDUCED.quaternion]))
        turned = 2.0 * math.acos(min(cos_half, 1.0))
        near = np.linalg.norm(start[REDUCED.position] - z[REDUCED.position]) <= self.settings.replan_distance
        return near and turned <= self.settings.replan_angle

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
        return True

    # -- the loop ---------------------------------------------------------------------------------
    def reset(self):
        """Forget the run; a mission prepared (``prepare``) and not yet run is kept."""
        if getattr(self, "k", 0) > 0 or self.reference is None:
            self.reference = None
            self.segment, self.segment_start = 0, 0.0
            self._pending = {}  # legs being planned, by segment
            self._refine_at = None  # when to refine the quasi-stable guess followed
            self._braking_since = None  # when the robot began to be brought to rest
            self._anchor = None
            self.log = {"solve_times": [], "statuses": [], "fallback_shifted": 0, "fallback_pid": 0,
                        "fallback_brake": 0, "late": 0, "failed": 0, "tilt": [], "replans": 0, "plan_solve_times": [],
                        "plan_failures": 0, "plan_wait": 0.0, "brakes": 0, "plan_late": 0, "stones": 0, "unfit": 0}
        self.k = 0
        self.warm = None
        self.current = None  # (U, index of the interval in use)
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
        if self.reference is None or isinstance(self.mission, Circle) or self._done:
            return False
        if self._monitor is None:
            self._monitor = StopMonitor(self.reference.segments[self.segment][1]["stop"], self._rule)
        centre_speed = self.params.R * math.hypot(obs.omega[0], obs.omega[1])
        return self._monitor.update(obs.t, obs.position, centre_speed, obs.theta_dot)

    def _advance_mission(self, t_now: float, obs: Observation, reached: bool, z):
        """Follow refined legs as they become ready, plan the next leg ahead, leave a stop once it is
        reached, and, if the robot was pushed off its plan or came to rest outside its stop's tolerance,
        bring it to rest and plan a new leg to the same stop from there (``_brake``)."""
        if self.reference is None or isinstance(self.mission, Circle):
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
        if (i + 1 < len(self.mission.stops) and self.reference.segments[i + 1] is None and i + 1 not in self._pending
                and not plan.extra.get("provisional") and not plan.extra.get("stone") and self._braking_since is None
                and i not in self._pending
                and local >= s.plan_ahead * plan.T):
            end = plan.z[:, -1].copy()
            end[REDUCED.velocity] = 0.0
            self._launch(i + 1, t_now, None, end)
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
                self._pending.pop(self.segment, None)  # nothing (or nothing that fits) planned ahead: from here
                self._brake(z, t_now, recovery=False)
            return
        at_rest = (self.params.R * float(np.linalg.norm(z[REDUCED.omega])) < s.recover_speed
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
                start = z.copy()
                start[REDUCED.velocity] = 0.0
                self._launch(i, t_now, None, start)
                self._rest_plan = start  # held there (``hold_weights``) until the leg is ready
                return
            else:
                return
            self.warm, self.current = None, None
            return
        anchor = self._anchor if self._anchor is not None else plan.state(local)[REDUCED.position]
        off_course = np.linalg.norm(z[REDUCED.position] - anchor) > s.replan_distance
        away = np.linalg.norm(z[REDUCED.position] - np.asarray(info["stop"], float)) > self._rule.tolerance
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
        self._pending.pop(self.segment, None)
        self._pending.pop(self.segment + 1, None)
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
            Zr = np.tile((self._rest_plan if held else z)[:, None], (1, s.N + 1))
            Ur, diag = np.zeros(s.N), self._hold_diag if held else self._brake_diag
            Zr[REDUCED.velocity] = 0.0
        else:
            Zr, Ur = self.reference.sample(self.segment, t_now - self.segment_start, s.h, s.N, position=z[0:2])
            self._settle(Zr, t_now, z)
            if self._anchor is not None:  # holding at a stop
                diag = self._hold_diag
        # q and -q are the same attitude: give the (continuous) reference the measurement's sign
        if float(Zr[2:6, 0] @ z[2:6]) < 0:
            Zr[2:6] *= -1.0
        circle = None
        if isinstance(self.mission, Circle):  # the distance from the circle counts once on the orbit
            on_orbit = (t_now - self.segment_start + s.h * np.arange(s.N + 1)) > self.reference.segments[0][0].T
            circle = (self.mission.centre, self.mission.radius, self.weights.radial * on_orbit)
        x, lam, status, ok, seconds = self.solver.solve(z, Zr, Ur, self.estimator.params(), self.warm, circle, diag)
        compute = seconds if s.realtime else self.solver.modelled_time()
        late = compute > (s.h if s.max_solve_time is None else s.max_solve_time)
        self.log["solve_times"].append(seconds)
        self.log["statuses"].append(status)
        self.log["tilt"].append(self.estimator.tilt.tolist())
        if ok and not late:
            _, U = self.solver.split(x)
            self.current = (U, k)
            self.warm = (self._shift(x), *lam)  # duals unshifted: the structure repeats every interval
            self.failures = 0
            return
        self.log["late" if ok else "failed"] += 1
        self.failures += 1
        if self.current is not None and self.failures < s.max_failures:
            self.log["fallback_shifted"] += 1  # keep following the previous solution (its index moves on)
            return
        self.warm, self.current, self.failures = None, None, 0
        if isinstance(self.mission, Waypoints) and s.fallback == "brake":
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

    def _settle(self, Zr, t_now: float, z):
        """Past a leg's end within ``hold_radius`` of its stop, hold the robot where it is: the reference
        position becomes the position it had on arriving, so the NMPC damps the motion instead of chasing
        a few centimetres a single motor cannot correct at rest."""
        if self.reference is None or isinstance(self.mission, Circle):
            return
        plan, info = self.reference.segments[self.segment]
        ended = t_now - self.segment_start + self.settings.h * np.arange(Zr.shape[1]) >= plan.T
        if not ended[0]:
            self._anchor = None
            return
        if self._anchor is None:
            near = np.linalg.norm(z[REDUCED.position] - np.asarray(info["stop"], float)) <= self.settings.hold_radius
            if not near:
                return
            self._anchor = z[REDUCED.position].copy()
        Zr[REDUCED.position, :] = self._anchor[:, None]

    def _shift(self, x):
        Z, U = self.solver.split(x)
        Zs = np.hstack([Z[:, 1:], Z[:, -1:]])
        Us = np.concatenate([U[1:], U[-1:]])
        return np.concatenate([Zs.T.ravel(), Us])

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
        goal = self.segment if isinstance(self.mission, Waypoints) else -1
        if self._pid is None or self._pid_goal != goal:
            from rollbot_oc.control.pid import QuasiStablePID

            mission = self.mission if goal < 0 else Waypoints(
                (self.reference.segments[self.segment][1]["stop"],), stop_tolerance=self.mission.stop_tolerance)
            self._pid, self._pid_goal, self._pid_fresh = QuasiStablePID(
                mission, self.params, dt=self.dt, radius_map=self.map), goal, True
        if self._pid_fresh:  # take over smoothly from the current driving speed
            self._pid.reset()
            self._pid.omega_cmd = max(float(z[REDUCED.theta_dot]), 0.0)
            self._pid_fresh = False
        speed = self._pid(obs).speed
        limit = self.params.max_accel  # the plant's motor cannot follow faster either
        self.commands[k] = float(np.clip((speed - float(z[REDUCED.theta_dot])) / self.dt, -limit, limit))
        self.commands.pop(k - 50, None)
        return Command(speed=speed)

    def report(self) -> dict:
        """Solve-time statistics (s), solver statuses, fallback counts, stops and plans."""
        times = np.array(self.log["solve_times"]) if self.log["solve_times"] else np.zeros(1)
        statuses = {}
        for st in self.log["statuses"]:
            statuses[st] = statuses.get(st, 0) + 1
        legs = [seg for seg in self.reference.segments if seg is not None] if self.reference else []
        plans = [seg[0].to_dict() for seg in legs]
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
            "plan_solve_time_median": float(np.median(plan_times)),
            "plan_solve_time_max": float(plan_times.max()),
            "tilt_estimate": self.estimator.tilt.tolist(),
        }


@functools.lru_cache(maxsize=8)
def _rest_to_rest(params: RollbotParams, settings: OCPSettings) -> RestToRest:
    return RestToRest(params, settings)


@functools.lru_cache(maxsize=8)
def _orbit_entry(radius: float, params: RollbotParams, settings: OCPSettings) -> OrbitEntry:
    return OrbitEntry(radius, params, settings)
