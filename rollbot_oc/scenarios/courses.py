"""Seeded random waypoint courses for robustness studies: course, floor, robot, sensors and model error.

``random_course(seed, index)`` draws one course, fully determined by the
pair: ``numpy.random.SeedSequence(seed, spawn_key=(index,))`` spawns one
independent stream each for the course's geometry, its robot, its sensors
and model error, and the sensor noise of the run, so that narrowing one
range (say the robots') leaves the others' draws as they were.

What is drawn (uniformly, ranges in ``CourseRanges``):

* geometry: 3 to 8 stops in a 3 m square centred on the origin, every leg
  (the start to the first stop included) 0.3 to 3 m long; the start heading
  in [0, 360) deg;
* floor: a slope of 0 to 2 deg towards any direction;
* robot: ``phi`` 30 to 60 deg, ``m`` 0.2 to 0.45 kg, ``r0`` 0.07 to
  0.10 m, ``R`` 0.10 to 0.15 m with ``r0`` at least ``clearance`` inside the
  shell; the shell's mass and inertia scale with its size as a shell of the
  prototype's wall (``M_s`` with ``R^2``, ``I`` with ``R^4``), and the
  damping ``k0 = 0.4 M R^2`` and the torque limit ``r0 m g`` follow (the
  paper's rules, ``RollbotParams.with_changes``).  A robot whose quasi-stable
  analysis fails (its slow branch, plant's or model's, cannot be followed to
  the full driving speed, so no controller has a radius map) is drawn
  again; ``robot_draws`` counts the draws;
* sensors: position noise 1 to 3 mm, orientation noise 0.2 to 0.6 deg,
  latency 1 to 3 control periods;
* model error: the controller's model of the robot (``Course.believed``)
  has the shell's mass (``M_s`` and ``m_b``), the pendulum's mass and the
  damping ``k0`` each off the plant's by a factor in [0.9, 1.1]; it knows the
  plant's geometry and motor limits but not the slope.

Each course is a ``Problem`` (kind ``waypoints``) with a duration derived
from its length (``course_duration``), generous for the slow PID baseline.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from rollbot_oc.core.errors import ConfigError, NumericalFailure
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.core.reproducible import norm
from rollbot_oc.analysis.quasi_stable import RadiusMap
from rollbot_oc.scenarios.problem import problem_from_dict

__all__ = ["CourseRanges", "GateCourseRanges", "Course", "random_course", "random_gate_course", "course_duration",
           "DURATION_BASE", "DURATION_PER_METRE",
           "DURATION_PER_STOP"]

PROTOTYPE = RollbotParams()

# Duration of a course: about twice what the PID baseline, the slowest controller, takes on the paper's N-shape
# per metre (README, "Control"), with time to settle at every stop.
DURATION_BASE = 60.0  # s
DURATION_PER_METRE = 90.0  # s per m of the path through the stops
DURATION_PER_STOP = 15.0  # s per stop


@dataclass(frozen=True)
class CourseRanges:
    """The ranges courses are drawn from (uniformly); file units (m, kg, deg, mm).

    Attributes
    ----------
    stops : (int, int)
        Number of stops, inclusive.
    square : float
        Side of the square (centred on the origin) the start and the stops lie in, m.
    leg : (float, float)
        Length of every leg, m.
    slope_deg : (float, float)
        Floor inclination, deg (its direction is drawn in [0, 360) deg).
    phi_deg, m, r0, R : (float, float)
        Robot: arm angle (deg), pendulum mass (kg), pendulum radius (m), shell radius (m).
    clearance : float
        Least ``R - r0``, m: room for the pendulum mass inside the shell.
    position_noise_mm : (float, float)
        Standard deviation of the position measurement, mm.
    angle_noise_deg : (float, float)
        Standard deviation of the orientation measurement, deg.
    latency : (int, int)
        Measurement latency, control periods, inclusive.
    model_error : float
        Largest relative error of the controller's masses and damping (0.1: +-10 %).
    """

    stops: tuple = (3, 8)
    square: float = 3.0
    leg: tuple = (0.3, 3.0)
    slope_deg: tuple = (0.0, 2.0)
    phi_deg: tuple = (30.0, 60.0)
    m: tuple = (0.2, 0.45)
    r0: tuple = (0.07, 0.10)
    R: tuple = (0.10, 0.15)
    clearance: float = 0.015
    position_noise_mm: tuple = (1.0, 3.0)
    angle_noise_deg: tuple = (0.2, 0.6)
    latency: tuple = (1, 3)
    model_error: float = 0.10

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, tuple):
                low, high = value
                if not (math.isfinite(low) and math.isfinite(high) and 0 <= low <= high):
                    raise ConfigError(f"course ranges: {f.name} = {list(value)} must be [low, high] with "
                                      "0 <= low <= high")
        if self.leg[0] <= 0 or self.leg[0] > self.square:
            raise ConfigError(f"course ranges: leg = {list(self.leg)} m must start in (0, square = {self.square} m]")
        if self.stops[0] < 1 or int(self.stops[0]) != self.stops[0] or int(self.stops[1]) != self.stops[1]:
            raise ConfigError(f"course ranges: stops = {list(self.stops)} must be whole numbers >= 1")
        if self.latency[0] != int(self.latency[0]) or self.latency[1] != int(self.latency[1]):
            raise ConfigError(f"course ranges: latency = {list(self.latency)} must be whole numbers of periods")
        if not 0 <= self.model_error < 1:
            raise ConfigError(f"course ranges: model_error = {self.model_error!r} is out of range: valid is [0, 1)")
        if self.r0[0] > self.R[1] - self.clearance:
            raise ConfigError(f"course ranges: r0 = {list(self.r0)} m leaves no robot with R - r0 >= clearance = "
                              f"{self.clearance} m for R = {list(self.R)} m")

    @classmethod
    def from_dict(cls, data: dict, source: str = "course ranges") -> "CourseRanges":
        """Ranges from a mapping of field names to ``[low, high]`` (or a number for ``square``,
        ``clearance``, ``model_error``); missing fields keep their defaults.

        Raises
        ------
        ConfigError
            On an unknown key, a value of the wrong shape or an impossible range (naming ``source``).
        """
        known = {f.name: f for f in fields(cls)}
        unknown = sorted(set(data) - set(known))
        if unknown:
            raise ConfigError(f"{source}: unknown key(s) {', '.join(unknown)}; valid keys are {', '.join(known)}")
        values = {}
        for key, value in data.items():
            pair = isinstance(getattr(cls, key), tuple)
            ok = (isinstance(value, list) and len(value) == 2 and all(_is_number(v) for v in value)) if pair \
                else _is_number(value)
            if not ok:
                raise ConfigError(f"{source}: key '{key}' = {value!r} must be "
                                  f"{'[low, high], two finite numbers' if pair else 'a finite number'}")
            values[key] = tuple(float(v) for v in value) if pair else float(value)
        try:
            return cls(**values)
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}") from None


@dataclass(frozen=True)
class GateCourseRanges:
    """The ranges courses of gates are drawn from (uniformly); m, deg.

    Attributes
    ----------
    gates : (int, int)
        Number of gates, inclusive.
    spacing : (float, float)
        Distance of each gate from the point before it (the start for the first), m.
    max_turn_deg : float
        Largest turn of the direction from one leg to the next (the first from the start heading), deg.
    tolerance : float
        A gate counts as passed within this distance, m.
    course : CourseRanges
        The square, floor, robot, sensors and model error (``stops`` and ``leg`` unused).
    """

    gates: tuple = (3, 6)
    spacing: tuple = (0.4, 1.2)
    max_turn_deg: float = 120.0
    tolerance: float = 0.05
    course: CourseRanges = field(default_factory=CourseRanges)

    def __post_init__(self):
        low, high = self.gates
        if not (int(low) == low and int(high) == high and 1 <= low <= high):
            raise ConfigError(f"gate course ranges: gates = {list(self.gates)} must be whole numbers 1 <= low <= high")
        low, high = self.spacing
        if not (math.isfinite(low) and math.isfinite(high) and 0 < low <= high < self.course.square / 2):
            raise ConfigError(f"gate course ranges: spacing = {list(self.spacing)} m must be 0 < low <= high < "
                              f"half the square ({self.course.square / 2} m)")
        if not (math.isfinite(self.max_turn_deg) and 0 <= self.max_turn_deg <= 180):
            raise ConfigError(f"gate course ranges: max_turn_deg = {self.max_turn_deg!r} is out of range: valid is "
                              "[0, 180]")
        if not (math.isfinite(self.tolerance) and 0 < self.tolerance <= 0.5):
            raise ConfigError(f"gate course ranges: tolerance = {self.tolerance!r} m is out of range: valid is "
                              "(0, 0.5]")


def _is_number(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)


@dataclass(frozen=True)
class Course:
    """A random course and what the controller believes about the robot.

    Attributes
    ----------
    seed, index : int
        What the course was drawn from (``random_course(seed, index)``).
    problem : Problem
        The scenario: the plant (with its slope), start, stops, sensors, duration.
    believed : RollbotParams
        The controller's model of the robot (level floor, masses and damping off the plant's).
    noise_seed : int
        Seed of the run's sensor noise (``run_problem(..., seed=noise_seed)``).
    inputs : dict
        What was drawn, as plain numbers for a results table (file units: m, kg, deg, mm).
    """

    seed: int
    index: int
    problem: object
    believed: RollbotParams
    noise_seed: int
    inputs: dict = field(default_factory=dict)


def course_duration(length: float, stops: int) -> float:
    """A generous duration for a course of path length ``length`` (m) through ``stops`` stops, s, at most 3600."""
    return float(min(3600.0, DURATION_BASE + DURATION_PER_METRE * length + DURATION_PER_STOP * stops))


def _uniform(rng, pair) -> float:
    return float(rng.uniform(pair[0], pair[1]))


def _geometry(rng, ranges: CourseRanges):
    """Start, stops (m) and the start heading (rad), every leg within ``ranges.leg``."""
    half = ranges.square / 2
    start = rng.uniform(-half, half, 2)
    points = [start]
    for _ in range(int(rng.integers(ranges.stops[0], ranges.stops[1] + 1))):
        for _attempt in range(10_000):
            candidate = rng.uniform(-half, half, 2)
            if ranges.leg[0] <= norm(candidate - points[-1]) <= ranges.leg[1]:
                break
        else:  # pragma: no cover - a leg range this narrow in this square is practically impossible
            raise ConfigError(f"course ranges: no leg of {list(ranges.leg)} m found in a {ranges.square} m square")
        points.append(candidate)
    return start, points[1:], float(rng.uniform(0.0, 2 * math.pi))


def _analysable(params: RollbotParams) -> bool:
    """Whether the quasi-stable radius map of ``params`` (level floor) can be built up to full speed."""

    try:
        RadiusMap(params.replace(slope=0.0))
    except NumericalFailure:
        return False
    return True


def _robot(rng, ranges: CourseRanges) -> tuple[dict, int]:
    """Robot parameters (file keys, on top of the prototype) and how many draws it took."""
    for draws in range(1, 1001):
        R = _uniform(rng, ranges.R)
        r0 = _uniform(rng, ranges.r0)
        phi_deg = _uniform(rng, ranges.phi_deg)
        m = _uniform(rng, ranges.m)
        if r0 > R - ranges.clearance:
            continue
        scale = R / PROTOTYPE.R
        robot = {"R": R, "r0": r0, "phi_deg": phi_deg, "m": m, "M_s": PROTOTYPE.M_s * scale**2,
                 "I": PROTOTYPE.I * scale**4}
        if _analysable(RollbotParams.from_file_dict(robot)):
            return robot, draws
    raise NumericalFailure(f"course ranges: no robot with a quasi-stable radius map in 1000 draws from {ranges}")


def random_course(seed: int, index: int, ranges: CourseRanges | None = None):
    """The random course ``index`` of the family ``seed`` (see the module doc).

    Parameters
    ----------
    seed : int
        Seed of the family of courses, >= 0.
    index : int
        Which course of the family, >= 0.
    ranges : CourseRanges, optional
        What is drawn from (the defaults of the module doc).

    Returns
    -------
    Course
    """
    ranges = ranges or CourseRanges()
    geometry, robot_rng, sensing, noise = _streams(seed, index)
    start, stops, heading = _geometry(geometry, ranges)
    return _course(seed, index, ranges, geometry, robot_rng, sensing, noise, start, stops, heading, "waypoints")


def random_gate_course(seed: int, index: int, ranges: GateCourseRanges | None = None):
    """The random course of gates ``index`` of the family ``seed``: 3 to 6 gates (``GateCourseRanges``), each
    0.4 to 1.2 m from the one before (the first from the start) and turning at most 120 deg from the direction
    of the leg before; the floor, robot, sensors and model error drawn as for the stop courses
    (``ranges.course``), from independent streams of the same pair.

    Returns
    -------
    Course
        A ``gates`` problem; ``inputs`` has ``n_gates`` (no ``n_stops``).
    """
    ranges = ranges or GateCourseRanges()
    geometry, robot_rng, sensing, noise = _streams(seed, index)
    start, gates, heading = _gate_geometry(geometry, ranges)
    return _course(seed, index, ranges.course, geometry, robot_rng, sensing, noise, start, gates, heading, "gates",
                   tolerance=ranges.tolerance)


def _streams(seed: int, index: int):
    """Independent generators for the geometry, the robot, the sensors and the run's noise of course ``index``."""
    return tuple(np.random.default_rng(s) for s in np.random.SeedSequence(seed, spawn_key=(index,)).spawn(4))


