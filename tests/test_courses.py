"""The random-course generator (issue 11, item 6): ranges, determinism, and a seeded handful run by the PID."""

import math

import numpy as np
import pandas as pd
import pytest

from rollbot_oc.campaign import RUN_COLUMNS, campaign_from_dict, run_campaign
from rollbot_oc.scenarios.courses import CourseRanges, course_duration, random_course
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.model.params import RollbotParams

PROTOTYPE = RollbotParams()


def test_courses_are_drawn_within_their_ranges():
    for index in range(12):
        course = random_course(11, index)
        problem, plant, believed, drawn = course.problem, course.problem.params, course.believed, course.inputs
        path = [problem.start_position] + list(problem.mission.stops)
        legs = [np.linalg.norm(b - a) for a, b in zip(path[:-1], path[1:])]
        assert 3 <= len(problem.mission.stops) <= 8 and all(0.3 <= leg <= 3.0 for leg in legs)
        assert np.abs(np.array(path)).max() <= 1.5
        assert 0 <= math.degrees(plant.slope) <= 2.0 and drawn["slope_deg"] == pytest.approx(math.degrees(plant.slope))
        assert 30 <= math.degrees(plant.phi) <= 60 and 0.2 <= plant.m <= 0.45
        assert 0.07 <= plant.r0 <= 0.10 and 0.10 <= plant.R <= 0.15 and plant.R - plant.r0 >= 0.015
        assert plant.k0 == pytest.approx(0.4 * plant.M * plant.R**2)  # the paper's derived damping and torque
        assert plant.max_torque == pytest.approx(plant.r0 * plant.m * plant.g)
        assert plant.M_s == pytest.approx(PROTOTYPE.M_s * (plant.R / PROTOTYPE.R) ** 2)
        sensor = problem.sensor
        assert 1e-3 <= sensor["position_noise"] <= 3e-3 and 1 <= sensor["latency"] <= 3
        assert math.radians(0.2) <= sensor["angle_noise"] <= math.radians(0.6)
        assert believed.slope == 0.0 and believed.max_torque == plant.max_torque and believed.R == plant.R
        for mine, true in ((believed.M_s, plant.M_s), (believed.m, plant.m), (believed.k0, plant.k0)):
            assert 0.9 <= mine / true <= 1.1
        assert problem.duration == course_duration(drawn["length"], len(problem.mission.stops))


def test_a_course_is_fully_determined_by_seed_and_index():
    first, again, other = random_course(5, 3), random_course(5, 3), random_course(5, 4)
    assert first.problem.params == again.problem.params and first.believed == again.believed
    assert [s.tolist() for s in first.problem.mission.stops] == [s.tolist() for s in again.problem.mission.stops]
    assert first.inputs == again.inputs and first.noise_seed == again.noise_seed
    assert first.problem.sensor == again.problem.sensor and first.problem.start_heading == again.problem.start_heading
    assert other.inputs != first.inputs and random_course(6, 3).inputs != first.inputs


def test_narrowing_the_robots_leaves_the_course_geometry():
    wide, narrow = random_course(2, 1), random_course(2, 1, CourseRanges(phi_deg=(44.0, 46.0)))
    assert [s.tolist() for s in wide.problem.mission.stops] == [s.tolist() for s in narrow.problem.mission.stops]
    assert 44 <= narrow.inputs["phi_deg"] <= 46
    with pytest.raises(ConfigError, match="leaves no robot"):
        CourseRanges(r0=(0.14, 0.15))
    with pytest.raises(ConfigError, match="unknown key"):
        CourseRanges.from_dict({"wheels": [1, 2]})


HANDFUL = {"name": "handful", "kind": "closed_loop", "seed": 0,
           "closed_loop": {"courses": 3, "first_course": 4, "controllers": ["pid"], "duration": 15.0}}


def test_a_seeded_handful_of_courses_under_the_pid(tmp_path):
    """Courses 4 to 6 of seed 0, 15 s each: the PID runs every robot (its radius limits follow each robot's map);
    every row says what happened, and twice gives the same table."""
    tables = [run_campaign(campaign_from_dict(HANDFUL, "handful.toml"), tmp_path / str(n), workers=1,
                           figures=n == 0).table for n in range(2)]
    pd.testing.assert_frame_equal(tables[0].drop(columns=list(RUN_COLUMNS)), tables[1].drop(columns=list(RUN_COLUMNS)))
    table = tables[0].set_index("course")
    assert list(table.index) == [4, 5, 6] and (table["controller"] == "pid").all()
    for course in (4, 5, 6):  # 15 s is too short for any course: failed, with the cause, the metrics measured
        assert table.loc[course, "status"] == "failed" and "stops in 15 s" in table.loc[course, "error"]
        assert table.loc[course, "max_torque_ratio"] <= 1.0 and not table.loc[course, "torque_limit_violation"]
        assert table.loc[course, "duration"] == 15.0 and table.loc[course, "n_stops"] >= 3
    assert table.loc[5, "phi_deg"] > 0  # what was drawn stays in an error row
    assert (tmp_path / "0" / "success_rates.png").exists() and (tmp_path / "0" / "stop_errors_and_times.png").exists()
