"""A link that misbehaves on purpose, and the link's statistics.

``FaultyLink`` wraps any transport and, frame by frame (a frame ends at its 0x00 delimiter), loses, corrupts,
duplicates, delays and reorders what it sends, and cuts the link both ways for a window of time.  Its
decisions come from a seeded generator, drawn in the same order for every frame: the same seed and the same
frames give the same faults.  Delays are wall-clock time: a delayed frame is sent by a background thread when
it is due, and ``send`` never waits.

The faults are named by a link URL's query options (``open_link`` wraps the transport) or by a ``FaultSpec``::

    udp://127.0.0.1:9750?loss=0.05&jitter=0.02&dup=0.01&corrupt=0.01&reorder=0.01&disconnect=2.0@5.0&seed=3

========== ======================================================================== ==============
option     fault                                                                    range
========== ======================================================================== ==============
loss       probability that a frame is lost                                         [0, 1]
corrupt    probability that a frame has one byte changed (its CRC then fails)       [0, 1]
dup        probability that a frame is sent twice                                   [0, 1]
reorder    probability that a frame is held back and sent after the next one        [0, 1]
jitter     a frame is delayed by a uniform time in [0, jitter], s                   [0, 10]
disconnect ``D@S``: no frame passes either way for D s from S s after opening       D in (0, 3600],
                                                                                    S in [0, 86400]
seed       the generator's seed                                                     [0, 2^32 - 1]
========== ======================================================================== ==============

The receiving side tells what happened from the protocol's sequence numbers (``protocol.Decoder``: ``lost``,
``late``, ``duplicates``; corrupted frames fail their CRC and are counted in ``dropped``); ``LinkStats`` puts
those and the transport's counters in one record for a run's JSON and log.
"""

from __future__ import annotations

import heapq
import math
import random
import threading
import time
from dataclasses import asdict, dataclass, field

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.robot.link import Transport

__all__ = ["FaultSpec", "FaultCounts", "FaultyLink", "LinkStats", "parse_faults", "FAULT_OPTIONS", "REORDER_HOLD"]

MAX_SEED = 2**32 - 1
FAULT_OPTIONS = ("loss", "corrupt", "dup", "reorder", "jitter", "disconnect", "seed")
_PROBABILITIES = ("loss", "corrupt", "dup", "reorder")
JITTER_RANGE = (0.0, 10.0)  # s
DISCONNECT_RANGE = (0.0, 3600.0)  # s, duration (open below)
START_RANGE = (0.0, 86400.0)  # s
REORDER_HOLD = 0.1  # s: a frame held back to be reordered is sent after this long if no other frame follows


def _check(where: str, name: str, value, low: float, high: float, open_low: bool = False) -> float:
    valid = f"({low:g}, {high:g}]" if open_low else f"[{low:g}, {high:g}]"
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}option {name} = {value!r} is not a number in {valid}") from None
    if not (math.isfinite(number) and (low < number if open_low else low <= number) and number <= high):
        raise ConfigError(f"{where}option {name} = {value!r} is out of range {valid}")
    return number


@dataclass(frozen=True)
class FaultSpec:
    """The faults of a ``FaultyLink`` (the module docstring's options, checked: ``ConfigError`` naming the
    option, its value and its range).

    Parameters
    ----------
    loss, corrupt, dup, reorder : float
        Probabilities per frame, in [0, 1].
    jitter : float
        Largest delay of a frame, s, in [0, 10].
    disconnect : tuple of (float, float) or None
        ``(duration, start)``, s: the link passes nothing either way from ``start`` s after opening for
        ``duration`` s.
    seed : int
        Seed of the generator, in [0, 2^32 - 1].
    where : str
        What the options came from (a URL), for messages; not a fault.
    """

    loss: float = 0.0
    corrupt: float = 0.0
    dup: float = 0.0
    reorder: float = 0.0
    jitter: float = 0.0
    disconnect: tuple | None = None
    seed: int = 0
    where: str = field(default="", compare=False)

    def __post_init__(self):
        where = f"{self.where}: " if self.where else ""
        for name in _PROBABILITIES:
            object.__setattr__(self, name, _check(where, name, getattr(self, name), 0.0, 1.0))
        object.__setattr__(self, "jitter", _check(where, "jitter", self.jitter, *JITTER_RANGE))
        if self.disconnect is not None:
            try:
                duration, start = self.disconnect
            except (TypeError, ValueError):
                raise ConfigError(f"{where}option disconnect = {self.disconnect!r} is not a (duration, start) "
                                  "pair: write disconnect=D@S (D s from S s after opening)") from None
            object.__setattr__(self, "disconnect", (_check(where, "disconnect", duration, *DISCONNECT_RANGE, True),
                                                    _check(where, "disconnect start", start, *START_RANGE)))
        seed = self.seed
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
            raise ConfigError(f"{where}option seed = {seed!r} is out of range: valid is a whole number in "
                              f"[0, {MAX_SEED}]")

    @property
    def any(self) -> bool:
        """True if any fault is asked for."""
        return bool(any(getattr(self, n) for n in _PROBABILITIES) or self.jitter or self.disconnect)


