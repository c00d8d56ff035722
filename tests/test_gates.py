"""Missions as registered kinds, and the kind ``gates``: its schema, its metrics, the PID and the NMPC on it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.missions import KINDS, Circle, Mission, gate_passes, mission_kind, register
from rollbot_oc.missions.schema import number, point
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.scenarios.problem import compute_metrics, problem_from_dict, run_problem
from rollbot_oc.scenarios.bundled import bundled_table, load_bundled

GATES = {"name": "g", "kind": "gates", "duration": 60.0,
         "gates": {"points": [[0.8, 0.2], [0.9, 1.0], [0.1, 1.1]], "tolerance": 0.05}}


# -- the registry -----------------------------------------------------------------------------------------------
def test_unknown_kind_is_one_line_listing_the_valid_kinds():
    with pytest.raises(ConfigError) as info:
        problem_from_dict({**GATES, "kind": "spiral"}, "p.toml")
    message = str(info.value)
    assert "\n" not in message
    assert message == "p.toml: key 'kind' = 'spiral'; valid are circle, waypoints, open_loop, gates"
    with pytest.raises(ConfigError, match="valid are circle, waypoints, open_loop, gates"):
        mission_kind(None)


@pytest.mark.parametrize("scenario", ["circle_R035", "n_shape", "open_loop", "gates"])
def test_each_kind_round_trips_its_table(scenario):
    data = bundled_table(scenario)
    problem = problem_from_dict(data)
    mission = problem.mission
    assert type(mission) is KINDS[data["kind"]] and mission.kind == problem.kind == data["kind"]
    table = mission.to_table()
    assert set(table) <= mission.keys and set(data[mission.kind]) <= set(table)
    again = problem_from_dict({**data, mission.kind: table}).mission
    assert again.to_table() == table


def test_gates_schema_errors_are_one_line():
    cases = [({"tolerance": 0.05}, "p.toml [gates]: key 'points' = None must be a list of [x, y] pairs"),
             ({"points": [[0, 0], [0.05, 0]], "tolerance": 0.05}, "gates 1 and 2 are 0.05 m apart"),
             ({"points": [[0, 1]], "tolerance": 2.0}, "key 'tolerance' = 2.0 is out of range: valid is [0.001, 1.0]"),
             ({"points": [[0, 1]], "speed": 1.0}, "unknown key(s) speed; valid keys are points, tolerance")]
    for table, message in cases:
        with pytest.raises(ConfigError) as info:
            problem_from_dict({**GATES, "gates": table}, "p.toml")
        assert "\n" not in str(info.value) and message in str(info.value), str(info.value)


# -- gate metrics -----------------------------------------------------------------------------------------------
def test_gate_passes_on_a_straight_line():
    """The line y = 0.03 m at 0.5 m/s, x from 0 to 2 m, past gates at x = 1 m and 1.5 m: misses 3 cm; a gate
    4 cm off the line with a 2 cm tolerance is missed (its closest approach, 4 cm, and not passed)."""
    t = np.arange(0.0, 4.0 + 1e-9, 0.01)
    line = np.vstack([0.5 * t, np.full_like(t, 0.03)])
    first, second = gate_passes(t, line, [np.array([1.0, 0.0]), np.array([1.5, 0.0])], 0.05)
    assert first == {"miss": pytest.approx(0.03), "time": pytest.approx(2.0), "passed": True}
    assert second == {"miss": pytest.approx(0.03), "time": pytest.approx(3.0), "passed": True}
    # measured after the gate before: a gate behind the robot is only seen from where it passed the first one
    behind = gate_passes(t, line, [np.array([1.5, 0.0]), np.array([1.0, 0.0])], 0.05)
    assert behind[0]["passed"] and not behind[1]["passed"] and behind[1]["miss"] == pytest.approx(np.hypot(0.5, 0.03))
    missed = gate_passes(t, line, [np.array([1.0, -0.01])], 0.02)[0]
    assert not missed["passed"] and missed["miss"] == pytest.approx(0.04) and missed["time"] == pytest.approx(2.0)


def test_gates_metrics_of_a_synthetic_run():
    """``compute_metrics`` on a run that rolls along y = 0.03 m past gates at 1 and 1.5 m (no contact event)."""
    problem = problem_from_dict({**GATES, "gates": {"points": [[1.0, 0.0], [1.5, 0.0]], "tolerance": 0.05}})
    result = _line_run(problem)
    m = compute_metrics(problem, result)
    assert m["completed"] and m["gate_misses"] == pytest.approx([0.03, 0.03])
    assert m["completion_time"] == pytest.approx(3.0) and m["gate_times"] == pytest.approx([2.0, 3.0])
    tight = problem_from_dict({**GATES, "gates": {"points": [[1.0, 0.0], [1.5, 0.0]], "tolerance": 0.02}})
    m = compute_metrics(tight, result)
    assert not m["completed"] and m["completion_time"] is None and m["gates_passed"] == 0


def _line_run(problem):
    """A ``SimulationResult`` whose shell centre moves along y = 0.03 m at 0.5 m/s for 4 s, the robot upright."""
    from rollbot_oc.model.dynamics import rest_state
    from rollbot_oc.simulation.plant import SimulationResult

    t = np.arange(0.0, 4.0 + 1e-9, 0.01)
    x = np.tile(rest_state(problem.params)[:, None], (1, t.size))
    x[0], x[1] = 0.5 * t, 0.03
    n = t.size - 1
    diag = np.ones((7, n))
    return SimulationResult(problem.params, 0.01, t, x, np.zeros(n), np.zeros(n), diag, [], np.zeros(n), {}, None)


# -- the controllers on problems/gates.toml -----------------------------------------------------------------------
def test_pid_passes_every_gate_of_the_bundled_course():
    problem = load_bundled("gates")
    m = run_problem(problem, "pid", show_progress=False).metrics
    assert m["completed"] and not m["events"] and len(m["gate_misses"]) == 3
    assert max(m["gate_misses"]) <= problem.mission.tolerance
    assert m["completion_time"] < 55.0


def test_nmpc_passes_every_gate_faster_than_the_pid():
    problem = load_bundled("gates")
    m = run_problem(problem, "nmpc", show_progress=False).metrics
    assert m["completed"] and not m["events"] and max(m["gate_misses"]) <= problem.mission.tolerance
    assert m["completion_time"] < 20.0  # the PID takes about 50 s
    assert m["plans"] and m["plans"][0]["gates"] == [[0.8, 0.2], [0.9, 1.0], [0.1, 1.1]]


# -- adding a kind touches one file -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Loiter(Mission):
    """Revolve near a point; measured by the largest distance from it after ``after`` seconds."""

    kind = "loiter"
    keys = frozenset({"point", "after"})

    centre: np.ndarray
    after: float = 2.0

    @classmethod
    def from_table(cls, table, where, params, duration):
        return cls(point(table, "point", where), number(table, "after", where, 0.0, duration, default=2.0))

    def to_table(self):
        return {"point": self.centre.tolist(), "after": self.after}

    @property
    def orbit(self):
        return Circle(self.centre, 0.3)

    def metrics(self, result):
        late = result.t >= self.after
        far = float(np.hypot(*(result.position[:, late] - self.centre[:, None])).max())
        return {"loiter_distance": far, "completed": far < 1.0, "completion_time": self.after}


@pytest.fixture
def loiter():
    register(Loiter)
    yield Loiter
    del KINDS["loiter"]


def test_a_kind_registered_in_one_place_runs_end_to_end(loiter):
    data = {"name": "loiter", "kind": "loiter", "duration": 4.0, "start": {"position": [0.3, 0.0]},
            "loiter": {"point": [0.0, 0.0], "after": 1.0}}
    problem = problem_from_dict(data, "loiter.toml", RollbotParams())
    assert isinstance(problem.mission, Loiter) and problem.mission.after == 1.0
    with pytest.raises(ConfigError, match=r"loiter.toml \[loiter\]: unknown key\(s\) radius"):
        problem_from_dict({**data, "loiter": {"radius": 1.0}}, "loiter.toml")
    run = run_problem(problem, "pid", show_progress=False)
    assert run.metrics["completed"] and run.metrics["loiter_distance"] < 1.0
    assert run.metrics["problem"] == "loiter" and run.result.t[-1] == pytest.approx(4.0)
