"""Settings of the NMPC: its horizon, tracking weights, limits, fallbacks and planning (SI units)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rollbot_oc.control.ocp import OCPSettings
from rollbot_oc.dynamics import REDUCED

__all__ = ["TrackingWeights", "NMPCSettings"]


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
    arrival_speed : float
        Stops: driving-speed weight at the horizon nodes past the end of the
        leg, s^2/rad^2 (``speed`` if that is larger; 0: ``speed`` there too).
        With it the NMPC plans the last braking so that the motor stands still
        on arrival, instead of overshooting the plan's zero speed by a fraction
        of an interval: a motor that swings back rocks the shell, and the rest
        test waits.
    arrival_omega : float
        Stops: shell angular-velocity weight at the same nodes, s^2/rad^2
        (``omega`` if that is larger; 0: ``omega`` there too).  With it the
        NMPC plans the approach so that the shell, too, arrives still: a robot
        that arrives swaying sideways cannot damp that sway at rest (the mode
        is uncontrollable there, ``tests/test_stability.py``) and waits for it
        to die out.
    """

    position: float = 400.0
    attitude: float = 20.0
    omega: float = 0.2
    speed: float = 0.02
    accel: float = 0.02
    radial: float = 0.0
    terminal: float = 5.0
    arrival_speed: float = 0.0
    arrival_omega: float = 0.0

    @classmethod
    def for_waypoints(cls) -> "TrackingWeights":
        """Stops: a firm hold on position, most of all at the end of the horizon (measured: it keeps
        every stop within 3.5 cm with the plant's masses and damping 10 % off the model), and the motor
        and the shell still on arrival (``arrival_speed``, ``arrival_omega``;
        ``benchmarks/bench_robustness_result.md`` items 9 and 10)."""
        return cls(position=1500.0, terminal=20.0, omega=40.0, arrival_speed=2000.0, arrival_omega=400.0)

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

    @property
    def arrives(self) -> bool:
        """Whether an arrival weight is set (``arrival_speed`` or ``arrival_omega`` above 0)."""
        return self.arrival_speed > 0 or self.arrival_omega > 0

    def diagonal(self, N: int, ended: np.ndarray | None = None) -> np.ndarray:
        """Gauss-Newton weights of every decision variable.

        Parameters
        ----------
        N : int
            Intervals of the horizon.
        ended : array_like (N+1,) of bool, optional
            The nodes past the end of a leg: their driving speed weighs
            ``arrival_speed`` (or ``speed`` if that is larger), their shell
            angular velocity ``arrival_omega`` (or ``omega``).

        Returns
        -------
        numpy.ndarray (10 (N+1) + N,)
            The state weights node by node (each in the units of its field),
            the terminal factor on the last node, then the N acceleration
            weights (``accel``).
        """
        wz = np.array([self.position] * 2 + [self.attitude] * 4 + [self.omega] * 3 + [self.speed])
        weights = np.tile(wz, (N + 1, 1))
        if ended is not None and self.arrives:
            ended = np.asarray(ended, bool)
            weights[ended, REDUCED.theta_dot] = max(self.speed, self.arrival_speed)
            weights[ended, REDUCED.omega] = max(self.omega, self.arrival_omega)
        weights[-1] *= self.terminal
        return np.concatenate([weights.ravel(), np.full(N, self.accel)])


