"""The replay log of the exported project: what the board's step received and gave, period by period.

On a robot the supervisor (modes, plans, reference windows) runs on the host and the control step on the board.
``StepRecorder`` is attached to the NMPC's step (``TrackingStep.recorder``) during a closed-loop run and keeps, per
control period, what crosses that boundary:

* the tick ``k`` and the measurement (its time, s, and the full state (11,));
* the host's edits of the step's memory (``TrackingStep.restart``, ``cold``, ``stop_motor``, ``hold_until``):
  the entries that differ, as ``(index, value)`` pairs, those made before ``measure`` and those made after it
  (before ``solve`` and ``commit``);
* at a solve instant the reference window solved on (``WindowLayout``: reference, weights, mission values);
* the inputs of ``commit`` the host decides: ``late``, ``done``, ``fallback_pid`` and ``pid_speed`` (NaN but
  in the PID fallback);
* what the step gave: the acceleration (rad/s^2), the speed (rad/s, NaN unless by speed), ``by_speed``, the
  event (``period.EVENTS``) and the step's mode after the period (``StepMode``, by ``MODE_CODES``).

``replay_bytes`` writes them as the file the C replay reads (``main.c``, ``firmware_main.c`` through
``rollbot_replay.c``; format in ``rollbot_replay.h``) and ``read_replay`` reads it back.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["StepRecorder", "Period", "replay_bytes", "read_replay", "MAGIC", "VERSION", "MAX_EDITS",
           "MEASUREMENT"]

MAGIC = b"RBREPLAY"
VERSION = 2
MEASUREMENT = 12  # doubles of a measurement: its time and the full state
MAX_EDITS = 64  # edits of the memory at one point of a period the C replay takes (rollbot_replay.h)


def _edits(new: np.ndarray, old: np.ndarray) -> np.ndarray:
    """``(index, value)`` rows of the entries of ``new`` that differ from ``old`` (NaN equal to NaN)."""
    differ = ~((new == old) | (np.isnan(new) & np.isnan(old)))
    index = np.flatnonzero(differ)
    return np.column_stack([index.astype(float), new[index]])


@dataclass
class Period:
    """One control period of the replay log (module doc)."""

    k: int
    meas: np.ndarray
    before: np.ndarray  # (edits, 2): the host's edits before measure
    after: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # and after it
    window: np.ndarray | None = None
    inputs: tuple = (0.0, 0.0, 0.0, np.nan)  # late, done, fallback_pid, pid_speed
    outputs: tuple = (0.0, np.nan, 0.0, 0.0, 0.0)  # accel, speed, by_speed, event, mode

    def values(self) -> np.ndarray:
        """The period as the doubles of the file (``rollbot_replay.h``)."""
        window = self.window if self.window is not None else np.zeros(0)
        return np.concatenate([[self.k], self.meas, [len(self.before)], self.before.ravel(), [len(self.after)],
                               self.after.ravel(), [float(self.window is not None)], window, self.inputs,
                               self.outputs])


class StepRecorder:
    """Keeps what the NMPC's step received and gave each period (module doc); attach it as
    ``TrackingStep.recorder``.

    Parameters
    ----------
    initial_memory : numpy.ndarray
        The step's memory before the first period (``StepFunctions.initial_memory``).
    mode_slice : slice
        Where the step's mode is in the memory.
    """

    def __init__(self, initial_memory: np.ndarray, mode_slice: slice):
        self.periods: list[Period] = []
        self._last = np.array(initial_memory, float)
        self._measured = None
        self._mode = mode_slice

    def measured(self, k: int, meas, mem_in, mem_out) -> None:
        """``measure`` at tick ``k`` on ``meas`` with the memory ``mem_in``, giving ``mem_out``."""
        self.periods.append(Period(int(k), np.array(meas, float), _edits(np.asarray(mem_in, float), self._last)))
        self._measured = np.array(mem_out, float)

    def committed(self, k: int, mem_in, window, inputs, outputs, mem_out) -> None:
        """``solve`` (on the packed ``window``, or None) and ``commit`` at tick ``k``: the memory before them,
        ``inputs`` (late, solving, done, fallback_pid, pid_speed) and ``outputs`` (accel, speed, by_speed,
        event), the memory after."""
        period = self.periods[-1]
        if period.k != k:
            raise RuntimeError(f"the step committed tick {k} after measuring tick {period.k}")
        period.after = _edits(np.asarray(mem_in, float), self._measured)
        period.window = None if window is None else np.array(window, float)
        late, solving, done, fallback_pid, pid_speed = (float(v) for v in inputs)
        if bool(solving) != (window is not None):
            raise RuntimeError(f"tick {k}: a solve instant without a window (or a window without a solve)")
        period.inputs = (late, done, fallback_pid, pid_speed)
        mem_out = np.array(mem_out, float)
        period.outputs = tuple(float(v) for v in outputs) + (float(mem_out[self._mode][0]),)
        self._last = mem_out


def replay_bytes(periods, memory_size: int, window_size: int) -> bytes:
    """The replay file of ``periods`` (``Period``) for a step of ``memory_size`` doubles of memory and windows of
    ``window_size``: ``MAGIC``, uint32 version, periods, memory size, window size (little-endian), then every
    period's doubles (``Period.values``).

    Raises
    ------
    ValueError
        If a period has more than ``MAX_EDITS`` edits at one point or a window of another size.
    """
    body = []
    for p in periods:
        if max(len(p.before), len(p.after)) > MAX_EDITS:
            raise ValueError(f"tick {p.k}: {max(len(p.before), len(p.after))} edits of the memory at once, "
                             f"the C replay takes at most {MAX_EDITS}")
        if p.window is not None and p.window.size != window_size:
            raise ValueError(f"tick {p.k}: a window of {p.window.size} doubles, not {window_size}")
        body.append(p.values())
    header = MAGIC + np.array([VERSION, len(body), memory_size, window_size], dtype="<u4").tobytes()
    data = np.concatenate(body) if body else np.zeros(0)
    return header + data.astype("<f8").tobytes()


def read_replay(data: bytes) -> tuple[dict, list[Period]]:
    """``(header, periods)`` of a replay file's bytes (``replay_bytes``); ``header``: ``periods``, ``memory``,
    ``window``.

    Raises
    ------
    ValueError
        If it is not a replay file of this version or ends early.
    """
    if data[:8] != MAGIC or len(data) < 24:
        raise ValueError("not a replay file of the exported step")
    version, count, memory, window = (int(v) for v in np.frombuffer(data[8:24], "<u4"))
    if version != VERSION:
        raise ValueError(f"replay file version {version}, this reader's is {VERSION}")
    v = np.frombuffer(data[24:], "<f8")
    periods, i = [], 0
    try:
        for _ in range(count):
            k, meas = int(v[i]), v[i + 1:i + 1 + MEASUREMENT].copy()
            i += 1 + MEASUREMENT
            n = int(v[i])
            before = v[i + 1:i + 1 + 2 * n].reshape(n, 2).copy()
            i += 1 + 2 * n
            n = int(v[i])
            after = v[i + 1:i + 1 + 2 * n].reshape(n, 2).copy()
            i += 1 + 2 * n
            solving = bool(v[i])
            i += 1
            win = v[i:i + window].copy() if solving else None
            i += window if solving else 0
            inputs, outputs = tuple(v[i:i + 4]), tuple(v[i + 4:i + 9])
            i += 9
            if len(outputs) < 5:
                raise IndexError
            periods.append(Period(k, meas, before, after, win, inputs, outputs))
    except (IndexError, ValueError):
        raise ValueError(f"the replay file ends within period {len(periods)} of {count}") from None
    return {"periods": count, "memory": memory, "window": window}, periods
