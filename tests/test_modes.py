"""The NMPC's modes: tables that name every mode, machines that keep to them, and the docs drawn from them."""

from pathlib import Path

import pytest

from rollbot_oc.control.nmpc.modes import TRANSITIONS, ModeMachine, StepMode, StopsMode, modes_page

DOCS = Path(__file__).resolve().parents[1] / "docs"


def test_every_mode_is_reached_and_left_along_the_table():
    """Each mode but the first is the target of a row; each but the final ones is the source of one; every row
    names its condition, and no pair repeats a condition."""
    for modes, table in TRANSITIONS.items():
        first = next(iter(modes))
        targets = {row.target for row in table}
        sources = {row.source for row in table}
        assert set(modes) - {first} <= targets, modes
        final = set(modes) - sources
        assert final <= {modes["DONE"] if "DONE" in modes.__members__ else None, getattr(modes, "ORBIT", None),
                         getattr(modes, "OFF", None)}, (modes, final)
        assert all(row.condition for row in table)
        assert len({(row.source, row.target, row.condition) for row in table}) == len(table)


def test_a_machine_refuses_a_change_not_in_its_table():
    machine = ModeMachine(StopsMode.RIDE)
    with pytest.raises(RuntimeError, match="no transition ride -> rest"):
        machine.go(StopsMode.REST, 3, "at rest, or brake_wait has passed: its leg is planned")
    with pytest.raises(RuntimeError, match="for 'because'"):
        machine.go(StopsMode.TRACK, 3, "because")  # a row exists, but not for this reason
    machine.go(StopsMode.TRACK, 150, "a refined leg is ready and its start has come")
    assert machine.mode is StopsMode.TRACK and machine.since == 150
    assert machine.report(0.01) == [{"mode": "ride", "t": 0.0, "reason": "start"},
                                    {"mode": "track", "t": 1.5, "reason": "a refined leg is ready and its start "
                                                                         "has come"}]
    step = ModeMachine(StepMode.SOLVE)
    step.go(StepMode.SHIFTED, 5, "a solve failed or was late")
    assert step.mode is StepMode.SHIFTED


def test_the_docs_page_is_drawn_from_the_tables():
    """``docs/nmpc_modes.md`` is what ``modes_page`` draws from the code (``python docs/make_modes.py``)."""
    page = (DOCS / "nmpc_modes.md").read_text()
    assert page == modes_page()
    for modes, table in TRANSITIONS.items():
        for row in table:
            assert f"{row.source.name} --> {row.target.name}: {row.condition}" in page


@pytest.fixture(scope="module")
def n_shape_nmpc():
    """An NMPC for the N-shape's first stop, prepared (its routes built once for the module)."""
    from dataclasses import replace

    from rollbot_oc.scenarios.problem import make_controller
    from rollbot_oc.scenarios.bundled import load_bundled

    base = load_bundled("n_shape")
    problem = replace(base, mission=base.mission.first(1))
    nmpc = make_controller("nmpc", problem)
    nmpc.prepare(problem.initial_state())
    return nmpc, problem


def test_the_motor_is_stopped_and_held_from_any_fallback(n_shape_nmpc):
    """A supervisor may stop the motor while the PID holds it (gates: the last gate passed during a PID
    fallback), and holding it until a plan starts names the fallback that holds it."""
    nmpc, _ = n_shape_nmpc
    step = nmpc.step
    step.reset(nmpc.telemetry)
    step.modes.go(StepMode.PID, 5, "failed or late with nothing to follow (none, or max_failures in a row): PID")
    step.stop_motor(10, 3.0, until=4.0)
    assert step.modes.mode is StepMode.RAMP and step.in_fallback(3.99)
    step.reset(nmpc.telemetry)
    step.hold_until(20, 1.0)  # from SOLVE, with no ramp of its own: the PID holds it
    assert step.modes.mode is StepMode.PID and step.in_fallback(0.5) and not step.in_fallback(1.0)


def test_the_last_stop_reached_while_braking_is_held_at_rest(n_shape_nmpc):
    """Reaching the last stop while being braked (a recovery ending inside the stop's tolerance), the robot is
    held at rest during ``finish_hold`` as it was being held (brake weights), not pulled onto its leg's end; a
    step that gives up while finishing brings it to rest the same way, counted as a brake."""
    import numpy as np

    from rollbot_oc.model.dynamics import to_reduced
    from rollbot_oc.missions import StopMonitor
    from rollbot_oc.control.protocol import Observation

    nmpc, problem = n_shape_nmpc
    sup, s = nmpc.supervisor, nmpc.settings
    z = to_reduced(problem.initial_state())
    sup._brake(z, 40, "off the plan by more than replan_distance")
    sup._monitor = StopMonitor(problem.mission.stops[0], problem.mission.stop_rule)
    sup._monitor.since = 0.5  # (came to rest there at 0.5 s)

    x = problem.initial_state()
    obs = Observation(0.6, x[:2], x[2:6], x[6:9], float(x[9]), float(x[10]))
    sup._leave_stop(60, obs, z)
    assert sup.mode is StopsMode.FINISH_AT_REST
    window = sup.window(z, 60)
    assert np.array_equal(window.diag, s.weights.brake.diagonal(s.horizon.N))
    assert np.allclose(window.Zr[:2], z[:2, None]) and np.allclose(window.Zr[6:], 0.0)  # rest where it is
    # finishing from a leg (not braking): a give-up brings it to rest, counted once; finish_hold counts from the
    # stop reached, not from the give-up
    sup.reset()
    sup.prepare(problem.initial_state(), None)
    sup._monitor = StopMonitor(problem.mission.stops[0], problem.mission.stop_rule)
    sup._monitor.since = 0.5
    sup._leave_stop(60, obs, z)
    assert sup.mode is StopsMode.FINISH
    brakes = nmpc.telemetry.brakes
    sup.on_give_up(z, 70)
    assert sup.mode is StopsMode.FINISH_AT_REST and nmpc.telemetry.brakes == brakes + 1
    assert np.array_equal(sup.window(z, 70).diag, s.weights.brake.diagonal(s.horizon.N))
    sup.on_give_up(z, 75)
    assert nmpc.telemetry.brakes == brakes + 1  # already at rest: no second brake
    done_at = 60 + round(s.arrival.finish_hold / nmpc.dt)
    sup.advance(done_at - 5, obs, False, z)
    assert sup.mode is StopsMode.FINISH_AT_REST
    sup.advance(done_at, obs, False, z)
    assert sup.mode is StopsMode.DONE
