"""Settings of the NMPC, nested by concern, frozen, every field validated (SI units).

``NMPCSettings`` holds one group per concern: ``horizon`` (the tracking problem's grid and solver),
``weights`` (what the tracking cost weighs in each mode), ``limits`` (the share of the robot's limits the
feedback may use), ``filter`` (the tilt and model filter), ``arrival`` (holding at a stop), ``recovery``
(fallbacks and getting back onto a plan), ``planner`` (legs and gate plans computed as the robot moves),
``entry`` (a circle's entry onto its orbit) and ``timing`` (the compute-time model).  A group may be given
as a dict of the fields it changes::

    NMPCSettings(horizon={"N": 30, "h": 0.1})
    NMPCSettings().replace(recovery={"max_failures": 3})

Every field is checked when its group is built (``rollbot_oc.core.checked``): a value out of range is a
one-line ``ConfigError`` naming the field, its value and the valid range.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace


from rollbot_oc.core.checked import Checked, choice, flag, functions, names, number, numbers, out_of_range, typed
from rollbot_oc.control.nmpc.estimation import LEARNABLE
from rollbot_oc.control.nmpc.weights import TrackingWeights
from rollbot_oc.planning.min_time import OCPSettings
from rollbot_oc.core.errors import ConfigError

__all__ = ["TrackingWeights", "Horizon", "Weights", "Limits", "FilterSettings", "Arrival", "Recovery",
           "PlannerSettings", "EntrySettings", "Timing", "NMPCSettings", "PRESETS"]


# -- the groups ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Horizon(Checked):
    """The tracking problem's grid and how it is solved.

    Attributes
    ----------
    N : int
        Shooting intervals of the horizon, in [2, 400].
    h : float
        Interval length and replanning period, s, in (0, 0.5]; a whole number of control periods.
    substeps : int
        RK4 steps per interval in the prediction, in [1, 10].
    solver : {"rti", "ipopt"}
        One real-time iteration per period (``"rti"``), or IPOPT to convergence (``"ipopt"``).
    compiled : bool or None
        RTI: evaluate the linearisation as compiled C (``rollbot_oc.model.codegen``); None: when a compiler exists.
    qp_max_iter : int
        RTI: the most active-set iterations of one QP (``qrqp``), in [1, 100000]: a bound on a solve's work
        where the active set cycles; a QP stopped there is judged, as any other, by its step's violation.
    """

    owner, group = "NMPC", "horizon"
    N: int = number(60, 2, 400, integer=True)
    h: float = number(0.05, 0.0, 0.5, open_low=True)
    substeps: int = number(1, 1, 10, integer=True)
    solver: str = choice("rti", "rti", "ipopt")
    compiled: bool | None = choice(None, None, True, False)
    qp_max_iter: int = number(1000, 1, 100000, integer=True)


@dataclass(frozen=True)
class Weights(Checked):
    """The tracking cost's weights in each mode.

    Attributes
    ----------
    legs : TrackingWeights
        On the way to a stop (``TrackingWeights.for_waypoints``).
    hold : TrackingWeights
        Holding at a stop once its leg has ended (``for_holding``).
    brake : TrackingWeights
        Bringing the robot to rest where it is (``for_braking``).
    circle : TrackingWeights
        On circles (``for_circles``).
    gate : float
        Gates: weight added on the position at the two horizon nodes around each planned passage, 1/m^2.
    """

    owner, group = "NMPC", "weights"
    legs: TrackingWeights = typed(TrackingWeights.for_waypoints, TrackingWeights)
    hold: TrackingWeights = typed(TrackingWeights.for_holding, TrackingWeights)
    brake: TrackingWeights = typed(TrackingWeights.for_braking, TrackingWeights)
    circle: TrackingWeights = typed(TrackingWeights.for_circles, TrackingWeights)
    gate: float = number(2e4, 0.0)


@dataclass(frozen=True)
class Limits(Checked):
    """The share of the robot's limits the tracking NMPC may use (fractions in (0, 1]).

    Attributes
    ----------
    torque_margin : float
        Of the motor's torque limit (more than the plans it tracks use: the rest is the feedback's).
    speed_margin : float
        Of the driving-speed limit.
    normal_margin : float
        Least normal force, as a fraction of the weight, in [0, 1).
    friction_margin : float
        Largest tangential force, as a fraction of ``mu`` times the normal force.
    constraints : tuple of callables
        More path constraints, each a function of an ``OCP`` returning a ``Constraint``
        (``rollbot_oc.planning.rollbot``), e.g. ``lambda ocp: position_box(ocp, (-0.1, -0.1), (1.3, 1.3))``:
        the legs, a circle's entry and the tracking problem all keep it (the tracking QP drops it, as the
        motor and contact limits, when no command can satisfy it).
    """

    owner, group = "NMPC", "limits"
    torque_margin: float = number(0.95, 0.0, 1.0, open_low=True)
    speed_margin: float = number(0.98, 0.0, 1.0, open_low=True)
    normal_margin: float = number(0.1, 0.0, 1.0, open_high=True)
    friction_margin: float = number(0.95, 0.0, 1.0, open_low=True)
    constraints: tuple = functions(())


@dataclass(frozen=True)
class FilterSettings(Checked):
    """The Kalman filter on the floor's tilt and the model's scale factors (``TiltEstimator``).

    Attributes
    ----------
    enabled : bool
        Estimate the floor tilt (offset-free); off gives the nominal model.
    learn : tuple of str
        Parameters (of ``control.nmpc.estimation.LEARNABLE``) whose scale factors the filter learns as the robot moves.
    learn_sigma : float
        Prior standard deviation of each learned factor, in (0, 0.3].
    process_noise : float
        Random-walk rate of the tilt estimate, 1/sqrt(s).
    gyro_sigma : float
        Assumed one-step prediction error of the angular velocity, rad/s.
    model_error : float
        Assumed relative error of the model's one-step change of the angular velocity.
    attitude_gain : float
        Fraction, each period, by which the attitude carried by the model moves to the measured one, in
        (0, 1]; 1 uses the measurement alone.
    settle : float
        Time after the start before the first plan on the estimated floor (the estimate settles), s.
    """

    owner, group = "NMPC", "filter"
    enabled: bool = flag(True)
    learn: tuple = names(("M", "m", "k0"), LEARNABLE)
    learn_sigma: float = number(0.1, 0.0, 0.3, open_low=True)
    process_noise: float = number(0.01, 0.0, open_low=True)
    gyro_sigma: float = number(2e-3, 0.0, open_low=True)
    model_error: float = number(0.1, 0.0)
    attitude_gain: float = number(0.05, 0.0, 1.0, open_low=True)
    settle: float = number(0.3, 0.0, 10.0)


@dataclass(frozen=True)
class Arrival(Checked):
    """At a stop.

    Attributes
    ----------
    hold_radius : float
        Past a leg's end within this distance of its stop, the robot is held where it arrived, m.
    hold_time : float
        How long past a leg's end a robot at rest outside its stop's tolerance waits before it gets a new
        leg to the same stop, s.
    finish_hold : float
        How long the robot is held at the last stop before the run is done, s.
    """

    owner, group = "NMPC", "arrival"
    hold_radius: float = number(0.05, 0.0)
    hold_time: float = number(0.3, 0.0)
    finish_hold: float = number(1.0, 0.0)


@dataclass(frozen=True)
class Recovery(Checked):
    """Fallbacks of the tracking step and recovery onto a plan.

    Attributes
    ----------
    max_failures : int
        Consecutive failed or late solves (the shifted plan followed meanwhile) before the fallback.
    fallback : {"brake", "pid"}
        Stops: ramp the motor's speed to zero and bring the robot to rest (``"brake"``), or the paper's PID
        towards the current stop for ``pid_time`` (``"pid"``).  Circles and gates always fall back to the PID.
    pid_time : float
        How long the PID keeps control after taking over, s.
    brake_accel : float
        Rate of the fallback's ramp of the motor's speed to zero, rad/s^2.
    brake_wait : float
        Longest wait for the robot to come to rest before its new leg is planned anyway, s.
    recover_speed, recover_drive : float
        At rest: shell-centre speed below ``recover_speed`` (m/s) and driving speed below ``recover_drive``
        (rad/s).
    replan_distance : float
        A robot farther than this from its plan is brought to rest and gets a new leg, m; a leg planned ahead
        is followed only if it starts within this of the robot.
    replan_interval : float
        Least time on a leg before the robot may be found off its plan, s.
    replan_angle : float
        A leg planned ahead is followed only if it starts with the robot's attitude within this angle, rad.
    swung_angle : float
        A robot at rest turned more than this from its balanced rest is held at that rest instead, rad, in
        (0, pi].
    caution, caution_floor : float
        After each recovery, later legs from rest have their speed and acceleration limits scaled by
        ``caution`` once more, down to ``caution_floor`` (both in (0, 1]).
    stone_distance : float
        A leg from rest farther than this that cannot be planned goes to a stepping stone this far towards
        its stop first, m.
    """

    owner, group = "NMPC", "recovery"
    max_failures: int = number(6, 1, 100, integer=True)
    fallback: str = choice("brake", "brake", "pid")
    pid_time: float = number(2.0, 0.0, open_low=True)
    brake_accel: float = number(15.0, 0.0, open_low=True)
    brake_wait: float = number(4.0, 0.0, open_low=True)
    recover_speed: float = number(0.02, 0.0, open_low=True)
    recover_drive: float = number(0.3, 0.0, open_low=True)
    replan_distance: float = number(0.15, 0.0, open_low=True)
    replan_interval: float = number(1.0, 0.0)
    replan_angle: float = number(0.2, 0.0, math.pi, open_low=True)
    swung_angle: float = number(0.8, 0.0, math.pi, open_low=True)
    caution: float = number(0.9, 0.0, 1.0, open_low=True)
    caution_floor: float = number(0.7, 0.0, 1.0, open_low=True)
    stone_distance: float = number(0.6, 0.0, open_low=True)


@dataclass(frozen=True)
class PlannerSettings(Checked):
    """Plans computed as the robot moves: legs between stops, and plans through gates.

    Attributes
    ----------
    handovers : tuple of float
        A leg started on its quasi-stable guess is refined from where the robot will be each of these times
        later, s; of the refinements ready in time, the one that arrives first takes over.
    ride_accels : tuple of float
        Ramp rates of the quasi-stable guesses a leg starts on at once, rad/s^2.
    ahead : float
        Fraction of the current leg gone by when the next leg is planned, in [0, 1].
    legs_ahead : int
        Legs beyond the current one planned ahead, one after the other, in [0, 10].
    starts : int
        Quasi-stable guesses a leg from rest is solved from (the fastest result kept), in [1, 10].
    resumes : int
        Starts solved again from where they stopped if none converged, in [0, 10].
    quick : float or None
        The last start is the quickest guess whose score is within this of the best's, m; None: by score.
    fresh : int
        Fresh quasi-stable guesses a refinement is also solved from, in [0, 5].
    legs : OCPSettings
        The minimum-time legs (a coarse grid, compiled stages, 15 % of the motor's acceleration left to the
        feedback, at most 150 IPOPT iterations per start).
    gates : OCPSettings
        The plan through gates (exact Hessian, half the motor's speed left to the feedback).
    """

    owner, group = "NMPC", "planner"
    handovers: tuple = numbers((1.2,), 0.0, 60.0)
    ride_accels: tuple = numbers((2.0,), 0.0, 1e3)
    ahead: float = number(0.0, 0.0, 1.0)
    legs_ahead: int = number(2, 0, 10, integer=True)
    starts: int = number(4, 1, 10, integer=True)
    resumes: int = number(3, 0, 10, integer=True)
    quick: float | None = number(0.25, 0.0, optional=True)
    fresh: int = number(1, 0, 5, integer=True)
    legs: OCPSettings = typed(lambda: OCPSettings(N=40, accel_margin=0.85, compiled=True, max_iter=150), OCPSettings)
    gates: OCPSettings = typed(lambda: OCPSettings(accel_margin=0.85, speed_margin=0.5, hessian="exact"),
                                OCPSettings)


@dataclass(frozen=True)
class EntrySettings(Checked):
    """A circle's entry onto its orbit.

    Attributes
    ----------
    times : tuple of float
        Durations tried in order for the entry (least effort in that time), s.
    shift_speed : float
        How fast an entry is taken to move the robot's revolving centre, m/s: durations too short for it
        are skipped.
    interval : float
        Interval of the entry's grid, s.
    handover : float
        The entry starts from where the ramp up to the orbit's speed will be this long after it is planned, s.
    ocp : OCPSettings
        Settings of the entry's problem (its ``N`` follows the entry's duration).
    """

    owner, group = "NMPC", "entry"
    times: tuple = numbers((5.0, 7.0, 10.0), 0.0, 600.0)
    shift_speed: float = number(0.35, 0.0, open_low=True)
    interval: float = number(0.1, 0.0, 1.0, open_low=True)
    handover: float = number(3.0, 0.0, open_low=True)
    ocp: OCPSettings = typed(OCPSettings, OCPSettings)


@dataclass(frozen=True)
class Timing(Checked):
    """The compute-time model: what decides when a solve is late and when a plan is ready.

    Attributes
    ----------
    realtime : bool
        Judge by the wall clock (a robot); off, by the modelled times below, so that a simulated run does
        not depend on how busy the machine is (the measured times are still reported).
    max_solve_time : float or None
        A solve longer than this is late and not used, s; None: the interval ``h``.
    rti_step : float
        Modelled time of one real-time iteration, s.
    ipopt_iteration : float
        Modelled time of one IPOPT iteration of the tracking problem, s.
    plan_iteration : float
        Modelled time of one IPOPT iteration of a plan, s.
    plan_guess : float
        Modelled time of the quasi-stable guesses of a leg, s.
    """

    owner, group = "NMPC", "timing"
    realtime: bool = flag(False)
    max_solve_time: float | None = number(None, 0.0, open_low=True, optional=True)
    rti_step: float = number(0.01, 0.0)
    ipopt_iteration: float = number(0.01, 0.0)
    plan_iteration: float = number(0.008, 0.0)
    plan_guess: float = number(0.3, 0.0)


_GROUPS = {"horizon": Horizon, "weights": Weights, "limits": Limits, "filter": FilterSettings,
           "arrival": Arrival, "recovery": Recovery, "planner": PlannerSettings, "entry": EntrySettings,
           "timing": Timing}


@dataclass(frozen=True)
class NMPCSettings:
    """Settings of the NMPC, one group per concern (module doc); a group may be given as a dict.

    Attributes
    ----------
    horizon : Horizon
        The tracking problem's grid and solver.
    weights : Weights
        The tracking cost's weights on legs, holding, braking, circles and gates.
    limits : Limits
        The share of the robot's limits the tracking may use, and more path constraints.
    filter : FilterSettings
        The tilt and model filter.
    arrival : Arrival
        Holding at a stop.
    recovery : Recovery
        Fallbacks, and getting back onto a plan.
    planner : PlannerSettings
        Legs and gate plans computed as the robot moves.
    entry : EntrySettings
        A circle's entry onto its orbit.
    timing : Timing
        The compute-time model.
    """

    horizon: Horizon = field(default_factory=Horizon)
    weights: Weights = field(default_factory=Weights)
    limits: Limits = field(default_factory=Limits)
    filter: FilterSettings = field(default_factory=FilterSettings)
    arrival: Arrival = field(default_factory=Arrival)
    recovery: Recovery = field(default_factory=Recovery)
    planner: PlannerSettings = field(default_factory=PlannerSettings)
    entry: EntrySettings = field(default_factory=EntrySettings)
    timing: Timing = field(default_factory=Timing)

    def __post_init__(self):
        for name, cls in _GROUPS.items():
            value = getattr(self, name)
            if isinstance(value, dict):
                object.__setattr__(self, name, _group_from(cls, name, value))
            elif not isinstance(value, cls):
                raise out_of_range("NMPC", name, value, f"a {cls.__name__} or a dict of its fields")

    def replace(self, **groups) -> "NMPCSettings":
        """These settings with the fields given per group changed, e.g. ``replace(horizon={"N": 30})``
        (a group object replaces the whole group)."""
        unknown = sorted(set(groups) - set(_GROUPS))
        if unknown:
            raise ConfigError(f"NMPC settings have no group {unknown[0]!r}: valid are {', '.join(_GROUPS)}")
        changed = {name: (_group_from(_GROUPS[name], name, value, getattr(self, name))
                          if isinstance(value, dict) else value) for name, value in groups.items()}
        return replace(self, **changed)

    @classmethod
    def embedded(cls) -> "NMPCSettings":
        """For a robot's processor: 25 intervals of 0.12 s with one RK4 step each (the same 3 s horizon),
        at most 100 active-set iterations per QP (a bounded worst case where the active set cycles), 3 failed
        solves before the fallback, and a filter that learns the tilt alone from the measured attitude
        (``rollbot-oc export-c``)."""
        return cls(horizon={"N": 25, "h": 0.12, "substeps": 1, "qp_max_iter": 100}, recovery={"max_failures": 3},
                   filter={"learn": (), "attitude_gain": 1.0})

    @classmethod
    def preset(cls, name: str) -> "NMPCSettings":
        """The preset ``name`` (``PRESETS``): ``"nmpc"`` the defaults, ``"embedded"`` ``embedded()``.

        Raises
        ------
        ConfigError
            If ``name`` is not a preset.
        """
        if name not in PRESETS:
            raise ConfigError(f"NMPC settings preset {name!r}: valid are {', '.join(PRESETS)}")
        return cls.embedded() if name == "embedded" else cls()

    def preset_name(self) -> str | None:
        """The name of the preset these settings are (``PRESETS``), or None."""
        return next((name for name in PRESETS if self == self.preset(name)), None)


PRESETS = ("nmpc", "embedded")  # NMPCSettings.preset: the defaults, and those for a robot's processor


def _group_from(cls, name: str, values: dict, base=None):
    """The group ``cls`` with the fields of ``values`` (over ``base``, else the defaults); an unknown field
    is a one-line ``ConfigError`` listing the valid ones."""
    valid = [f.name for f in fields(cls)]
    unknown = [key for key in values if key not in valid]
    if unknown:
        raise ConfigError(f"NMPC {name} has no field {unknown[0]!r}: valid are {', '.join(valid)}")
    return replace(base, **values) if base is not None else cls(**values)
