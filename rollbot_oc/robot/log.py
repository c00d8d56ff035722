"""Runs as MCAP logs: one file per run that robotics tools open (Foxglove, the ``mcap`` command line).

A log holds JSON messages on channels, each with its JSON schema (defined once, in ``CHANNELS``)::

    /measurement  the state at every state time (the full state of rollbot_oc.model.dynamics, SI units)
    /tf           the same pose as a foxglove.FrameTransform (floor -> shell), for Foxglove's 3D panel
    /command      every control period: the motor acceleration asked for, the speed command, the step's time
    /diagnostics  every control period: applied acceleration, motor torque, ground force, contact margins
    /reference    what the controller followed: the NMPC's reference window at each solve, the PID's target
    /mode         each change of the supervisor's and of the step's mode (machine, mode, reason)
    /plan         each plan, when it is first followed (its summary and nodes)
    /link         the robot link's statistics (``rollbot_oc.robot.faults.LinkStats``), when there is a link

Message times are the run's time (s from its start) in ns, plus ``start_ns``.  Two metadata records carry what
is not a time series: ``run`` (problem, controller, seed, control period, the robot's parameters) at the start,
``result`` (contact events and metrics) at the end.

``LogWriter`` streams a log: open, ``write`` messages as they happen, ``close``.  It flushes what it has every
``flush_every`` s of log time (whole MCAP chunks), so a process that dies keeps its log up to the last flush,
and ``read_log`` reads such a truncated log to its last whole record.  ``write_run_log`` writes a finished run
(a ``problems.RunResult``) whole; ``read_log`` gives it back as a ``SimulationResult`` (the trajectory, commands
and diagnostics exactly: JSON keeps every bit of a double), its metrics and its messages.
"""

from __future__ import annotations

import importlib.util
import json
import math
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rollbot_oc.model.dynamics import STATE_NAMES, STATE_UNITS
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.core.outputs import atomic_path, json_ready
from rollbot_oc.simulation.plant import DIAG_NAMES, SimulationResult

__all__ = ["CHANNELS", "FORMAT", "available", "LogWriter", "LoggedRun", "write_run_log", "read_log", "run_messages"]

FORMAT = "rollbot_oc run log 1"  # the ``run`` metadata's ``format``: what this module writes and reads

_NUMBER = {"type": "number"}
_NULLABLE = {"type": ["number", "null"]}
_ARRAY = {"type": "array", "items": _NULLABLE}
_TIME = {"type": "number", "description": "time from the run's start, s"}
_PERIOD = {"type": "integer", "description": "control period index"}


def _schema(title: str, properties: dict, required=("t",)) -> dict:
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title, "type": "object",
            "properties": properties, "required": list(required)}


_STATE = {name: {**_NUMBER, "description": unit} for name, unit in zip(STATE_NAMES, STATE_UNITS)}
_XYZ = {"type": "object", "properties": {k: _NUMBER for k in "xyz"}}

