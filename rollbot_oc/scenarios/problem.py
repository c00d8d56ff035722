"""Scenario files (``problems/*.toml``), running them under a controller, and their metrics.

Schema (TOML; SI units, degrees only in keys ending in ``_deg``)::

    name        = "circle_R035"          # required: letters, digits, _ and - (it names the output files)
    description = "..."                  # optional
    kind        = "circle"               # required: a mission kind ("circle", "waypoints", "open_loop",
                                         # "gates"; rollbot_oc.missions.KINDS)
    duration    = 300.0                  # required: longest run, s, in [1, 3600]
    dt          = 0.01                   # optional: control period, s

    [start]                              # optional: where the robot rests at t = 0
    position    = [0.35, 0.0]            # m
    heading_deg = 0.0                    # azimuth of the motor axis' horizontal projection

    [floor]                              # optional: the floor the plant rolls on
    slope_deg     = 1.0
    slope_dir_deg = -45.0                # downhill direction
    mu            = 0.5                  # friction; with rolling_resistance (m), damping (N m s) and
                                         # [[floor.patches]] the shell may slide (rollbot_oc.simulation.floor)

    [<kind>]                             # required: the mission's table, its schema in its module:
                                         # rollbot_oc.missions.circle ([circle]: centre, radius, ...),
                                         # .waypoints ([waypoints]: stops, stop_tolerance),
                                         # .open_loop ([open_loop]: speeds, ramp_rate),
                                         # .gates ([gates]: points, tolerance)

    [sensor]                             # optional: how the controller learns the state (seeded)
    mode           = "mocap"             # "mocap" (default), "imu" or "imu+mocap"
    # mode "mocap": the controller sees motion capture, a gyroscope and the encoder directly
    position_noise = 0.001               # m
    angle_noise    = 0.003               # rad
    gyro_noise     = 0.0                 # rad/s
    speed_noise    = 0.0                 # rad/s
    latency        = 1                   # control periods
    # modes "imu" and "imu+mocap": the controller sees the estimator's estimate (rollbot_oc.simulation.ekf)
    encoder_counts = 4096                # counts per revolution
    [sensor.imu]                         # body-fixed IMU at the shell centre (rollbot_oc.simulation.sensors.ImuModel)
    rate                   = 100.0       # Hz, a whole multiple of the control rate
    gyro_noise_density_deg = 0.005       # deg/s/sqrt(Hz)
    gyro_bias_deg          = 0.5         # deg/s, bound of the initial bias on each axis
    gyro_bias_walk_deg     = 0.001       # deg/s/sqrt(s)
    accel_noise_density    = 0.00147     # m/s^2/sqrt(Hz) (150 ug/sqrt(Hz))
    accel_bias             = 0.098       # m/s^2, bound of the initial bias on each axis (10 mg)
    accel_bias_walk        = 0.0001      # m/s^2/sqrt(s)
    [sensor.mocap]                       # mode "imu+mocap" (rollbot_oc.simulation.sensors.MocapModel)
    rate           = 100.0               # Hz, its period a whole number of control periods
    latency        = 0.01                # s
    position_noise = 0.001               # m
    angle_noise    = 0.003               # rad
    outage_length  = 1.0                 # s, each outage
    outage_every   = 10.0                # s, outages start at 10, 20, 30, ... s (0: none)
    outage_times   = [35.0]              # s, further outage starts

    Each key of [sensor] serves the modes named above; a key the chosen mode
    does not use is refused (naming the mode that uses it).

    [params]                             # optional: robot parameter overrides (parameter-file keys)

Unknown keys and tables, missing required keys and impossible values are
rejected on load with a ``ConfigError`` (a ``ValueError``) naming the file,
the key and the valid range.  Each check is a small function beside the key
it checks (``_check_name``, ``check_duration``, ...; a
mission's table by its kind's ``from_table``).
"""

from __future__ import annotations

import warnings

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from rollbot_oc.model.dynamics import rest_state
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.simulation.ekf import EstimatorSettings
from rollbot_oc.simulation.floor import (DAMPING_RANGE, FLOOR_KEYS, MU_RANGE, PATCH_KEYS, ROLLING_RESISTANCE_RANGE,
                                         Floor, FloorPatch, RollbotDeprecationWarning)
