"""The NMPC's modes: one enum per machine, one table of transitions each, and the machine that keeps them.

Two machines run in an NMPC: the supervisor of its mission kind (``StopsMode``, ``OrbitMode`` or
``GatesMode``) decides what the tracking step follows, and the step's own ``StepMode`` says whether its
solutions are used or a fallback commands the motor.  A machine changes mode only along a row of its table
(``TRANSITIONS``), each row naming the condition that takes it; a change not in the table is a bug and
raises.  Every change is kept with its time and reason (``ModeMachine.timeline``): runs report it, and the
report draws it under the driving speed.  ``mermaid`` draws a table as a state diagram for the docs.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

__all__ = ["StopsMode", "OrbitMode", "GatesMode", "StepMode", "Transition", "TRANSITIONS", "ModeChange", "ModeMachine",
           "mermaid"]


class _Mode(Enum):
    """A mode: its value is its name in the reports; ``meaning`` says what the controller does in it."""

    def __new__(cls, value: str, meaning: str):
        mode = object.__new__(cls)
        mode._value_, mode.meaning = value, meaning
        return mode


class StopsMode(_Mode):
    """A course of stops."""

    RIDE = ("ride", "following a leg's quasi-stable guess while its minimum-time plan is computed")
    TRACK = ("track", "following a planned leg")
    HOLD = ("hold", "the leg has ended near its stop: held where the robot arrived")
    BRAKE = ("brake", "brought to rest where it is (off its plan, or a new stop with no leg that fits)")
    REST = ("rest", "held at rest while its leg from there is planned")
    FINISH = ("finish", "the last stop reached: held there ``arrival.finish_hold``")
    FINISH_AT_REST = ("finish at rest", "the last stop reached while being brought to rest, or the step gave up "
                      "while finishing: kept at rest there until ``arrival.finish_hold`` has passed")
    DONE = ("done", "the mission is done")


class OrbitMode(_Mode):
    """A circle."""

    RAMP = ("ramp", "up to the orbit's speed (a simulation of the model) while the entry is planned")
    ENTRY = ("entry", "following the planned entry onto the orbit")
    ORBIT = ("orbit", "on the orbit: the distance from the circle weighed")


class GatesMode(_Mode):
    """A course of gates."""

    TRACK = ("track", "following the plan through the gates left")
    STOP_MOTOR = ("stop motor", "the motor's speed ramped to zero, waiting for the robot to come to rest")
    DONE = ("done", "the mission is done")


class StepMode(_Mode):
    """The tracking step."""

    SOLVE = ("solve", "the tracking solves' solutions are followed")
    SHIFTED = ("shifted", "a solve failed or was late: the previous solution is followed")
    RAMP = ("ramp", "the motor's speed ramped to zero (and held there) for a while")
    PID = ("pid", "the paper's PID on the current goal for a while")
    OFF = ("off", "the mission is done: the motor's acceleration is zero")


@dataclass(frozen=True)
class Transition:
    """A row of a transition table: from ``source`` to ``target`` when ``condition`` holds."""

    source: Enum
    target: Enum
    condition: str


def _table(*rows):
    return tuple(Transition(*row) for row in rows)


S, O, G, P = StopsMode, OrbitMode, GatesMode, StepMode

TRANSITIONS = {
    StopsMode: _table(
        *[(m, S.TRACK, "a refined leg is ready and its start has come") for m in (S.RIDE, S.TRACK, S.HOLD)],
        *[(m, S.HOLD, "the leg has ended within hold_radius of its stop") for m in (S.RIDE, S.TRACK)],
        *[(m, S.TRACK, "stop reached: the leg planned ahead fits and takes over")
          for m in (S.RIDE, S.TRACK, S.HOLD, S.BRAKE, S.REST)],
        *[(m, S.BRAKE, "stop reached: no leg planned ahead fits") for m in (S.RIDE, S.TRACK, S.HOLD, S.BRAKE, S.REST)],
        *[(m, S.FINISH, "the last stop reached") for m in (S.RIDE, S.TRACK, S.HOLD)],
        *[(m, S.FINISH_AT_REST, "the last stop reached") for m in (S.BRAKE, S.REST)],
        (S.FINISH, S.FINISH_AT_REST, "the step gave up: failed with nothing to follow"),
        *[(m, S.DONE, "finish_hold has passed") for m in (S.FINISH, S.FINISH_AT_REST)],
        *[(m, S.BRAKE, "off the plan by more than replan_distance") for m in (S.RIDE, S.TRACK, S.HOLD)],
        *[(m, S.BRAKE, "at rest outside the stop's tolerance hold_time after the leg's end")
          for m in (S.RIDE, S.TRACK, S.HOLD)],
        *[(m, S.BRAKE, "the step gave up: failed with nothing to follow") for m in (S.RIDE, S.TRACK, S.HOLD)],
        (S.BRAKE, S.REST, "at rest, or brake_wait has passed: its leg is planned"),
        (S.REST, S.BRAKE, "the leg from rest is ready, but the robot moved off its start"),
        (S.REST, S.TRACK, "the leg from rest is ready"),
        (S.REST, S.RIDE, "the leg from rest failed: the quasi-stable guess from here"),
    ),
    OrbitMode: _table(
        (O.RAMP, O.ENTRY, "the entry is ready and its start has come"),
        (O.RAMP, O.ORBIT, "the ramp has ended"),
        (O.ENTRY, O.ORBIT, "the entry has ended"),
    ),
    GatesMode: _table(
        (G.TRACK, G.STOP_MOTOR, "every gate passed"),
        (G.TRACK, G.STOP_MOTOR, "the plan has ended hold_time ago with a gate missed"),
        (G.STOP_MOTOR, G.TRACK, "at rest, or brake_wait has passed: a new plan through the gates left"),
        (G.STOP_MOTOR, G.STOP_MOTOR, "the plan through the gates left failed: at rest, tried again"),
        (G.STOP_MOTOR, G.DONE, "at rest, or brake_wait has passed, with every gate passed or no replan left"),
    ),
    StepMode: _table(
        (P.SOLVE, P.SHIFTED, "a solve failed or was late"),
        (P.SHIFTED, P.SHIFTED, "a solve failed or was late"),
        (P.SHIFTED, P.SOLVE, "a solve succeeded in time"),
        *[(m, P.RAMP, "failed or late with nothing to follow (none, or max_failures in a row): brake")
          for m in (P.SOLVE, P.SHIFTED, P.RAMP, P.PID)],
        *[(m, P.PID, "failed or late with nothing to follow (none, or max_failures in a row): PID")
          for m in (P.SOLVE, P.SHIFTED, P.RAMP, P.PID)],
        *[(m, P.RAMP, "the supervisor stops the motor") for m in (P.SOLVE, P.SHIFTED, P.RAMP, P.PID)],
        *[(m, P.RAMP, "the supervisor holds the motor until its plan starts") for m in (P.SOLVE, P.SHIFTED)],
        *[(m, P.PID, "the supervisor holds the motor until its plan starts") for m in (P.SOLVE, P.SHIFTED)],
        (P.RAMP, P.SOLVE, "the fallback's time is over"),
        (P.PID, P.SOLVE, "the fallback's time is over"),
        *[(m, P.OFF, "the mission is done") for m in (P.SOLVE, P.SHIFTED, P.RAMP, P.PID)],
    ),
}
del S, O, G, P


@dataclass(frozen=True)
class ModeChange:
    """One change of mode: the mode entered, when (control periods from the start) and why."""

    mode: Enum
    tick: int
    reason: str

    def to_dict(self, dt: float) -> dict:
        """``{"mode", "t" (s), "reason"}``."""
        return {"mode": self.mode.value, "t": round(self.tick * dt, 9), "reason": self.reason}


class ModeMachine:
    """A machine of ``modes`` (an Enum) that changes mode only along its table (``TRANSITIONS[modes]``).

    Parameters
    ----------
    initial : Enum
        The mode it starts in, at tick 0.
    reason : str
        Why it starts there (the first entry of the timeline).
    """

    def __init__(self, initial: Enum, reason: str = "start"):
        self.table = TRANSITIONS[type(initial)]
        self._rows = {(row.source, row.target, row.condition) for row in self.table}
        self.mode = initial
        self.since = 0
        self.timeline = [ModeChange(initial, 0, reason)]

    def go(self, target: Enum, tick: int, reason: str) -> None:
        """Change to ``target`` at ``tick`` for ``reason``, which must be a condition of the table for that change.

        Raises
        ------
        RuntimeError
            If the table has no such row (a bug in the supervisor, never a state of the robot).
        """
        if (self.mode, target, reason) not in self._rows:
            raise RuntimeError(f"{type(self.mode).__name__}: no transition {self.mode.value} -> {target.value} "
                               f"for {reason!r}")
        self.mode, self.since = target, tick
        self.timeline.append(ModeChange(target, tick, reason))

    def since_within(self, *modes) -> int:
        """The tick since which the machine has stayed among ``modes`` (the current mode one of them)."""
        tick = self.since
        for change in reversed(self.timeline):
            if change.mode not in modes:
                break
            tick = change.tick
        return tick

    def report(self, dt: float) -> list:
        """The timeline as ``[{"mode", "t", "reason"}, ...]`` (``dt``: the control period, s)."""
        return [change.to_dict(dt) for change in self.timeline]


def mermaid(modes: type[Enum]) -> str:
    """The transition table of ``modes`` as a Mermaid state diagram (one edge per condition)."""
    lines = ["stateDiagram-v2"]
    first = next(iter(modes))
    lines.append(f"    [*] --> {first.name}")
    for row in TRANSITIONS[modes]:
        lines.append(f"    {row.source.name} --> {row.target.name}: {row.condition}")
    return "\n".join(lines)


def modes_page() -> str:
    """The Markdown page of the NMPC's modes (``docs/nmpc_modes.md``): each machine's modes with what they
    mean, and its transition table as a state diagram, all drawn from the code."""
    out = ["# The NMPC's modes", "",
           "Generated from `rollbot_oc/control/nmpc/modes.py` by `python docs/make_modes.py`; a test checks "
           "that this page matches the code. Every run reports each machine's timeline (`modes`, `step_modes` "
           "in its JSON: mode, start time, reason) and the report draws it under the driving speed.", ""]
    for modes in TRANSITIONS:
        out += [f"## {modes.__name__}: {modes.__doc__.strip().rstrip('.').lower()}", "", "| mode | meaning |",
                "|---|---|"]
        out += [f"| `{mode.value}` | {mode.meaning.replace('``', '`')} |" for mode in modes]
        out += ["", "```mermaid", mermaid(modes), "```", ""]
    return "\n".join(out)