def _gate_geometry(rng, ranges: GateCourseRanges):
    """Start, gates (m) and the start heading (rad): each gate ``ranges.spacing`` from the point before, turning
    at most ``ranges.max_turn_deg`` from the direction of the leg before (the start heading for the first)."""
    half = ranges.course.square / 2
    start = rng.uniform(-half / 2, half / 2, 2)
    heading = float(rng.uniform(0.0, 2 * math.pi))
    points, direction = [start], heading + math.pi / 2  # the shell rolls across its motor axis (the heading)
    for _ in range(int(rng.integers(ranges.gates[0], ranges.gates[1] + 1))):
        for _attempt in range(10_000):
            turn = math.radians(rng.uniform(-ranges.max_turn_deg, ranges.max_turn_deg))
            length = _uniform(rng, ranges.spacing)
            candidate = points[-1] + length * np.array([math.cos(direction + turn), math.sin(direction + turn)])
            if np.all(np.abs(candidate) <= half):
                break
        else:  # pragma: no cover - always possible for spacings shorter than the square
            raise ConfigError(f"gate course ranges: no gate {list(ranges.spacing)} m on in a {ranges.course.square} "
                              "m square")
        points.append(candidate)
        direction += turn
    return start, points[1:], heading


def _course(seed, index, ranges: CourseRanges, geometry, robot_rng, sensing, noise, start, targets, heading,
            kind: str, tolerance: float | None = None):
    """The ``Course`` of ``kind`` (``"waypoints"`` through stops, or ``"gates"``) on ``targets``, with its floor,
    robot, sensors and model error drawn from the given streams."""

    slope_deg, slope_dir_deg = _uniform(geometry, ranges.slope_deg), float(geometry.uniform(0.0, 360.0))
    # a robot the model error keeps analysable too (the controller builds its radius map from its model)
    draws = 0
    for _ in range(1000):
        robot, robot_draws = _robot(robot_rng, ranges)
        draws += robot_draws
        position_noise_mm = _uniform(sensing, ranges.position_noise_mm)
        angle_noise_deg = _uniform(sensing, ranges.angle_noise_deg)
        latency = int(sensing.integers(int(ranges.latency[0]), int(ranges.latency[1]) + 1))
        errors = sensing.uniform(-ranges.model_error, ranges.model_error, 3)
        plant_robot = RollbotParams.from_file_dict(robot)
        believed = plant_robot.replace(M_s=plant_robot.M_s * (1 + errors[0]), m_b=plant_robot.m_b * (1 + errors[0]),
                                       m=plant_robot.m * (1 + errors[1]), k0=plant_robot.k0 * (1 + errors[2]),
                                       max_torque=plant_robot.max_torque)
        if _analysable(believed):
            break
    else:  # pragma: no cover
        raise NumericalFailure(f"course {seed}/{index}: no analysable model of the robot in 1000 draws")
    path = [start] + list(targets)
    length = float(sum(norm(b - a) for a, b in zip(path[:-1], path[1:])))
    duration = course_duration(length, len(targets))
    name, noun = ("course", "stops") if kind == "waypoints" else ("gate_course", "gates")
    table = {
        "name": f"{name}_{seed}_{index}", "kind": kind, "duration": duration,
        "description": f"random {name.replace('_', ' ')} {index} of seed {seed}: {len(targets)} {noun}, {length:.2f} m",
        "start": {"position": start.tolist(), "heading_deg": math.degrees(heading)},
        "floor": {"slope_deg": slope_deg, "slope_dir_deg": slope_dir_deg},
        "sensor": {"position_noise": position_noise_mm * 1e-3, "angle_noise": math.radians(angle_noise_deg),
                   "latency": latency},
        "params": robot,
    }
    table["waypoints" if kind == "waypoints" else "gates"] = (
        {"stops": [s.tolist() for s in targets]} if kind == "waypoints"
        else {"points": [g.tolist() for g in targets], "tolerance": tolerance})
    problem = problem_from_dict(table, f"random {name.replace('_', ' ')} (seed {seed}, index {index})")
    inputs = {f"n_{noun}": len(targets), "length": length, "duration": duration, "slope_deg": slope_deg,
              "slope_dir_deg": slope_dir_deg, "phi_deg": robot["phi_deg"], "m": robot["m"], "r0": robot["r0"],
              "R": robot["R"], "position_noise_mm": position_noise_mm, "angle_noise_deg": angle_noise_deg,
              "latency": latency, "shell_mass_error": float(errors[0]), "pendulum_mass_error": float(errors[1]),
              "k0_error": float(errors[2]), "robot_draws": draws}
    return Course(seed, index, problem, believed, int(noise.integers(2**32)), inputs)