from rollbot_oc.simulation.onboard import OnboardSensing
from rollbot_oc.missions import KINDS, REACH_HOLD, Mission, centre_of_curvature, mission_kind
from rollbot_oc.missions.schema import NAME_PATTERN
from rollbot_oc.missions.schema import check_keys as _check_keys
from rollbot_oc.missions.schema import number as _number
from rollbot_oc.missions.schema import point, points
from rollbot_oc.missions.schema import table as _table
from rollbot_oc.model.params import RollbotParams, read_toml
from rollbot_oc.core.progress import RunProgress, working
from rollbot_oc.simulation.sensors import MODES, EncoderModel, ImuModel, MocapModel, SensingConfig
from rollbot_oc.simulation.floor_plant import simulate
from rollbot_oc.simulation.plant import Sensor, SimulationResult
from rollbot_oc.view.text import comparison_row, comparison_table
from rollbot_oc.analysis.quasi_stable import RadiusMap

__all__ = ["Problem", "load_problem", "make_controller", "run_problem", "run_open_loop", "compute_metrics", "RunResult",
           "compare", "comparison_row", "comparison_table",  # the last two live in summary
           "CONTROLLERS", "REACH_HOLD", "DURATION_RANGE", "check_duration"]

CONTROLLERS = ("pid", "nmpc")
DURATION_RANGE = (1.0, 3600.0)  # s: a run's length, from a problem file or an option (--duration)

_COMMON_KEYS = {"name", "description", "kind", "duration", "dt", "start", "floor", "sensor", "params"}
_TABLE_KEYS = {  # the common tables; each mission kind's table has its own keys (``Mission.keys``)
    "start": {"position", "heading_deg"},
    "floor": set(FLOOR_KEYS),
    "sensor": {"mode", "position_noise", "angle_noise", "gyro_noise", "speed_noise", "latency", "encoder_counts",
               "imu", "mocap"},
}
_MOCAP_MODE_KEYS = ("position_noise", "angle_noise", "gyro_noise", "speed_noise", "latency")


@dataclass(frozen=True)
class Problem:
    """A scenario: robot, floor, start, mission and measurement model.

    Attributes
    ----------
    name, description : str
    kind : str
        The mission's kind (``mission.kind``).
    duration : float
        Longest run, s.
    dt : float
        Control period, s.
    params : RollbotParams
        The plant (slope included).
    start_position : numpy.ndarray (2,)
        Initial shell-centre position (at rest, pendulum down), m.
    start_heading : float
        Initial motor-axis azimuth, rad.
    mission : Mission
        What is asked, and how a run is measured (``rollbot_oc.missions``).
    sensor : dict
        ``Sensor`` settings (noise, latency) of mode ``"mocap"``; the seed comes with each run.
    sensing : SensingConfig
        The sensing mode and, for the onboard modes, the IMU, encoder and
        motion-capture models.
    source : str
        Where the problem came from (file path).
    floor : Floor
        What the floor adds to the no-slip model (Coulomb contact, rolling
        resistance, damping, patches); ``Floor()`` without ``[floor]`` keys
        beyond the slope.  Its friction coefficient is ``params.mu``.
    """

    name: str
    kind: str
    duration: float
    params: RollbotParams
    description: str = ""
    dt: float = 0.01
    start_position: np.ndarray = field(default_factory=lambda: np.zeros(2))
    start_heading: float = 0.0
    mission: Mission | None = None
    sensor: dict = field(default_factory=dict)
    sensing: SensingConfig = field(default_factory=SensingConfig)
    source: str = "<problem>"
    floor: Floor = field(default_factory=Floor)

    def initial_state(self) -> np.ndarray:
        """The start state: at rest at ``start_position`` with heading ``start_heading``."""
        return rest_state(self.params, position=self.start_position, heading=self.start_heading)

    def with_duration(self, duration: float) -> "Problem":
        """The same problem with another duration (s, in ``DURATION_RANGE``), for quick runs."""
        return replace(self, duration=check_duration(duration, "duration"))


def check_duration(value, where: str = "duration") -> float:
    """A run's length in s, checked against ``DURATION_RANGE`` (problem files and ``--duration`` alike).

    Parameters
    ----------
    value : float
        The duration, s.
    where : str
        Where it came from (``"--duration"``, ``"problem.toml: key 'duration'"``), for the message.

    Raises
    ------
    ConfigError
        If ``value`` is not a finite number in ``DURATION_RANGE``.
    """
    low, high = DURATION_RANGE
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{where} = {value!r} must be a finite number of seconds")
    if not low <= value <= high:
        raise ConfigError(f"{where} = {value!r} s is out of range: valid is [{low:g}, {high:g}] s")
    return float(value)


