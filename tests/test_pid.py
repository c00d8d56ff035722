"""The paper's quasi-stable PID baseline on the paper's experiments (full plant, 1 deg slope, 100 Hz)."""

import math
from pathlib import Path

import numpy as np
import pytest

from rollbot_oc.missions import Circle, Waypoint, Waypoints
from rollbot_oc.control.pid import PIDGains, QuasiStablePID
from rollbot_oc.control.waypoints import StopPredictor
from rollbot_oc.analysis.experiments import open_loop_run
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.scenarios.problem import load_problem, run_open_loop, run_problem
from rollbot_oc.analysis.quasi_stable import RadiusMap, quasi_stable_state
from rollbot_oc.simulation.plant import simulate

from shared import same_problem

PROBLEMS = Path(__file__).parent.parent / "problems"


@pytest.mark.parametrize("name", ["circle_R020", "circle_R035", "circle_R050", "circle_R065"])
def test_circle_tracking_on_the_slope(name, pid_circle_run):
    run = pid_circle_run(name)  # shared with the slope-drift test below
    assert same_problem(run.problem, load_problem(PROBLEMS / f"{name}.toml")) and run.seed == 0
    m = run.metrics
    assert m["completed"]
    assert m["avg_deviation"] <= 0.034 and m["max_deviation"] <= 0.15  # the paper's real-world figures
    assert not m["torque_limit_violation"] and not m["speed_limit_violation"]
    assert m["min_normal_force"] > 0 and m["min_slide_margin"] > 0


def test_n_shape_stops(n_shape_pid_run):
    problem, run = n_shape_pid_run  # the session's shared PID run (seed 0) of the bundled N-shape
    assert same_problem(problem, load_problem(PROBLEMS / "n_shape.toml")) and run.controller == "pid"
    m = run.metrics
    assert m["completed"] and len(m["stop_errors"]) == 4
    assert max(m["stop_errors"]) <= 0.07  # paper: every stop within 7 cm
    assert m["completion_time"] < load_problem(PROBLEMS / "n_shape.toml").duration
    assert m["avg_speed"] > 0.005


def test_approach_reports_its_average_speed():
    m = run_problem(load_problem(PROBLEMS / "approach.toml"), "pid").metrics
    assert m["completed"] and m["reach_time"] > 0
    assert 0.005 < m["avg_speed"] < 0.2  # paper: about 2 cm/s
    assert m["avg_deviation"] <= 0.034


def test_open_loop_problem_matches_the_quasi_stable_theory():
    out = run_open_loop(load_problem(PROBLEMS / "open_loop.toml"))
    assert out["completed"] and [r["omega0"] for r in out["runs"]][0] == 0.5
    assert out["max_R0_error"] <= 0.02
    assert max(abs(r["xi_error"]) for r in out["runs"]) < math.radians(1.0)


def test_slope_drift_without_feedback_and_its_removal_by_the_pid(pid_circle_run):
    sloped = RollbotParams(slope=math.radians(1.0), slope_dir=math.radians(-45))
    measured, _ = open_loop_run(4.0, sloped, duration=90.0)
    assert measured.drift > 0.005  # m/s: half a metre a minute without feedback
    run = pid_circle_run("circle_R035")  # the session's shared run (the circle test's)
    assert same_problem(run.problem, load_problem(PROBLEMS / "circle_R035.toml")) and run.controller == "pid"
    late = run.result.t > 200.0
    centre_error = np.linalg.norm(run.centres[:, late].mean(axis=1))
    assert centre_error < 0.02  # with the PID the centre of curvature stays put


def test_runs_are_reproducible():
    problem = load_problem(PROBLEMS / "circle_R020.toml").with_duration(30.0)
    a, b = (run_problem(problem, "pid", seed=3).result for _ in range(2))
    c = run_problem(problem, "pid", seed=4).result
    assert np.array_equal(a.x, b.x) and not np.array_equal(a.x, c.x)


def test_stop_predictor_against_the_plant():
    radius_map = RadiusMap()
    predictor = StopPredictor(radius_map, decel=1.0)
    state = quasi_stable_state(2.5)
    x0 = state.state(phase=0.3)
    run = simulate(x0, 2.5 + 15.0, speed=lambda t: max(0.0, 2.5 - t))
    predicted = predictor.rest_point(x0[:2], 0.3, 2.5)
    assert np.linalg.norm(predicted - run.position[:, -1]) < 0.025


def test_pass_through_waypoint():
    mission = Waypoints((Waypoint([0.6, 0.0], stop=False, velocity=[0.0, 0.3]),), tolerance=0.07)
    problem = load_problem(PROBLEMS / "n_shape.toml")
    ctrl = QuasiStablePID(mission, RollbotParams())
    result = simulate(problem.initial_state(), 200.0, params=problem.params, controller=ctrl)
    assert ctrl.done and result.t[-1] < 200.0
    assert np.min(np.linalg.norm(result.position - np.array([[0.6], [0.0]]), axis=0)) < 0.07


@pytest.mark.parametrize("kwargs, message", [
    (dict(kp=-1.0), "kp"), (dict(max_accel=0.0), "max_accel"), (dict(min_radius=0.5, max_radius=0.4), "min_radius"),
    (dict(ki=float("nan")), "ki"),
])
def test_bad_gains(kwargs, message):
    with pytest.raises(ValueError, match=message):
        PIDGains(**kwargs)


def test_radius_limits_must_fit_the_robot():
    with pytest.raises(ValueError, match="radius limits"):
        QuasiStablePID(Circle([0, 0], 0.3), gains=PIDGains(min_radius=0.05))


def test_radius_limits_follow_the_robots_own_map():
    """A heavier, larger robot (R 0.15 m, M_s 1.2 kg, m 0.5 kg, r0 0.08 m) revolves on 0.15 to 2.2 m: the PID's
    limits come from its map (the prototype's fixed [0.13, 0.9] m would refuse it)."""
    from rollbot_oc.analysis.quasi_stable import RadiusMap

    heavy = RollbotParams().with_changes(R=0.15, M_s=1.2, m=0.5, r0=0.08)
    pid = QuasiStablePID(Circle([0, 0], 0.5), heavy)
    g, radius_map = pid.gains, pid.map
    assert radius_map.R_min < g.min_radius < g.stop_radius < g.max_radius < radius_map.R_max
    assert g.min_radius == pytest.approx(1.08 * radius_map.R_min)
    prototype = PIDGains().radius_limits(RadiusMap())
    assert (prototype.min_radius, prototype.max_radius, prototype.stop_radius) == pytest.approx((0.13, 0.9, 0.2),
                                                                                               abs=0.01)
