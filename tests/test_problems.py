"""Scenario files: loading, validation and metrics."""

import math
from pathlib import Path

import numpy as np
import pytest

from rollbot_oc.missions import Circle, Waypoint, Waypoints
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.scenarios.problem import load_problem, problem_from_dict

PROBLEMS = Path(__file__).parent.parent / "problems"


def test_every_problem_file_loads():
    names = sorted(p.stem for p in PROBLEMS.glob("*.toml"))
    assert {"open_loop", "circle_R020", "circle_R035", "circle_R050", "circle_R065", "approach",
            "n_shape"} <= set(names)
    for path in PROBLEMS.glob("*.toml"):
        problem = load_problem(path)
        assert problem.name == path.stem and problem.duration > 0
    circle = load_problem(PROBLEMS / "circle_R050.toml")
    assert circle.mission.radius == 0.5 and circle.params.slope == pytest.approx(math.radians(1.0))
    assert circle.sensor["latency"] == 1
    n_shape = load_problem(PROBLEMS / "n_shape.toml")
    assert len(n_shape.mission.stops) == 4


def test_base_parameters_and_overrides():
    data = {"name": "x", "kind": "circle", "duration": 10.0, "circle": {"radius": 0.3},
            "params": {"m": 0.4}, "floor": {"slope_deg": 2.0}}
    problem = problem_from_dict(data, base=RollbotParams(R=0.13))
    assert problem.params.m == 0.4 and problem.params.R == 0.13 and problem.params.slope == pytest.approx(
        math.radians(2.0))


BASE = {"name": "p", "kind": "circle", "duration": 100.0, "circle": {"radius": 0.35}}


@pytest.mark.parametrize("change, message", [
    ({"duration": None}, "missing required key 'duration'"),
    ({"kind": "spiral"}, "kind"),
    ({"colour": "red"}, "unknown key.*colour"),
    ({"circle": {"radius": 0.35, "speed": 1}}, r"\[circle\].*unknown key.*speed"),
    ({"circle": {"radius": -1.0}}, "radius.*out of range"),
    ({"circle": {}}, "missing required key 'radius'"),
    ({"duration": "long"}, "finite number"),
    ({"start": {"position": [1.0]}}, "position"),
    ({"kind": "waypoints", "waypoints": {"stops": []}}, "stops"),
    ({"kind": "waypoints", "waypoints": {"stops": [[0, 0], [1, "a"]]}}, "stops"),
    ({"kind": "waypoints"}, r"needs a \[waypoints\] table"),
    ({"sensor": {"latency": 1.5}}, "whole number"),
    ({"params": {"phi_deg": 120}}, "phi"),
    ({"floor": {"slope_deg": 60}}, "slope"),
    ({"kind": "open_loop", "open_loop": {"speeds": [1.0, 50.0]}}, "out of range"),
])
def test_bad_problems_are_clear_errors(change, message):
    data = {**BASE, **change}
    data = {k: v for k, v in data.items() if v is not None}
    with pytest.raises(ValueError, match=message):
        problem_from_dict(data, "bad.toml")


def test_bad_files(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        load_problem(tmp_path / "nope.toml")
    path = tmp_path / "broken.toml"
    path.write_text("name = ")
    with pytest.raises(ValueError, match="not valid TOML"):
        load_problem(path)


def test_missions_validate():
    with pytest.raises(ValueError, match="radius"):
        Circle([0, 0], 0.0)
    with pytest.raises(ValueError, match="two finite numbers"):
        Circle([0, float("nan")], 1.0)
    with pytest.raises(ValueError, match="needs a velocity"):
        Waypoint([1, 1], stop=False)
    with pytest.raises(ValueError, match="at least one"):
        Waypoints(())
    assert np.allclose(Circle([1, 0], 0.5).deviation(np.array([[1.0, 2.0], [0.6, 0.0]])), [0.1, 0.5])
    course = Waypoints(([0, 0], [1, 0], [1, 1]), stop_tolerance=0.03)
    first = course.first(2)
    assert [p.tolist() for p in first.stops] == [[0, 0], [1, 0]] and first.stop_tolerance == 0.03
    for count in (0, 4, 1.0):
        with pytest.raises(ValueError, match="give 1 to 3"):
            course.first(count)