def _check_name(value, source: str) -> str:
    """The problem's ``name``: a plain identifier (it is the stem of every file a run writes)."""
    if not isinstance(value, str) or not NAME_PATTERN.fullmatch(value):
        raise ConfigError(f"{source}: key 'name' = {value!r} must be 1 to 64 letters, digits, '_' or '-' "
                          "(not starting with '-'); it names the output files")
    return value


def _check_damping(params: RollbotParams, source: str) -> None:
    """Scenarios need damping: the controllers and the open-loop theory use the quasi-stable states."""
    if not params.k0 > 0:
        raise ConfigError(f"{source} [params]: k0 = {params.k0!r} N m s: scenarios need damping k0 > 0 (the PID, "
                          "the NMPC and the open-loop theory use the quasi-stable states, which need it)")


def load_problem(path: str | Path, base: RollbotParams | None = None) -> Problem:
    """Read and validate a problem file (schema in the module doc).

    ``base`` is the robot the file's ``[params]`` and ``[floor]`` apply to
    (the paper's prototype by default).

    Raises
    ------
    ValueError
        Missing file, invalid TOML, unknown or missing keys, impossible values.
    """
    return problem_from_dict(read_toml(path, "problem file"), str(path), base)


def problem_from_dict(data: dict, source: str = "<problem>", base: RollbotParams | None = None) -> Problem:
    """Validate a problem given as a mapping (the parsed TOML); see ``load_problem``."""
    _check_keys(data, _COMMON_KEYS | set(KINDS), source)
    tables = {**_TABLE_KEYS, **{name: cls.keys for name, cls in KINDS.items()}}
    for table, keys in tables.items():
        _check_keys(_table(data, table, source), keys, f"{source} [{table}]")
    if "name" not in data:
        raise ConfigError(f"{source}: missing required key 'name'")
    name = _check_name(data["name"], source)
    kind = data.get("kind")
    mission_class = mission_kind(kind, source)
    if kind not in data:
        raise ConfigError(f"{source}: kind = '{kind}' needs a [{kind}] table")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise ConfigError(f"{source}: key 'description' = {description!r} must be a string")
    if "duration" not in data:
        raise ConfigError(f"{source}: missing required key 'duration'")
    duration = check_duration(data["duration"], f"{source}: key 'duration'")
    dt = _number(data, "dt", source, 1e-3, 0.1, default=0.01)
    params, floor = _problem_params(data, source, base)
    start = data.get("start", {})
    position = point(start, "position", f"{source} [start]")
    heading = math.radians(_number(start, "heading_deg", f"{source} [start]", -360.0, 360.0, default=0.0))
    sensor_table = data.get("sensor", {})
    sensor = {key: _number(sensor_table, key, f"{source} [sensor]", 0.0, 1.0) for key in
              ("position_noise", "angle_noise", "gyro_noise", "speed_noise") if key in sensor_table}
    if "latency" in sensor_table:
        sensor["latency"] = _number(sensor_table, "latency", f"{source} [sensor]", 0, 100, integer=True)
    sensing = _sensing(sensor_table, f"{source} [sensor]", dt)
    common = dict(name=name, kind=kind, duration=duration, dt=dt, params=params, description=description,
                  start_position=position, start_heading=heading, sensor=sensor, sensing=sensing, source=source,
                  floor=floor)
    mission = mission_class.from_table(data[kind], f"{source} [{kind}]", params, duration)
    return Problem(mission=mission, **common)


def _sensing(table: dict, where: str, dt: float) -> SensingConfig:
    """The ``[sensor]`` table's mode and onboard sensors, each key checked against the mode that uses it."""
    mode = table.get("mode", "mocap")
    if mode not in MODES:
        raise ConfigError(f"{where}: key 'mode' = {mode!r}; valid are {', '.join(repr(m) for m in MODES)}")
    onboard = mode != "mocap"
    unused = [key for key in _MOCAP_MODE_KEYS if key in table] if onboard else \
        [key for key in ("encoder_counts", "imu", "mocap") if key in table]
    if mode == "imu" and "mocap" in table:
        unused.append("mocap")
    if unused:
        users = {"mocap": "mode 'imu+mocap'", "imu": "modes 'imu' and 'imu+mocap'",
                 "encoder_counts": "modes 'imu' and 'imu+mocap'"}
        key = unused[0]
        user = users.get(key, "mode 'mocap'")
        raise ConfigError(f"{where}: key '{key}' is not used in mode {mode!r}: it serves {user}; "
                          "remove it or change 'mode'")
    imu = _sensor_model(ImuModel, _table(table, "imu", where), f"{where[:-1]}.imu]")
    mocap = _sensor_model(MocapModel, _table(table, "mocap", where), f"{where[:-1]}.mocap]")
    counts = _number(table, "encoder_counts", where, 16, 1 << 30, integer=True, default=4096)
    try:
        config = SensingConfig(mode, imu, EncoderModel(counts), mocap)
        config.check_period(dt)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return config


