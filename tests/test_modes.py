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
    assert step.is_in(StepMode.SHIFTED, StepMode.RAMP)


def test_the_docs_page_is_drawn_from_the_tables():
    """``docs/nmpc_modes.md`` is what ``modes_page`` draws from the code (``python docs/make_modes.py``)."""
    page = (DOCS / "nmpc_modes.md").read_text()
    assert page == modes_page()
    for modes, table in TRANSITIONS.items():
        for row in table:
            assert f"{row.source.name} --> {row.target.name}: {row.condition}" in page