@dataclass(frozen=True)
class NMPCSettings:
    """Horizon, weights, limits and fallbacks of the NMPC (SI units).

    Attributes
    ----------
    N : int
        Shooting intervals of the horizon.
    h : float
        Interval length and replanning period, s.  Short enough that the
        commands follow the bang-bang switches of a minimum-time plan's motor
        acceleration: a robot that brakes late arrives swaying sideways, and
        its motor cannot damp that sway at rest (the mode is uncontrollable
        there, ``tests/test_stability.py``), so it fails the rest test for
        seconds (``benchmarks/bench_nmpc_result.txt`` compares 0.1 s).
    substeps : int
        RK4 steps per interval in the prediction.
    solver : {"rti", "ipopt"}
        ``"rti"`` (default, chosen by measurement: ``benchmarks/bench_nmpc.py``)
        or ``"ipopt"`` (converged every period; too slow for 10 Hz replanning
        on a small machine: its late solves fall back).  Both are routes of
        the one tracking problem (``tracking.tracking_problem``).
    waypoint_weights, hold_weights, circle_weights : TrackingWeights
        Tracking weights on the way to a stop, holding at it once its leg has
        ended, and on circles (defaults in ``TrackingWeights.for_waypoints``,
        ``for_holding`` and ``for_circles``).
    torque_margin : float
        Fraction of the torque limit the tracking NMPC may use (more than the
        plans it tracks, ``plan.torque_margin``: the rest is the feedback's).
    speed_margin : float
        Fraction of the driving-speed limit the tracking NMPC may use.
    constraints : tuple of callables
        More path constraints of the NMPC, each a function of an ``OCP``
        returning a ``Constraint`` (``rollbot_oc.ocp.constraints``, or
        ``bounded(lower, expression, upper, name)`` of the stage symbols) or a
        relation, e.g. ``lambda ocp: position_box(ocp, (-0.1, -0.1), (1.3,
        1.3))``: one line, and the legs it plans, a circle's entry and the
        tracking problem all keep it (like the motor and contact limits, the
        tracking QP drops it when no command can satisfy it).
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
    learn : tuple of str
        Parameters (of ``estimation.LEARNABLE``) whose scale factors the tilt filter
        learns as the robot moves, used by every later plan and solve (with
        ``estimate_tilt``): the shell's mass ``M``, the pendulum's ``m`` and the
        damping ``k0`` by default; ``()`` keeps the nominal model.
    learn_sigma : float
        Prior standard deviation of each learned factor (0.1: the model may be
        10 % off).
    tilt_process_noise : float
        Random-walk rate of the tilt estimate, 1/sqrt(s).
    gyro_sigma : float
        Assumed one-step prediction error of the angular velocity, rad/s.
    tilt_model_error : float
        Assumed relative error of the model's one-step change of the angular
        velocity (``TiltEstimator.model_error``).
    attitude_gain : float
        Gain of the filter's attitude (``TiltEstimator.attitude_gain``): the
        fraction, each period, by which the attitude carried by the model moves
        to the measured one; 1 uses the measurement alone.
    hold_time : float
        How long after a leg's plan ends a robot nearly at rest (see
        ``recover_speed``) outside its stop's tolerance waits before it gets a
        new leg to the same stop, s (it never moves on from a stop it has not
        reached; a robot at rest that late seldom creeps into the tolerance:
        ``benchmarks/bench_robustness_result.md`` item 11).
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
    swung_angle : float
        A robot brought to rest whose pendulum frame is turned more than
        this from its balanced rest (``dynamics.rest_attitude``: the mass
        swung up) is held at that rest, and its leg from rest planned from
        it; nearer, it is held where it is, rad.
    finish_hold : float
        After the last stop is reached, the NMPC holds the robot there this
        long before it reports ``done`` (the run then ends), s.
    gate_weight : float
        Gates: the weight added on the position deviation from the plan at the
        two horizon nodes around each planned gate passage, 1/m^2.
    hold_radius : float
        At the end of a leg within this distance of its stop (m), the NMPC holds
        the robot where it arrived (damping its motion) instead of chasing the
        last centimetres.
    plan_handovers : tuple of float
        A leg planned from where the robot is (the first, or a replan) starts
        at once on the quasi-stable guess (a full-model simulation); minimum-time
        legs are refined from where the tracking NMPC predicts the robot
        following the guess will be each of these times later, s, one after
        the other (a minimum-time leg has local optima, and where it starts
        decides which one IPOPT finds); of those ready in time, the one that
        arrives first takes over where it starts.  The
        default, 1.2 s, is the modelled time of the planner's longest solve
        (``plan.max_iter`` iterations of ``plan_iteration_time``): a refinement
        from the guess's tail that converges is never late.  The fresh ones
        (``refine_fresh``) queue behind it on the one planner, with their
        guesses' ``plan_guess_time``, and are used only if ready in time
        (on the N-shape the tail took 52 iterations, 0.42 s, which with the
        guesses' 0.3 s leaves the fresh one 60 iterations of the 1.2 s).
    ride_accels : tuple of float
        The quasi-stable guess a leg starts on at once (the first leg, and a
        leg whose plan from rest failed) is the best of the trapezoidal
        driving-speed profiles that ramp at these rates, rad/s^2 (the
        planner's own starts ramp at 2, 4 and 8).  A gentle ramp leaves the
        robot slow and near its start when the refinement takes over: from
        there the minimum-time legs converge, and are fast, far more often
        than from a robot already at full speed in a poor direction
        (``benchmarks/bench_robustness_result.md`` item 16).
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
    legs_ahead : int
        How many legs beyond the current one may be planned ahead, one after
        the other (a single planner: each plan starts when the one before it is
        done), each from the rest state the leg before it is planned to end in.
    plan_starts : int
        A leg planned ahead is solved from this many quasi-stable guesses, and
        the fastest result is kept.
    plan_quick : float or None
        The last of a leg's ``plan_starts`` is the quickest quasi-stable guess
        whose score is within this of the best's, m (``quasi_stable_guesses``'
        ``quick``; chosen from the simulated guesses ranked after the others,
        ``keep`` of them in all): the best few by score (the miss, plus 0.01 m
        per second of profile) are often long profiles that revolve on the
        way, and converge to slow legs.  None: the best by score only.
    refine_fresh : int
        A guess's refinement is also solved from this many fresh quasi-stable
        guesses from the same predicted start (their ``plan_guess_time`` and
        iterations are charged to the one planner); of all those ready in
        time, the one that arrives first takes over (at most 5).  The
        guess's tail alone often leads to a slow local optimum (the N-shape,
        seed 0: 4.73 s against 3.37 s from a fresh guess).
    plan_resumes : int
        If none of a leg's ``plan_starts`` converges, up to this many of them
        are solved again from where they stopped before the leg is given up
        for a stepping stone (``RestToRest.fastest``).
    stone_distance : float
        A leg from rest to a stop farther than this that cannot be planned is
        planned instead to a stepping stone this far towards the stop (a
        shorter leg converges far more often on a robot whose revolving
        radii are small); from the stone, the leg is planned again, m.
    plan_iteration_time, plan_guess_time : float
        Modelled compute time of one IPOPT iteration of a leg's plan, and of
        the quasi-stable guesses of a leg planned ahead, s: a plan is used only
        once that much simulated time has passed after it was started (with
        ``realtime``, its measured wall-clock time instead).  The defaults are
        the planner's measured times on a 2-core machine with a closed-loop run
        on the other core (``benchmarks/bench_planner.py --busy``), rounded up
        with room for a slower machine.
    entry_times : tuple of float
        Circles: durations tried, in order, for the planned entry onto the
        orbit (least effort in that time), s; those too short for
        ``entry_shift_speed`` are skipped.
    entry_shift_speed : float
        Circles: how fast an entry is taken to move the robot's revolving
        centre, m/s.  The entry tries the durations of ``entry_times`` from the
        shortest in which the ramp's centre can reach the orbit's at this speed
        (one half revolution at the fastest driving speed moves the centre by
        about twice the difference of the fastest revolving radius and the
        orbit's: of the order of 1.5 m in 4 s).
    entry_interval : float
        Circles: interval of the entry's grid, s.
    entry_handover : float
        Circles: the robot starts at once on a ramp up to the orbit's speed;
        the entry is planned ``tilt_settle`` s after the start, from where the
        ramp will be this long after that, and takes over there if it is ready
        (else it is planned again from further along), s.
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
        Settings of a circle's entry onto its orbit (its ``N`` follows the entry time; in CasADi's virtual
        machine, expanded: compiling its stages as C pays only over many circles, ``compiled=True``).
    gates : OCPSettings
        Settings of the plan through gates (``nmpc.gates``; its ``N`` is unused:
        each gate has ``GATE_INTERVALS``): the exact Hessian, and half the
        motor's speed left to the feedback (at 85 % the fast plan is tracked
        too loosely to pass every gate within 5 cm; at 60 % the bundled course
        passed on some machines and not on others, see the README).
    """

    N: int = 60
    h: float = 0.05
    substeps: int = 1
    solver: str = "rti"
    waypoint_weights: "TrackingWeights" = None
    hold_weights: "TrackingWeights" = None
    circle_weights: "TrackingWeights" = None
    torque_margin: float = 0.95
    speed_margin: float = 0.98
    constraints: tuple = ()
    normal_margin: float = 0.1
    friction_margin: float = 0.95
    max_failures: int = 6
    fallback: str = "brake"
    pid_time: float = 2.0
    estimate_tilt: bool = True
    learn: tuple = ("M", "m", "k0")
    learn_sigma: float = 0.1
    tilt_process_noise: float = 0.01
    gyro_sigma: float = 2e-3
    tilt_model_error: float = 0.1
    attitude_gain: float = 0.05
    hold_time: float = 0.3
    hold_radius: float = 0.05
    replan_distance: float = 0.15
    replan_angle: float = 0.2
    swung_angle: float = 0.8
    finish_hold: float = 1.0
    gate_weight: float = 2e4
    replan_interval: float = 1.0
    brake_weights: "TrackingWeights" = None
    brake_accel: float = 15.0
    brake_wait: float = 4.0
    recover_speed: float = 0.02
    recover_drive: float = 0.3
    plan_handovers: tuple = (1.2,)
    ride_accels: tuple = (2.0,)
    tilt_settle: float = 0.3
    plan_ahead: float = 0.0
    plan_iteration_time: float = 0.008
    plan_starts: int = 4
    plan_resumes: int = 3
    plan_quick: float | None = 0.25
    refine_fresh: int = 1
    legs_ahead: int = 2
    stone_distance: float = 0.6
    caution: float = 0.9
    caution_floor: float = 0.7
    plan_guess_time: float = 0.3
    entry_times: tuple = (5.0, 7.0, 10.0)
    entry_shift_speed: float = 0.35
    entry_interval: float = 0.1
    entry_handover: float = 3.0
    max_solve_time: float | None = None
    realtime: bool = False
    rti_step_time: float = 0.01
    ipopt_iteration_time: float = 0.01
    compiled: bool | None = None
    plan: OCPSettings = field(default_factory=lambda: OCPSettings(N=40, accel_margin=0.85, compiled=True, max_iter=150))
    entry: OCPSettings = field(default_factory=OCPSettings)
    gates: OCPSettings = field(default_factory=lambda: OCPSettings(accel_margin=0.85, speed_margin=0.5,
                                                                   hessian="exact"))

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
        from rollbot_oc.control.nmpc.estimation import check_filter  # (estimation needs no settings)

        object.__setattr__(self, "learn", tuple(self.learn))
        check_filter(self.learn, self.learn_sigma, self.attitude_gain, "NMPC ")
        if not (math.isfinite(self.swung_angle) and 0 < self.swung_angle <= math.pi):
            raise ValueError(f"NMPC swung_angle = {self.swung_angle!r} rad is out of range: valid is (0, pi]")
        if not (math.isfinite(self.entry_shift_speed) and self.entry_shift_speed > 0):
            raise ValueError(f"NMPC entry_shift_speed = {self.entry_shift_speed!r} m/s must be positive")
        object.__setattr__(self, "ride_accels", tuple(self.ride_accels))
        if not self.ride_accels or not all(isinstance(a, (int, float)) and math.isfinite(a) and a > 0
                                           for a in self.ride_accels):
            raise ValueError(f"NMPC ride_accels = {self.ride_accels!r} must be positive ramp rates, rad/s^2")
        if self.plan_quick is not None and not (isinstance(self.plan_quick, (int, float))
                                                and not isinstance(self.plan_quick, bool)
                                                and math.isfinite(self.plan_quick) and self.plan_quick >= 0):
            raise ValueError(f"NMPC plan_quick = {self.plan_quick!r} must be None or a distance >= 0 m")
        if not (isinstance(self.refine_fresh, int) and not isinstance(self.refine_fresh, bool)
                and 0 <= self.refine_fresh <= 5):
            raise ValueError(f"NMPC refine_fresh = {self.refine_fresh!r} must be a whole number in [0, 5]")
        if not (math.isfinite(self.h) and 0 < self.h <= 0.5):
            raise ValueError(f"NMPC h = {self.h!r} s is out of range: valid is (0, 0.5]")