def _sensor_model(cls, table: dict, where: str):
    """A sensor model (``ImuModel``, ``MocapModel``) from its table: its ``FILE_KEYS`` in file units."""
    extra = {"outage_times"} if cls is MocapModel else set()
    _check_keys(table, set(cls.FILE_KEYS) | extra, where)
    values = {}
    for key, (attr, scale, low, high, _unit) in cls.FILE_KEYS.items():
        if key in table:
            values[attr] = _number(table, key, where, low, high) * scale
    if "outage_times" in table:
        times = table["outage_times"]
        if not (isinstance(times, list) and all(isinstance(t, (int, float)) and not isinstance(t, bool)
                                                and math.isfinite(t) and 0 <= t <= 3600 for t in times)):
            raise ConfigError(f"{where}: key 'outage_times' = {times!r} must be a list of times in [0, 3600] s")
        values["outage_times"] = tuple(float(t) for t in times)
    try:
        return cls(**values)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def _problem_params(data: dict, source: str, base: RollbotParams | None) -> tuple[RollbotParams, Floor]:
    """The robot and floor of a problem: ``[params]`` and ``[floor]`` on top of ``base``, derived defaults following.

    The floor's slope and friction go into the parameters (their one home);
    ``[params] mu`` still works, with a deprecation warning (``floor_from_table``).
    Checked for what every scenario needs (damping, see ``_check_damping``).
    """
    table = dict(_table(data, "params", source))
    floor, keys = floor_from_table(data, source)
    table.update(keys)
    params = RollbotParams.from_file_dict(table, source=f"{source} [params]", base=base)
    _check_damping(params, source)
    return params, floor


def make_controller(name: str, problem: Problem, params: RollbotParams | None = None, **options):
    """A controller by name for a problem.

    Parameters
    ----------
    name : {"pid", "nmpc"}
    problem : Problem
    params : RollbotParams, optional
        The robot the controller believes in; the problem's robot on a level
        floor by default (controllers do not know the slope; they must reject it).
    **options
        Passed to the controller (for the PID: ``gains=PIDGains(...)``).
    """
    believed = params or problem.params.replace(slope=0.0)
    if name == "pid":
        from rollbot_oc.control.pid import QuasiStablePID as controller  # start-up: only the chosen controller
    elif name == "nmpc":
        from rollbot_oc.control.nmpc import NMPC as controller  # is imported (the NMPC's modules take seconds)
    else:
        raise ConfigError(f"controller = {name!r}; valid are {', '.join(CONTROLLERS)}")
    try:
        return controller(problem.mission, believed, dt=problem.dt, **options)
    except ConfigError:
        raise
    except ValueError as exc:  # the constructors check the problem and robot they are given: a user's setting
        raise ConfigError(f"{problem.source}: the {name} controller cannot be built for this problem: {exc}") from None


@dataclass
class RunResult:
    """A controller's run on a problem: the simulation and its metrics."""

    problem: Problem
    controller: str
    seed: int
    result: SimulationResult
    metrics: dict
    centres: np.ndarray | None = None
    wall_time: float = 0.0
    references: list = field(default_factory=list)  # what the controller followed (its ``references``), for logs


