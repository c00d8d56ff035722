"""Closed-loop cases: a controller on a random course (``rollbot_oc.scenarios.courses``), or the course's time bound.

Spec table::

    [closed_loop]
    courses        = 100               # number of random courses, in [1, 100000]
    first_course   = 0                 # index of the first course (random_course(seed, index)), >= 0
    controllers    = ["pid", "nmpc"]   # each runs every course; "bound" adds the minimum-time bound
    stop_tolerance = 0.07              # m: a stop further than this from its waypoint fails the run
    duration       = 600.0             # optional, s, in [1, 3600]: every course's duration (default:
                                       # derived from the course's length, rollbot_oc.scenarios.courses)
    [closed_loop.ranges]               # optional: narrower ranges to draw from (CourseRanges fields)
    slope_deg = [0.0, 1.0]

The courses are ``random_course(seed, index)`` with the campaign's seed:
every controller meets the same course, robot, floor, model error and sensor
noise.  A run *succeeds* when it completed (every stop reached, no contact
event), every stop is within ``stop_tolerance`` of its waypoint and neither
the motor's torque nor its speed limit was exceeded; otherwise its row says
why (``error``).  The pseudo-controller ``bound`` computes the course's
minimum-time bound (``rollbot_oc.scenarios.bounds``) on the plant, so that the
summary can divide each run's completion time by it.
"""

from __future__ import annotations

import numpy as np

from rollbot_oc.campaign.case import Outcome, describe, register
from rollbot_oc.scenarios.courses import CourseRanges, random_course
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.scenarios.problem import CONTROLLERS, _check_keys, _number, check_duration
from rollbot_oc.campaign import figures
from rollbot_oc.campaign.summary import quantiles
from rollbot_oc.scenarios.bounds import minimum_time_bound
from rollbot_oc.scenarios.problem import run_problem

__all__ = ["ClosedLoopKind", "BOUND"]

BOUND = "bound"  # the pseudo-controller: the course's minimum-time bound
MAX_COURSES = 100_000

COURSE_COLUMNS = ("n_stops", "length", "duration", "slope_deg", "slope_dir_deg", "phi_deg", "m", "r0", "R",
                  "position_noise_mm", "angle_noise_deg", "latency", "shell_mass_error", "pendulum_mass_error",
                  "k0_error", "robot_draws")
# run metrics copied from the run's metrics when the controller reports them (the NMPC's solver counts)
SOLVER_COLUMNS = ("failed_solves", "cold_retries", "late_solves", "fallback_shifted", "fallback_brake", "fallback_pid",
                  "brakes", "stop_replans", "stones", "plan_failures", "plan_time", "plan_wait", "stop_wait")