CHANNELS = {
    "/measurement": ("rollbot_oc.Measurement", _schema("The robot's state", {
        "t": _TIME, "period": _PERIOD,
        "state": {"type": "object", "properties": _STATE, "required": list(STATE_NAMES),
                  "description": "the full state of rollbot_oc.model.dynamics (body -> floor quaternion, scalar first)"},
    }, ("t", "state"))),
    "/tf": ("foxglove.FrameTransform", {
        "title": "foxglove.FrameTransform", "type": "object", "properties": {
            "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}},
            "parent_frame_id": {"type": "string"}, "child_frame_id": {"type": "string"},
            "translation": _XYZ,
            "rotation": {"type": "object", "properties": {k: _NUMBER for k in "xyzw"}}}}),
    "/command": ("rollbot_oc.Command", _schema("The command of a control period", {
        "t": _TIME, "period": _PERIOD,
        "accel": {**_NULLABLE, "description": "motor acceleration asked for (before the motor's limits), rad/s^2"},
        "speed": {**_NULLABLE, "description": "driving-speed command, rad/s (null: an acceleration command)"},
        "step_time": {**_NULLABLE, "description": "wall-clock time of the controller's step, s"},
    }, ("t", "accel"))),
    "/diagnostics": ("rollbot_oc.Diagnostics", _schema("Contact diagnostics at the start of a control period", {
        "t": _TIME, "period": _PERIOD, **{name: _NULLABLE for name in DIAG_NAMES},
    })),
    "/reference": ("rollbot_oc.Reference", _schema("What the controller follows", {
        "t": _TIME, "period": _PERIOD,
        "h": {**_NUMBER, "description": "NMPC: time between the window's nodes, s (the first at t)"},
        "x": {**_ARRAY, "description": "NMPC: the window's positions, m"}, "y": _ARRAY,
        "theta_dot": {**_ARRAY, "description": "NMPC: the window's driving speeds, rad/s"},
        "accel": {**_ARRAY, "description": "NMPC: the window's accelerations, rad/s^2"},
        "centre": {**_XYZ, "description": "PID: the centre of curvature it steers to, m"},
        "radius": {**_NUMBER, "description": "PID: the revolving radius it steers to, m"},
        "braking": {"type": "boolean", "description": "PID: braking to a stop"},
    })),
    "/mode": ("rollbot_oc.Mode", _schema("A change of mode", {
        "t": _TIME, "machine": {"type": "string", "description": "supervisor or step"},
        "mode": {"type": "string"}, "reason": {"type": "string"},
    }, ("t", "machine", "mode"))),
    "/plan": ("rollbot_oc.Plan", _schema("A plan, when first followed", {
        "t": _TIME, "summary": {"type": "object", "description": "duration T (s), status, iterations, ..."},
        "nodes": {"type": "object", "description": "the plan's nodes: t (s from its start), x, y (m), "
                  "theta_dot (rad/s)", "properties": {k: _ARRAY for k in ("t", "x", "y", "theta_dot")}},
    })),
    "/link": ("rollbot_oc.LinkStats", _schema("The robot link's statistics so far", {
        "t": _TIME, **{name: {"type": "integer"} for name in (
            "frames_sent", "bytes_sent", "frames_received", "bytes_received", "lost", "late", "duplicated",
            "corrupted")},
        "injected": {"type": ["object", "null"], "description": "what a fault-injecting link did to the frames "
                     "it sent: frames, lost, corrupted, duplicated, delayed, reordered, disconnected, bytes_cut"},
    })),
}


INSTALL = "pip install 'rollbot_oc[robot]'"


def available() -> bool:
    """True if the ``mcap`` package (the ``robot`` extra) is installed: logs can be written and read."""
    return importlib.util.find_spec("mcap") is not None


def _require(path) -> None:
    if not available():
        raise ConfigError(f"{path}: MCAP logs need the mcap package ({INSTALL})")


def _plain(value):
    """A numpy array or scalar as a list or number (``json.dumps``'s ``default``)."""
    if isinstance(value, (np.ndarray, np.generic)):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON-ready")


def _ns(t: float, start_ns: int) -> int:
    return start_ns + int(round(t * 1e9))