def run_problem(problem: Problem, controller="pid", *, seed: int = 0, params: RollbotParams | None = None,
                duration: float | None = None, show_progress: bool | None = None,
                estimator: EstimatorSettings | None = None, kicks=(), label: str | None = None,
                **options) -> RunResult:
    """Run a circle or waypoint problem in closed loop and compute its metrics.

    Parameters
    ----------
    problem : Problem
    controller : str or Controller
        ``"pid"``, ``"nmpc"`` or a controller object.
    seed : int
        Seed of the sensor noise.
    params : RollbotParams, optional
        The controller's model of the robot (default: the plant's, level floor).
    duration : float, optional
        Override the problem's duration, s, in ``DURATION_RANGE``.
    show_progress : bool or None
        Progress on stderr (planning, then simulated time and stops reached):
        True shows it, False hides it, None only on a terminal (``progress``).
    kicks : sequence of simulate.Kick
        Sudden pushes and spins of the robot during the run.
    estimator : EstimatorSettings, optional
        The filter's settings in the onboard sensing modes (``problem.sensing``);
        the filter believes in the controller's model of the robot.
    label : str, optional
        The run's name for its controller (``controller`` in the metrics, file names): by default the name
        given, or the controller object's class name.
    **options
        Passed to ``make_controller``.

    Raises
    ------
    ConfigError
        On an open-loop problem, a duration out of range or a controller that
        cannot be built for the problem (before anything runs).
    """
    if not problem.mission.closed_loop:
        raise ConfigError(f"{problem.source}: open-loop problems have no controller; use run_open_loop")
    if duration is not None:
        problem = problem.with_duration(duration)
    name = label or (controller if isinstance(controller, str) else type(controller).__name__)
    ctrl = make_controller(controller, problem, params, **options) if isinstance(controller, str) else controller
    if problem.sensing.onboard:
        believed = params or problem.params.replace(slope=0.0)
        sensor = OnboardSensing(problem.sensing, believed, problem.dt, seed=seed, settings=estimator)
    else:
        sensor = Sensor(seed=seed, **problem.sensor)
    label = f"{problem.name} {name}"
    with working(f"{label}: planning", show_progress):  # offline planning happens before the run starts
        ctrl.prepare(problem.initial_state())
    stops = len(problem.mission.stops)
    with RunProgress(problem.duration, label, stops, show_progress) as progress:
        start = time.perf_counter()
        result = simulate(problem.initial_state(), problem.duration, params=problem.params,
                          controller=ctrl, dt=problem.dt, sensor=sensor, progress=progress if progress.shown else None,
                          kicks=kicks, floor=problem.floor)
        wall = time.perf_counter() - start
        progress.finish(float(result.t[-1]), result.info)
    centres = _centres(result, ctrl.map)
    metrics = compute_metrics(problem, result, centres)
    metrics.update({k: v for k, v in result.info.items() if k != "stops"})
    metrics.update(controller=name, seed=seed, wall_time=wall)
    return RunResult(problem, name, seed, result, metrics, centres, wall, list(getattr(ctrl, "references", [])))


def _centres(result: SimulationResult, radius_map) -> np.ndarray | None:
    """The paper's centre of curvature along a run (quasi-stable radius at the measured speed)."""
    if radius_map is None:
        radius_map = RadiusMap(result.params.replace(slope=0.0))
    radius = radius_map.radius(np.clip(result.driving_speed, 0.0, radius_map.omega_max))
    return centre_of_curvature(result.position, result.heading, radius)


def compute_metrics(problem: Problem, result: SimulationResult, centres=None) -> dict:
    """The metrics JSON of a run (SI units); see the README for every key."""
    t = result.t
    steps = result.step_times if result.step_times is not None and result.step_times.size else np.zeros(1)
    out = {
        "problem": problem.name,
        "completed": False,
        "completion_time": None,
        "avg_speed": None,
        "stop_errors": [],
        "avg_deviation": None,
        "max_deviation": None,
        "max_motor_torque": float(np.abs(result.motor_torque).max()) if result.motor_torque.size else 0.0,
        "max_driving_speed": float(np.abs(result.driving_speed).max()),
        "min_normal_force": float(result.normal_force.min()) if result.normal_force.size else None,
        "min_slide_margin": float(result.slide_margin.min()) if result.slide_margin.size else None,
        "step_time_min": float(steps.min()),
        "step_time_median": float(np.median(steps)),
        "step_time_p95": float(np.percentile(steps, 95)),
        "step_time_max": float(steps.max()),
        "events": [{"kind": e.kind, "time": e.time, "margin": e.margin} for e in result.events],
        "duration": float(t[-1]),
        "torque_limit_violation": bool(np.abs(result.motor_torque).max(initial=0.0) > problem.params.max_torque
                                       * (1 + 1e-6)),
        "speed_limit_violation": bool(np.abs(result.driving_speed).max() > problem.params.max_speed * (1 + 1e-9)),
        "sensing": problem.sensing.mode,
    }
    if result.estimation is not None:
        error = result.estimation.position_error(result.x)
        out.update(estimation_error_max=float(error.max()), estimation_error_final=float(error[-1]))
    if result.contact is not None:  # a floor that can slip: how much it did
        out.update(result.contact.metrics())
    out.update(problem.mission.metrics(result))
    out["completed"] = bool(out["completed"] and not result.events)
    return out