@register
class ClosedLoopKind:
    """Controllers on random courses (see the module doc).

    Parameters
    ----------
    seed : int
        The family of courses (the campaign's seed).
    courses : int
        How many courses.
    first_course : int
        Index of the first.
    controllers : sequence of str
        ``"pid"``, ``"nmpc"`` and/or ``"bound"``.
    stop_tolerance : float
        Largest stop error of a successful run, m.
    duration : float or None
        Every course's duration, s (None: each course's own).
    ranges : CourseRanges or None
        What the courses are drawn from.
    """

    name = "closed_loop"
    group = "controller"
    input_columns = ("course", "controller") + COURSE_COLUMNS
    metric_columns = ("completed", "completion_time", "stops_reached", "max_stop_error", "mean_stop_error",
                      "stop_errors", "avg_speed", "max_torque_ratio", "max_driving_speed", "min_normal_force",
                      "min_slide_margin", "torque_limit_violation", "speed_limit_violation", "events",
                      "bound_legs") + SOLVER_COLUMNS

    def __init__(self, seed: int = 0, courses: int = 10, first_course: int = 0, controllers=("pid",),
                 stop_tolerance: float = 0.07, duration: float | None = None, ranges: CourseRanges | None = None):
        self.seed, self.courses, self.first_course = seed, courses, first_course
        self.controllers = tuple(controllers)
        self.stop_tolerance, self.duration = stop_tolerance, duration
        self.ranges = ranges or CourseRanges()

    @classmethod
    def from_spec(cls, table: dict, source: str, seed: int = 0) -> "ClosedLoopKind":
        """The kind from its ``[closed_loop]`` table (see the module doc)."""
        _check_keys(table, {"courses", "first_course", "controllers", "stop_tolerance", "duration", "ranges"},
                    source)
        courses = _number(table, "courses", source, 1, MAX_COURSES, integer=True, default=10)
        first = _number(table, "first_course", source, 0, 2**31, integer=True, default=0)
        controllers = table.get("controllers", ["pid"])
        valid = CONTROLLERS + (BOUND,)
        if not (isinstance(controllers, list) and controllers and all(c in valid for c in controllers)
                and len(set(controllers)) == len(controllers)):
            raise ConfigError(f"{source}: key 'controllers' = {controllers!r} must be a list of distinct names "
                              f"from {', '.join(valid)}")
        tolerance = _number(table, "stop_tolerance", source, 1e-3, 10.0, default=0.07)
        duration = check_duration(table["duration"], f"{source}: key 'duration'") if "duration" in table else None
        ranges = table.get("ranges", {})
        if not isinstance(ranges, dict):
            raise ConfigError(f"{source}: 'ranges' = {ranges!r} must be a table ([closed_loop.ranges])")
        return cls(seed, courses, first, controllers, tolerance, duration,
                   CourseRanges.from_dict(ranges, f"{source} [ranges]"))

    def settings(self) -> dict:
        """The course family, tolerance, duration and ranges (a case's inputs name its course and controller)."""
        return {"seed": self.seed, "stop_tolerance": self.stop_tolerance, "duration": self.duration,
                "ranges": {k: list(v) if isinstance(v, tuple) else v for k, v in vars(self.ranges).items()}}

    def case_inputs(self) -> list[dict]:
        """Every course with every controller (course-major)."""
        return [{"course": index, "controller": controller}
                for index in range(self.first_course, self.first_course + self.courses)
                for controller in self.controllers]

    def run(self, inputs: dict, seed: int) -> Outcome:
        """Draw the course and run its controller (or plan its bound)."""
        course = random_course(self.seed, inputs["course"], self.ranges)
        problem = course.problem if self.duration is None else course.problem.with_duration(self.duration)
        drawn = {**course.inputs, "duration": problem.duration}
        try:
            if inputs["controller"] == BOUND:
                return self._bound(problem, drawn)

            run = run_problem(problem, inputs["controller"], seed=course.noise_seed, params=course.believed)
        except Exception as exc:  # the row keeps what was drawn, and the error
            return Outcome(inputs=drawn, error=describe(exc))
        return self._judge(problem, run.metrics, drawn)

    @staticmethod
    def _bound(problem, drawn: dict) -> Outcome:
        bound = minimum_time_bound(problem.params, problem.initial_state(), problem.mission.stops)
        stops = len(problem.mission.stops)
        # what the stop rule adds to any run: the time at rest at each stop before it counts as reached
        dwell = stops * problem.mission.stop_rule.hold
        return Outcome({"completed": True, "completion_time": bound.total, "stops_reached": stops,
                        "bound_legs": list(bound.legs), "dwell": dwell}, drawn)

    def _judge(self, problem, m: dict, drawn: dict) -> Outcome:
        """The run's metrics and, if it did not succeed, why."""
        errors = [float(e) for e in m.get("stop_errors", [])]
        stops = len(problem.mission.stops)
        metrics = {
            "completed": bool(m["completed"]), "completion_time": m.get("completion_time"),
            "stops_reached": len(errors), "max_stop_error": max(errors, default=None),
            "mean_stop_error": sum(errors) / len(errors) if errors else None, "stop_errors": errors,
            "avg_speed": m.get("avg_speed"), "max_torque_ratio": m["max_motor_torque"] / problem.params.max_torque,
            "max_driving_speed": m["max_driving_speed"], "min_normal_force": m["min_normal_force"],
            "min_slide_margin": m["min_slide_margin"], "torque_limit_violation": m["torque_limit_violation"],
            "speed_limit_violation": m["speed_limit_violation"],
            "events": "; ".join(f"{e['kind']} at {e['time']:.2f} s" for e in m.get("events", [])) or None,
            **{key: m.get(key) for key in SOLVER_COLUMNS},
        }
        causes = []
        if metrics["events"]:
            causes.append(f"left the no-slip model: {metrics['events']}")
        if not m["completed"] and len(errors) < stops:
            causes.append(f"reached {len(errors)} of {stops} stops in {problem.duration:.0f} s")
        causes += [f"stop {i + 1} missed by {e:.3f} m (tolerance {self.stop_tolerance:g} m)"
                   for i, e in enumerate(errors) if e > self.stop_tolerance]
        if m["torque_limit_violation"]:
            causes.append(f"motor torque above its limit ({metrics['max_torque_ratio']:.3f} of it)")
        if m["speed_limit_violation"]:
            causes.append(f"driving speed above its limit ({m['max_driving_speed']:.3f} rad/s)")
        if not causes and not m["completed"]:
            causes.append("not completed")
        return Outcome(metrics, drawn, "; ".join(causes) or None)

    def summarise(self, table) -> dict:
        """Per controller (``controllers``): success rate, stop errors (m, every stop reached), completion times
        (s, successful runs) and their ratios to the course's bound (``time_ratio``) and to the bound plus the
        stop rule's dwell (``time_ratio_dwell``: the rest time each stop asks for, which no run can avoid);
        ``bound``: the bounds planned (s)."""

        ratios, with_dwell = time_ratios(table), time_ratios(table, dwell=True)
        out, bound = {}, {}
        for controller in self.controllers:
            rows = table[table["controller"] == controller]
            ok = rows["status"] == "succeeded"
            if controller == BOUND:
                bound = {"courses": len(rows), "planned": int(ok.sum()),
                         **quantiles(rows["completion_time"][ok], "bound")}
                continue
            errors = stop_errors(rows)
            out[controller] = {"runs": len(rows), "succeeded": int(ok.sum()),
                               "success_rate": float(ok.mean()) if len(rows) else None,
                               **quantiles(errors, "stop_error"),
                               **quantiles(rows["completion_time"][ok], "completion_time"),
                               **quantiles(ratios[rows.index][ok], "time_ratio"),
                               **quantiles(with_dwell[rows.index][ok], "time_ratio_dwell")}
        return {"controllers": out, **({"bound": bound} if bound else {})}

    def figures(self, table, folder) -> list:
        """Success rate against each varied input, histograms of stop errors and of time ratios."""

        runs = table[table["controller"] != BOUND]
        ratios = time_ratios(table)
        with_ratio = bool(ratios.notna().any())
        errors, times = {}, {}
        for controller in (c for c in self.controllers if c != BOUND):
            rows = runs[(runs["controller"] == controller)]
            errors[controller] = stop_errors(rows)
            ok = rows[rows["status"] == "succeeded"]
            times[controller] = (ratios[ok.index] if with_ratio else ok["completion_time"]).dropna().tolist()
        return [figures.plot_success_rates(runs, self.input_columns[2:], "controller", folder / "success_rates.png"),
                figures.plot_closed_loop_histograms(errors, times, self.stop_tolerance, with_ratio,
                                                    folder / "stop_errors_and_times.png")]


def stop_errors(rows) -> list[float]:
    """Every stop error (m) of the runs ``rows`` (a table's rows), in order."""
    return [float(e) for errors in rows["stop_errors"] if hasattr(errors, "__len__") for e in errors]


def time_ratios(table, dwell: bool = False):
    """Each run's completion time over its course's minimum-time bound (a ``pandas.Series`` on the table's
    index; NaN where the course has no bound, for the bound rows and for runs without a completion time);
    ``dwell``: over the bound plus the stop rule's time at rest at every stop (NaN where the bound rows do not
    record it)."""
    bounds = table[(table["controller"] == BOUND) & (table["status"] == "succeeded")].set_index("course")
    total = bounds["completion_time"].astype(float)
    if dwell:
        total = total + (bounds["dwell"].astype(float) if "dwell" in bounds else np.nan)
    ratio = table["completion_time"].astype(float) / table["course"].map(total).astype(float)
    return ratio.where(table["controller"] != BOUND)