class LogWriter:
    """A run's MCAP log, written as it happens (a context manager: the log is closed, whole, on any exit).

    Parameters
    ----------
    target : str, Path or binary file
        Where to write (a path is created or truncated).
    run : dict, optional
        The ``run`` metadata: ``problem``, ``controller``, ``seed``, ``dt`` (s), ``params_file`` (the robot's
        parameter table), anything JSON-ready; written first.
    start_ns : int, default 0
        Log time of the run's start, ns (a wall-clock epoch for a live run, 0 for a simulated one).
    flush_every : float, default 1.0
        Flush (finish the MCAP chunk and write it out) after this much log time, s: what a crash can lose.
    """

    def __init__(self, target, run: dict | None = None, start_ns: int = 0, flush_every: float = 1.0):
        _require(target if isinstance(target, (str, Path)) else "MCAP log")
        from mcap.writer import CompressionType, Writer

        self._handle = open(target, "wb") if isinstance(target, (str, Path)) else None
        self._writer = Writer(self._handle or target, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="rollbot_oc")
        self.start_ns = int(start_ns)
        self.flush_every = float(flush_every)
        self._channels, self._sequence = {}, {}
        for topic, (name, schema) in CHANNELS.items():
            schema_id = self._writer.register_schema(name, "jsonschema", json.dumps(schema).encode())
            self._channels[topic] = self._writer.register_channel(topic, "json", schema_id)
            self._sequence[topic] = 0
        self._flushed = 0.0
        self.closed = False
        self._writer.add_metadata("run", {"format": FORMAT, **{k: json.dumps(json_ready(v), allow_nan=False)
                                                               for k, v in (run or {}).items()}})
        self._writer.flush()

    def write(self, topic: str, t: float, message: dict) -> None:
        """Write ``message`` (JSON-ready; ``t`` added) on channel ``topic`` at run time ``t`` (s)."""
        if topic not in self._channels:
            raise ValueError(f"unknown channel {topic!r}: valid are {', '.join(CHANNELS)}")
        message = {"t": t, **message}
        try:  # numpy values through _plain; NaN and infinities (rare) as null through json_ready
            data = json.dumps(message, allow_nan=False, separators=(",", ":"), default=_plain).encode()
        except (ValueError, TypeError):
            data = json.dumps(json_ready(message), allow_nan=False, separators=(",", ":")).encode()
        ns = _ns(t, self.start_ns)
        self._writer.add_message(self._channels[topic], log_time=ns, publish_time=ns, data=data,
                                 sequence=self._sequence[topic])
        self._sequence[topic] += 1
        if t - self._flushed >= self.flush_every:
            self.flush()
            self._flushed = t

    def measurement(self, t: float, state, period: int | None = None, radius: float | None = None) -> None:
        """The state (11,) at ``t``, on /measurement, and its pose on /tf (the shell's centre ``radius`` m above
        the floor, if given)."""
        state = [float(v) for v in state]
        self.write("/measurement", t, {"period": period, "state": dict(zip(STATE_NAMES, state))})
        ns = _ns(t, self.start_ns)
        qw, qx, qy, qz = state[2:6]
        self.write("/tf", t, {"timestamp": {"sec": ns // 10**9, "nsec": ns % 10**9}, "parent_frame_id": "floor",
                              "child_frame_id": "shell", "translation": {"x": state[0], "y": state[1],
                                                                         "z": radius or 0.0},
                              "rotation": {"x": qx, "y": qy, "z": qz, "w": qw}})

    def command(self, t: float, accel: float, speed: float | None = None, step_time: float | None = None,
                period: int | None = None) -> None:
        """The command of a control period on /command (rad/s^2; rad/s or None; s)."""
        self.write("/command", t, {"period": period, "accel": accel, "speed": speed, "step_time": step_time})

    def mode(self, t: float, machine: str, mode: str, reason: str = "") -> None:
        """A change of ``machine``'s mode on /mode."""
        self.write("/mode", t, {"machine": machine, "mode": mode, "reason": reason})

    def link(self, t: float, stats) -> None:
        """The link's statistics so far (a ``LinkStats`` or its dict) on /link."""
        self.write("/link", t, stats if isinstance(stats, dict) else stats.to_dict())

    def flush(self) -> None:
        """Write out everything so far (a whole MCAP chunk) and flush the file."""
        if not self.closed:
            self._writer.flush()

    def close(self, result: dict | None = None) -> None:
        """Write the ``result`` metadata (contact events, metrics: JSON-ready), the index and the footer; again:
        no effect."""
        if self.closed:
            return
        self.closed = True
        try:
            if result:
                self._writer.add_metadata("result", {k: json.dumps(json_ready(v), allow_nan=False)
                                                     for k, v in result.items()})
            self._writer.finish()
        finally:
            if self._handle is not None:
                self._handle.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def run_messages(run) -> list[tuple[float, str, dict]]:
    """The messages of a finished run (``problems.RunResult``), as ``(t, topic, message)`` in time order (every
    channel but /tf, which ``LogWriter.measurement`` adds)."""
    result, dt = run.result, run.result.dt
    out = []
    times = result.t.tolist()
    for i, (t, state) in enumerate(zip(times, result.x.T.tolist())):
        out.append((t, "/measurement", {"period": i, "state": state}))
    steps = result.command.size
    speeds = [None if math.isnan(v) else v for v in result.speed_command.tolist()]
    step_times = [None] * steps if result.step_times is None else result.step_times.tolist()
    for k, (accel, diag) in enumerate(zip(result.command.tolist(), result.diag.T.tolist())):
        out.append((times[k], "/command", {"period": k, "accel": accel, "speed": speeds[k],
                                           "step_time": step_times[k]}))
        out.append((times[k], "/diagnostics", {"period": k, **dict(zip(DIAG_NAMES, diag))}))
    for record in run.references:
        record = dict(record)
        t = record.pop("k") * dt
        plan = record.pop("plan", None)
        if plan is not None:
            plan = dict(plan)
            nodes = {key: plan.pop(key) for key in ("t", "x", "y", "theta_dot")}
            out.append((t, "/plan", {"summary": plan, "nodes": nodes}))
        if "centre" in record:
            record["centre"] = {"x": record["centre"][0], "y": record["centre"][1]}
        out.append((t, "/reference", {"period": int(round(t / dt)), **record}))
    for key, machine in (("modes", "supervisor"), ("step_modes", "step")):
        for change in run.metrics.get(key) or []:
            out.append((float(change["t"]), "/mode", {"machine": machine, "mode": str(change["mode"]),
                                                      "reason": str(change.get("reason", ""))}))
    if run.metrics.get("link"):
        out.append((float(result.t[-1]), "/link", run.metrics["link"]))
    order = {topic: i for i, topic in enumerate(CHANNELS)}
    out.sort(key=lambda m: (m[0], order[m[1]]))
    return out


def _run_metadata(run) -> dict:
    result = run.result
    return {"problem": run.problem.name, "controller": run.controller, "seed": run.seed, "dt": result.dt,
            "params_file": result.params.to_file_dict(), "state_names": list(STATE_NAMES)}


def write_run_log(run, path: str | Path) -> Path:
    """Write a finished run (``problems.RunResult``) as an MCAP log at ``path``, whole (atomically)."""
    radius = float(run.result.params.R)
    with atomic_path(path) as handle:
        log = LogWriter(handle, _run_metadata(run), flush_every=math.inf)
        try:
            for t, topic, message in run_messages(run):
                if topic == "/measurement":
                    log.measurement(t, message["state"], message["period"], radius)
                else:
                    log.write(topic, t, message)
        finally:
            log.close({"events": [{"kind": e.kind, "time": e.time, "margin": e.margin} for e in run.result.events],
                       "metrics": run.metrics})
    return Path(path)


@dataclass
class LoggedRun:
    """A run read back from its MCAP log.

    Attributes
    ----------
    result : SimulationResult
        The trajectory, commands, diagnostics, step times and contact events (no onboard estimation record).
    run : dict
        The ``run`` metadata (problem, controller, seed, dt, params_file, ...).
    metrics : dict
        The run's metrics (empty if the log was not closed).
    messages : dict of str to list of (float, dict)
        Every channel's messages, ``(t, message)`` in the order written.
    complete : bool
        False if the log ends early (its writer did not close it: a crash); what it holds is read.
    """

    result: SimulationResult | None
    run: dict
    metrics: dict
    messages: dict = field(default_factory=dict)
    complete: bool = True


def _records(path: Path):
    """The records of an MCAP file to its last whole one; yields ``None`` last if the file ends early."""
    from mcap.exceptions import InvalidMagic, McapError
    from mcap.records import Footer
    from mcap.stream_reader import StreamReader

    with open(path, "rb") as handle:
        records = StreamReader(handle, record_size_limit=1 << 30).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                return
            except (McapError, EOFError, struct.error, zlib.error) as exc:
                if isinstance(exc, InvalidMagic) and handle.tell() <= 8:
                    raise
                yield None  # a log cut short (its writer died): what came before is whole
                return
            yield record
            if isinstance(record, Footer):
                return


def read_log(path: str | Path) -> LoggedRun:
    """A run from its MCAP log (written by ``LogWriter`` or ``write_run_log``, closed or cut short).

    Raises
    ------
    ConfigError
        If the file cannot be read, is not an MCAP file, is not a rollbot_oc run log, or holds no state.
    """
    path = Path(path)
    _require(path)
    from mcap.records import Channel, Message, Metadata

    channels, messages, meta, complete = {}, {topic: [] for topic in CHANNELS}, {}, True
    try:
        for record in _records(path):
            if record is None:
                complete = False
            elif isinstance(record, Channel):
                channels[record.id] = record.topic
            elif isinstance(record, Message):
                topic = channels.get(record.channel_id)
                if topic is not None:
                    message = json.loads(record.data)
                    messages.setdefault(topic, []).append((float(message["t"]), message))
            elif isinstance(record, Metadata):
                meta[record.name] = record.metadata
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the log ({exc.strerror or exc})") from None
    except Exception as exc:  # noqa: BLE001 - not MCAP (bad magic) or not our JSON
        raise ConfigError(f"{path}: not an MCAP run log ({type(exc).__name__}: {exc})") from None
    if meta.get("run", {}).get("format") != FORMAT:
        raise ConfigError(f"{path}: not a rollbot_oc run log (no 'run' metadata of format {FORMAT!r})")
    run = {k: json.loads(v) for k, v in meta["run"].items() if k != "format"}
    result_meta = {k: json.loads(v) for k, v in meta.get("result", {}).items()}
    return LoggedRun(_result(path, run, messages, result_meta), run, result_meta.get("metrics", {}), messages,
                     complete)


def _numbers(values) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], float)