def run_open_loop(problem: Problem, show_progress: bool | None = None) -> dict:
    """Run an open-loop problem: each driving speed measured in simulation against the quasi-stable theory.

    ``show_progress``: a bar over the speeds on stderr, as for ``run_problem``.  The run and its
    result (a dict of measured and theoretical values per speed) are ``missions.OpenLoop.run``'s.
    """
    if problem.mission.closed_loop:
        raise ConfigError(f"{problem.source}: kind = '{problem.kind}' is not an open-loop problem")
    return problem.mission.run(problem, show_progress)


def compare(problem: Problem, seed: int = 0, params: RollbotParams | None = None,
            duration: float | None = None, show_progress: bool | None = None,
            nmpc_options: dict | None = None) -> list[RunResult]:
    """Run the PID baseline and the NMPC on the same problem, plant, noise and seed.

    ``show_progress`` as for ``run_problem``; ``nmpc_options`` go to the NMPC
    (e.g. ``settings``); the table is ``comparison_table``.
    """
    return [run_problem(problem, name, seed=seed, params=params, duration=duration, show_progress=show_progress,
                        **((nmpc_options or {}) if name == "nmpc" else {}))
            for name in ("pid", "nmpc")]


def floor_from_table(data: dict, source: str) -> tuple[Floor, dict]:
    """The ``[floor]`` and ``[params]`` tables of a scenario as a ``Floor`` and the parameter keys they set.

    Parameters
    ----------
    data : dict
        The whole scenario (its ``floor`` and ``params`` tables are read).
    source : str
        Where it came from, for messages.

    Returns
    -------
    (Floor, dict)
        The floor, and the parameter-file keys the floor sets
        (``slope_deg``, ``slope_dir_deg``, ``mu``) to merge into ``[params]``.

    Raises
    ------
    ConfigError
        One line naming the key, its value and the valid range; also when
        ``mu`` is set in both ``[floor]`` and ``[params]``.

    Warns
    -----
    RollbotDeprecationWarning
        For ``[params] mu`` (it keeps working: a rigid, no-slip floor of that friction).
    """
    table = data.get("floor", {})
    where = f"{source} [floor]"
    params = data.get("params", {}) if isinstance(data.get("params", {}), dict) else {}
    _check_keys(table, FLOOR_KEYS, where)
    keys = {key: _number(table, key, where) for key in ("slope_deg", "slope_dir_deg") if key in table}
    if "mu" in params:
        if "mu" in table:
            raise ConfigError(f"{source}: mu is set in both [floor] and [params]; keep [floor] mu only")
        warnings.warn(f"{source}: [params] mu is deprecated; write it as [floor] mu (the floor's friction, "
                      "which also lets the shell slide)", RollbotDeprecationWarning, stacklevel=3)
    coulomb = any(key in table for key in ("mu", "rolling_resistance", "damping", "patches"))
    if "mu" in table:
        keys["mu"] = _number(table, "mu", where, *MU_RANGE)
    resistance = _number(table, "rolling_resistance", where, *ROLLING_RESISTANCE_RANGE, default=0.0)
    damping = _number(table, "damping", where, *DAMPING_RANGE, default=0.0)
    patches = []
    raw = table.get("patches", [])
    if not (isinstance(raw, list) and all(isinstance(p, dict) for p in raw)):
        raise ConfigError(f"{where}: patches = {raw!r} must be an array of tables ([[floor.patches]])")
    for i, patch in enumerate(raw):
        here = f"{source} [[floor.patches]] #{i + 1}"
        _check_keys(patch, PATCH_KEYS, here)
        if "polygon" not in patch:
            raise ConfigError(f"{here}: missing required key 'polygon'")
        polygon = points(patch, "polygon", here)
        if len(polygon) < 3:
            raise ConfigError(f"{here}: key 'polygon' = {patch['polygon']!r} needs at least 3 [x, y] vertices")
        patches.append(FloorPatch(tuple(map(tuple, polygon)), _number(patch, "mu", here, *MU_RANGE),
                                  _number(patch, "rolling_resistance", here, *ROLLING_RESISTANCE_RANGE),
                                  _number(patch, "damping", here, *DAMPING_RANGE)))
    floor = Floor("coulomb", resistance, damping, tuple(patches)) if coulomb else Floor()
    return floor, keys