def parse_faults(query: dict, where: str = "") -> FaultSpec | None:
    """The ``FaultSpec`` of a URL's fault options (``{name: [text]}``, as ``urllib.parse.parse_qs`` gives;
    other names are ignored), or None if it has none."""
    given = {name: values for name, values in query.items() if name in FAULT_OPTIONS}
    if not given:
        return None
    prefix = f"{where}: " if where else ""
    options = {}
    for name, values in given.items():
        if len(values) != 1:
            raise ConfigError(f"{prefix}option {name} is given {len(values)} times")
        text = values[0]
        if name == "disconnect":
            duration, at, start = text.partition("@")
            if not at:
                raise ConfigError(f"{prefix}option disconnect = {text!r}: write disconnect=D@S (D s from S s "
                                  "after opening)")
            options[name] = (duration, start)
        elif name == "seed":
            if not text.isdigit():
                raise ConfigError(f"{prefix}option seed = {text!r} is not a whole number in [0, {MAX_SEED}]")
            options[name] = int(text)
        else:
            options[name] = text
    return FaultSpec(**options, where=where)


@dataclass
class FaultCounts:
    """What a ``FaultyLink`` did to the frames it was given to send.

    Attributes
    ----------
    frames : int
        Frames given to ``send``.
    lost, corrupted, duplicated : int
        Frames lost, sent with a byte changed, sent twice.
    delayed : int
        Frames delayed by the jitter (by more than 0 s).
    reordered : int
        Frames sent after a frame given later (held back, or delayed past it).
    disconnected : int
        Frames not sent because the link was cut then.
    bytes_cut : int
        Bytes received while the link was cut, thrown away.
    """

    frames: int = 0
    lost: int = 0
    corrupted: int = 0
    duplicated: int = 0
    delayed: int = 0
    reordered: int = 0
    disconnected: int = 0
    bytes_cut: int = 0

    def to_dict(self) -> dict:
        """The counts as a JSON-ready dict."""
        return asdict(self)