def _result(path: Path, run: dict, messages: dict, result_meta: dict) -> SimulationResult:
    """The ``SimulationResult`` of a log's channels, checked as a saved run is (``SimulationResult`` loader)."""
    states = messages.get("/measurement", [])
    if len(states) < 2:
        raise ConfigError(f"{path}: the log holds {len(states)} measurement(s): a run needs two at least")
    commands = messages.get("/command", [])[:len(states) - 1]
    steps = len(commands)
    diag = np.full((len(DIAG_NAMES), steps), np.nan)  # a log without diagnostics (a robot's) has NaN there
    for k, (_, m) in enumerate(messages.get("/diagnostics", [])[:steps]):
        diag[:, k] = _numbers(m.get(name) for name in DIAG_NAMES)
    events = result_meta.get("events", [])
    arrays = {
        "t": np.array([t for t, _ in states[:steps + 1]], float),
        "x": np.array([[m["state"][name] for name in STATE_NAMES] for _, m in states[:steps + 1]], float).T,
        "command": _numbers(m["accel"] for _, m in commands[:steps]),
        "speed_command": _numbers(m["speed"] for _, m in commands[:steps]),
        "step_times": _numbers(m.get("step_time") or 0.0 for _, m in commands[:steps]),
        "diag": diag,
        "dt": np.array(run.get("dt", np.nan)), "params_file": np.array(json.dumps(run.get("params_file", {}))),
        "event_kinds": np.array([e["kind"] for e in events], dtype=str),
        "event_times": np.array([e["time"] for e in events], float),
        "event_margins": np.array([e["margin"] if e["margin"] is not None else np.nan for e in events], float),
    }
    return SimulationResult._from_arrays(arrays, str(path))