class FaultyLink(Transport):
    """A transport whose frames suffer the faults of ``faults`` (module docstring); a ``Transport`` itself.

    Parameters
    ----------
    inner : Transport
        The link that carries the frames (closed with this one).
    faults : FaultSpec
    clock : callable, default time.monotonic
        Wall-clock time, s (the disconnect window and delays).

    Attributes
    ----------
    counters : LinkCounters
        The inner transport's: what went on the wire.
    injected : FaultCounts
        What was done to the frames sent.
    """

    def __init__(self, inner: Transport, faults: FaultSpec, clock=time.monotonic):
        super().__init__(inner.spec)
        self.inner, self.faults, self.clock = inner, faults, clock
        self.counters = inner.counters
        self.injected = FaultCounts()
        self._rng = random.Random(faults.seed)
        self._opened = clock()
        self._index = 0
        self._queue: list = []  # (due, order, index, frame)
        self._order = 0
        self._held = None  # (deadline, index, frame, copies, delay): the frame held back to be reordered
        self._newest = -1  # the index of the newest frame sent
        self._lock = threading.Condition()
        self._closed = False
        self._thread = None
        if faults.jitter > 0 or faults.reorder > 0:
            self._thread = threading.Thread(target=self._deliver_loop, name="FaultyLink", daemon=True)
            self._thread.start()

    def cut(self, now: float | None = None) -> bool:
        """True if the link is cut (inside the disconnect window) at ``now`` (default: the clock's now)."""
        window = self.faults.disconnect
        if window is None:
            return False
        elapsed = (self.clock() if now is None else now) - self._opened
        return window[1] <= elapsed < window[1] + window[0]

    def send(self, data: bytes) -> None:
        data = bytes(data)
        parts = data.split(b"\x00")
        frames = [part + b"\x00" for part in parts[:-1]]
        if parts[-1]:
            frames.append(parts[-1])  # no delimiter: the rest of a frame, faulted as one
        with self._lock:
            for frame in frames:
                if frame != b"\x00":
                    self._frame(frame)
                else:
                    self._enqueue(self.clock(), -1, frame)
            self._lock.notify()
        if self._thread is None:
            self._deliver(self.clock())

    def _frame(self, frame: bytes) -> None:
        f, counts = self.faults, self.injected
        r = self._rng
        # every draw for every frame, in one order: the faults of frame i depend on the seed and i only
        lose, corrupt, dup, reorder, jitter = r.random(), r.random(), r.random(), r.random(), r.random()
        position, value = r.randrange(max(1, len(frame) - 1)), r.randrange(1, 255)
        index, now = self._index, self.clock()
        self._index += 1
        counts.frames += 1
        if lose < f.loss:
            counts.lost += 1
            return
        if corrupt < f.corrupt and len(frame) > 1:
            body = bytearray(frame)
            old = body[position]
            body[position] = value if value < old else value + 1  # any byte but the old one and 0x00
            frame = bytes(body)
            counts.corrupted += 1
        delay = f.jitter * jitter
        if delay > 0:
            counts.delayed += 1
        copies = 2 if dup < f.dup else 1
        counts.duplicated += copies - 1
        if reorder < f.reorder and self._held is None:
            self._held = (now + REORDER_HOLD, index, frame, copies, delay)
            return
        due = now + delay
        for _ in range(copies):
            self._enqueue(due, index, frame)
        self._release(due)

    def _release(self, after: float) -> None:
        """Send the frame held back (if any), due no sooner than ``after``."""
        if self._held is not None:
            deadline, index, frame, copies, delay = self._held
            self._held = None
            due = max(after, deadline - REORDER_HOLD + delay)
            for _ in range(copies):
                self._enqueue(due, index, frame)

    def _enqueue(self, due: float, index: int, frame: bytes) -> None:
        heapq.heappush(self._queue, (due, self._order, index, frame))
        self._order += 1

    def _deliver(self, now: float) -> float | None:
        """Send the frames due at ``now``; the time the next one is due (None: none waits)."""
        with self._lock:
            if self._held is not None and self._held[0] <= now:
                self._release(now)
            due = []
            while self._queue and self._queue[0][0] <= now:
                due.append(heapq.heappop(self._queue))
            nxt = min([q[0] for q in self._queue[:1]] + ([self._held[0]] if self._held else []), default=None)
            for _, _, index, frame in due:
                if self.cut(now):
                    self.injected.disconnected += frame.count(0) or 1
                    continue
                if 0 <= index < self._newest:
                    self.injected.reordered += 1
                self._newest = max(self._newest, index)
                if not self._closed:
                    self.inner.send(frame)
        return nxt

    def _deliver_loop(self) -> None:
        while True:
            with self._lock:
                if self._closed:
                    return
            nxt = self._deliver(self.clock())
            with self._lock:
                if self._closed:
                    return
                wait = None if nxt is None else max(0.0, nxt - self.clock())
                if wait is None or wait > 0:
                    self._lock.wait(timeout=wait if wait is not None else 0.5)

    def receive(self, timeout: float = 0.0) -> bytes:
        if self._thread is None:
            self._deliver(self.clock())
        data = self.inner.receive(timeout)
        if data and self.cut():
            self.injected.bytes_cut += len(data)
            return b""
        return data

    @property
    def pending(self) -> int:
        """Frames waiting to be sent (delayed or held back)."""
        with self._lock:
            return len(self._queue) + (self._held is not None)

    def close(self) -> None:
        """Stop (frames still waiting are not sent) and close the inner transport."""
        with self._lock:
            self._closed = True
            self._lock.notify_all()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)
        self.inner.close()


@dataclass(frozen=True)
class LinkStats:
    """A link's statistics, as a run's JSON and log (/link) carry them.

    Attributes
    ----------
    frames_sent, bytes_sent, frames_received, bytes_received : int
        What went on the wire each way (the transport's counters).
    lost : int
        Frames the receiving decoder never got (sequence numbers skipped and not filled later).
    late : int
        Frames decoded after a later-numbered one (reordered or delayed on the way).
    duplicated : int
        Frames decoded twice.
    corrupted : int
        Frames that did not decode (a failed CRC, COBS or length check), dropped.
    injected : dict or None
        What a ``FaultyLink`` did to the frames sent (``FaultCounts``), if there is one.
    """

    frames_sent: int = 0
    bytes_sent: int = 0
    frames_received: int = 0
    bytes_received: int = 0
    lost: int = 0
    late: int = 0
    duplicated: int = 0
    corrupted: int = 0
    injected: dict | None = None

    @classmethod
    def of(cls, link: Transport, decoder) -> "LinkStats":
        """The statistics of a transport and the ``protocol.Decoder`` of what it received."""
        c = link.counters
        injected = getattr(link, "injected", None)
        return cls(c.frames_sent, c.bytes_sent, c.frames_received, c.bytes_received, decoder.lost, decoder.late,
                   decoder.duplicates, decoder.dropped, injected.to_dict() if injected is not None else None)

    def to_dict(self) -> dict:
        """The record as a JSON-ready dict."""
        return asdict(self)
