"""The robot link's wire protocol: versioned, checksummed messages in COBS frames.

The same protocol is written in C for the robot (``rollbot_oc/robot/c/rollbot_link.c``); a test checks
that each side decodes what the other encodes and that both encode byte for byte alike.

Frame layout
------------
A frame on the wire is a packet, COBS-encoded (so it holds no zero byte), followed by one ``0x00``
delimiter.  The packet (little-endian throughout)::

    offset  size  field
    0       1     version (u8), VERSION = 1
    1       1     message type (u8), a MessageType
    2       2     sequence number (u16): the sender's count of frames sent, wrapping at 65536
    4       2     payload length n (u16), at most MAX_PAYLOAD = 244
    6       n     payload (below)
    6+n     4     CRC-32 (IEEE 802.3, as zlib.crc32) of bytes 0 .. 5+n

A packet is 10 + n bytes; COBS adds one byte to any packet of at most 253 bytes (two at most to the
largest, 254), and the delimiter one more: a frame is 12 + n bytes.

Payloads::

    HEARTBEAT   (1)  5 bytes  time_ms u32 (the sender's clock, ms, wrapping), mode u8
    MEASUREMENT (2)  56 bytes period u32, time f64 (s), state 11 x f32 (the full state of
                              rollbot_oc.model.dynamics: x, y [m]; qw, qx, qy, qz; wx, wy, wz [rad/s];
                              theta [rad]; theta_dot [rad/s]; single precision, 1e-7 of each value,
                              so that 100 measurements a second take 59 % of a 115200-baud UART)
    COMMAND     (3)  13 bytes period u32, motor acceleration f64 (rad/s^2), status u8
    PLAN_CHUNK  (4) 6+k bytes plan_id u16, index u16, count u16, k bytes of the plan (k <= MAX_CHUNK = 238)
    MODE        (5)  6 bytes  mode u8, tick u32 (the control period it took effect), reason u8

The mode, status and reason codes are the application's; the link carries them unchanged.  Frames are
thus 17 (HEARTBEAT), 68 (MEASUREMENT), 25 (COMMAND), 18 + k (PLAN_CHUNK) and 18 (MODE) bytes.

Decoding never raises on bad input: ``Decoder`` counts each frame it drops by its reason (COBS,
CRC, length, version, type, payload, overflow) and goes on with the next delimiter.
"""

from __future__ import annotations

import enum
import math
import struct
import zlib
from dataclasses import dataclass
from typing import ClassVar

__all__ = [
    "VERSION", "SEQ_WINDOW", "MAX_PAYLOAD", "MAX_CHUNK", "MAX_ENCODED", "HEADER_BYTES", "CRC_BYTES", "STATE_SIZE",
    "MessageType", "Heartbeat", "Measurement", "Command", "PlanChunk", "Mode", "Message", "Packet",
    "cobs_encode", "cobs_decode", "CobsError", "crc32", "encode", "decode_frame", "FrameError",
    "Decoder", "split_plan", "PlanAssembler",
]

VERSION = 1
HEADER_BYTES = 6  # version, type, sequence number, payload length
CRC_BYTES = 4
MAX_PAYLOAD = 244  # so that a packet is at most 254 bytes, one COBS block
MAX_PACKET = HEADER_BYTES + MAX_PAYLOAD + CRC_BYTES
MAX_ENCODED = MAX_PACKET + MAX_PACKET // 254 + 1  # a packet's COBS encoding at most (256 bytes)
STATE_SIZE = 11
SEQ_WINDOW = 32  # sequence numbers behind the highest one that the decoder remembers (duplicates, late frames)
_PLAN_HEADER = struct.Struct("<HHH")
MAX_CHUNK = MAX_PAYLOAD - _PLAN_HEADER.size  # plan bytes in one PLAN_CHUNK (238)

_HEADER = struct.Struct("<BBHH")
_CRC = struct.Struct("<I")


class MessageType(enum.IntEnum):
    """The message type byte of a packet."""

    HEARTBEAT = 1
    MEASUREMENT = 2
    COMMAND = 3
    PLAN_CHUNK = 4
    MODE = 5


def _uint(name: str, value, bits: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) and not hasattr(value, "__index__"):
        raise TypeError(f"{name} must be an integer, not {type(value).__name__}")
    value = int(value)
    if not 0 <= value < (1 << bits):
        raise ValueError(f"{name} = {value} is out of range: valid is [0, {(1 << bits) - 1}] (u{bits})")
    return value


def _set(obj, name: str, value) -> None:
    object.__setattr__(obj, name, value)


@dataclass(frozen=True)
class Heartbeat:
    """HEARTBEAT: the sender is alive.

    Parameters
    ----------
    time_ms : int
        The sender's clock, ms (u32, wraps after about 49.7 days).
    mode : int
        The sender's mode code (u8, the application's).
    """

    time_ms: int
    mode: int
    TYPE: ClassVar[MessageType] = MessageType.HEARTBEAT
    _FORMAT: ClassVar[struct.Struct] = struct.Struct("<IB")

    def __post_init__(self):
        _set(self, "time_ms", _uint("time_ms", self.time_ms, 32))
        _set(self, "mode", _uint("mode", self.mode, 8))

    def pack(self) -> bytes:
        """The payload (5 bytes)."""
        return self._FORMAT.pack(self.time_ms, self.mode)

    @classmethod
    def unpack(cls, payload: bytes) -> "Heartbeat":
        """The message of a payload; ``ValueError`` if its length is not 5 bytes."""
        return cls(*_unpack(cls._FORMAT, payload))


F32_MAX = 3.4028234663852886e38  # the largest finite single-precision number


def _f32(x: float) -> float:
    """``x`` rounded to the nearest single-precision number (to the nearest even on a tie), as C's ``(float)``
    cast does; infinite beyond the single-precision range (where the cast is undefined, the C side clamps the
    same way)."""
    if math.isfinite(x) and abs(x) > F32_MAX:
        rounded = struct.unpack("<f", struct.pack("<f", math.copysign(F32_MAX, x)))[0]
        # beyond half a unit past the largest float, the nearest is infinity
        return math.copysign(math.inf, x) if abs(x) >= F32_MAX + 2.0 ** 103 else rounded
    return struct.unpack("<f", struct.pack("<f", x))[0]


@dataclass(frozen=True)
class Measurement:
    """MEASUREMENT: the robot's state at the start of a control period (robot -> host).

    Parameters
    ----------
    period : int
        Control period index (u32).
    time : float
        Time of the measurement, s (f64).
    state : tuple of 11 float
        The full state of ``rollbot_oc.model.dynamics`` (position m, quaternion, angular velocity rad/s,
        motor angle rad, driving speed rad/s); any sequence of 11 numbers, kept as a tuple of floats
        rounded to single precision (f32, as on the wire; beyond its range, infinite).
    """

    period: int
    time: float
    state: tuple
    TYPE: ClassVar[MessageType] = MessageType.MEASUREMENT
    _FORMAT: ClassVar[struct.Struct] = struct.Struct(f"<Id{STATE_SIZE}f")

    def __post_init__(self):
        _set(self, "period", _uint("period", self.period, 32))
        _set(self, "time", float(self.time))
        state = tuple(_f32(float(v)) for v in self.state)
        if len(state) != STATE_SIZE:
            raise ValueError(f"state has {len(state)} values: a measurement carries the full state ({STATE_SIZE})")
        _set(self, "state", state)

    def pack(self) -> bytes:
        """The payload (56 bytes)."""
        return self._FORMAT.pack(self.period, self.time, *self.state)

    @classmethod
    def unpack(cls, payload: bytes) -> "Measurement":
        """The message of a payload; ``ValueError`` if its length is not 56 bytes."""
        values = _unpack(cls._FORMAT, payload)
        return cls(values[0], values[1], values[2:])


@dataclass(frozen=True)
class Command:
    """COMMAND: the motor acceleration for a control period (host -> robot).

    Parameters
    ----------
    period : int
        The control period it applies to (u32).
    acceleration : float
        Motor acceleration theta_ddot, rad/s^2 (f64).
    status : int
        The controller's status code (u8, the application's; for example ``ROLLBOT_STATUS_*``).
    """

    period: int
    acceleration: float
    status: int = 0
    TYPE: ClassVar[MessageType] = MessageType.COMMAND
    _FORMAT: ClassVar[struct.Struct] = struct.Struct("<IdB")

    def __post_init__(self):
        _set(self, "period", _uint("period", self.period, 32))
        _set(self, "acceleration", float(self.acceleration))
        _set(self, "status", _uint("status", self.status, 8))

    def pack(self) -> bytes:
        """The payload (13 bytes)."""
        return self._FORMAT.pack(self.period, self.acceleration, self.status)

    @classmethod
    def unpack(cls, payload: bytes) -> "Command":
        """The message of a payload; ``ValueError`` if its length is not 13 bytes."""
        return cls(*_unpack(cls._FORMAT, payload))


@dataclass(frozen=True)
class PlanChunk:
    """PLAN_CHUNK: one piece of a plan's bytes (host -> robot); ``split_plan`` makes them.

    Parameters
    ----------
    plan_id : int
        The plan's identifier (u16).
    index : int
        This chunk's index, ``0 <= index < count`` (u16).
    count : int
        Number of chunks of the plan, at least 1 (u16).
    data : bytes
        The chunk's bytes, at most ``MAX_CHUNK`` (238).
    """

    plan_id: int
    index: int
    count: int
    data: bytes
    TYPE: ClassVar[MessageType] = MessageType.PLAN_CHUNK

    def __post_init__(self):
        _set(self, "plan_id", _uint("plan_id", self.plan_id, 16))
        _set(self, "index", _uint("index", self.index, 16))
        _set(self, "count", _uint("count", self.count, 16))
        _set(self, "data", bytes(self.data))
        if not self.index < self.count:
            raise ValueError(f"chunk index {self.index} is out of range: valid is [0, {self.count - 1}]")
        if len(self.data) > MAX_CHUNK:
            raise ValueError(f"a chunk holds {len(self.data)} bytes: at most {MAX_CHUNK}")

    def pack(self) -> bytes:
        """The payload (6 + len(data) bytes)."""
        return _PLAN_HEADER.pack(self.plan_id, self.index, self.count) + self.data

    @classmethod
    def unpack(cls, payload: bytes) -> "PlanChunk":
        """The message of a payload; ``ValueError`` if it is shorter than 6 bytes or its fields are invalid."""
        if not _PLAN_HEADER.size <= len(payload) <= MAX_PAYLOAD:
            raise ValueError(f"a PLAN_CHUNK payload has {_PLAN_HEADER.size} to {MAX_PAYLOAD} bytes, not {len(payload)}")
        return cls(*_PLAN_HEADER.unpack_from(payload), bytes(payload[_PLAN_HEADER.size:]))


@dataclass(frozen=True)
class Mode:
    """MODE: the sender's mode changed.

    Parameters
    ----------
    mode : int
        The new mode's code (u8, the application's).
    tick : int
        The control period it took effect (u32).
    reason : int
        The reason's code (u8, the application's).
    """

    mode: int
    tick: int
    reason: int = 0
    TYPE: ClassVar[MessageType] = MessageType.MODE
    _FORMAT: ClassVar[struct.Struct] = struct.Struct("<BIB")

    def __post_init__(self):
        _set(self, "mode", _uint("mode", self.mode, 8))
        _set(self, "tick", _uint("tick", self.tick, 32))
        _set(self, "reason", _uint("reason", self.reason, 8))

    def pack(self) -> bytes:
        """The payload (6 bytes)."""
        return self._FORMAT.pack(self.mode, self.tick, self.reason)

    @classmethod
    def unpack(cls, payload: bytes) -> "Mode":
        """The message of a payload; ``ValueError`` if its length is not 6 bytes."""
        return cls(*_unpack(cls._FORMAT, payload))


Message = Heartbeat | Measurement | Command | PlanChunk | Mode
_CLASSES = {cls.TYPE: cls for cls in (Heartbeat, Measurement, Command, PlanChunk, Mode)}


def _unpack(fmt: struct.Struct, payload: bytes) -> tuple:
    if len(payload) != fmt.size:
        raise ValueError(f"payload has {len(payload)} bytes, not {fmt.size}")
    return fmt.unpack(payload)


@dataclass(frozen=True)
class Packet:
    """A decoded frame: its sequence number and its message."""

    seq: int
    message: Message


# --- COBS and CRC -----------------------------------------------------------------------------------------

class CobsError(ValueError):
    """Bytes that are not a valid COBS encoding."""


def cobs_encode(data: bytes) -> bytes:
    """COBS encoding of ``data`` (no zero byte in the result; the delimiter is not added).

    Blocks of 254 non-zero bytes get code 0xFF; a trailing full block is followed by a code 0x01 (as the
    C side encodes), so the result is ``len(data) + len(data) // 254 + 1`` bytes at most.
    """
    out = bytearray()
    for part in bytes(data).split(b"\x00"):
        while len(part) >= 254:
            out.append(0xFF)
            out += part[:254]
            part = part[254:]
        out.append(len(part) + 1)
        out += part
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """The bytes a COBS encoding (without delimiter) stands for; ``CobsError`` if it is not one."""
    data = bytes(data)
    out = bytearray()
    i, n = 0, len(data)
    if n == 0:
        raise CobsError("empty COBS block")
    while i < n:
        code = data[i]
        end = i + code
        if code == 0 or end > n:
            raise CobsError(f"bad COBS code {code} at byte {i} of {n}")
        block = data[i + 1:end]
        if 0 in block:
            raise CobsError("zero byte inside a COBS block")
        out += block
        i = end
        if code < 0xFF and i < n:
            out.append(0)
    return bytes(out)


def crc32(data: bytes) -> int:
    """CRC-32 (IEEE 802.3: reflected polynomial 0xEDB88320, initial and final XOR 0xFFFFFFFF)."""
    return zlib.crc32(data) & 0xFFFFFFFF


# --- frames -----------------------------------------------------------------------------------------------

def encode(message: Message, seq: int) -> bytes:
    """The frame of ``message`` with sequence number ``seq``: COBS-encoded packet and its 0x00 delimiter.

    Parameters
    ----------
    message : Heartbeat, Measurement, Command, PlanChunk or Mode
        The message.
    seq : int
        Sequence number, u16 (the caller wraps it: ``seq % 65536``).

    Returns
    -------
    bytes
        The frame, ready to send (12 bytes more than the payload for any message).
    """
    payload = message.pack()
    body = _HEADER.pack(VERSION, int(message.TYPE), _uint("seq", seq, 16), len(payload)) + payload
    return cobs_encode(body + _CRC.pack(crc32(body))) + b"\x00"


class FrameError(ValueError):
    """A frame that does not decode; ``reason`` is the counter it is counted under."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


def decode_frame(frame: bytes) -> Packet:
    """The packet of one frame (COBS bytes, without the 0x00 delimiter).

    Raises
    ------
    FrameError
        With ``reason`` one of ``"cobs"``, ``"length"``, ``"crc"``, ``"version"``, ``"type"``, ``"payload"``.
    """
    try:
        packet = cobs_decode(frame)
    except CobsError as err:
        raise FrameError("cobs", str(err)) from None
    if not HEADER_BYTES + CRC_BYTES <= len(packet) <= MAX_PACKET:
        raise FrameError("length", f"a packet of {len(packet)} bytes: valid is [{HEADER_BYTES + CRC_BYTES}, "
                                   f"{MAX_PACKET}]")
    (crc,) = _CRC.unpack_from(packet, len(packet) - CRC_BYTES)
    if crc32(packet[:-CRC_BYTES]) != crc:
        raise FrameError("crc", "CRC mismatch")
    version, kind, seq, length = _HEADER.unpack_from(packet)
    if length != len(packet) - HEADER_BYTES - CRC_BYTES or length > MAX_PAYLOAD:
        raise FrameError("length", f"payload length {length} does not match the packet's {len(packet)} bytes")
    if version != VERSION:
        raise FrameError("version", f"protocol version {version}: this side speaks {VERSION}")
    cls = _CLASSES.get(kind)
    if cls is None:
        raise FrameError("type", f"unknown message type {kind}")
    try:
        message = cls.unpack(packet[HEADER_BYTES:HEADER_BYTES + length])
    except (ValueError, TypeError, struct.error) as err:
        raise FrameError("payload", f"{cls.TYPE.name}: {err}") from None
    return Packet(seq, message)


class Decoder:
    """Streaming decoder: bytes in, in chunks of any size; decoded packets out.

    Bad input never raises: each dropped frame is counted in ``errors`` under its reason (``cobs``,
    ``crc``, ``length``, ``version``, ``type``, ``payload``; ``overflow`` for more than ``MAX_ENCODED``
    bytes without a delimiter, dropped up to the next one).  Empty frames (two delimiters in a row) are
    skipped without being counted, so a sender may start with a delimiter to flush a partial frame.

    Attributes
    ----------
    frames : int
        Frames decoded.
    errors : dict of str to int
        Frames dropped, by reason.
    missed : int
        Sequence numbers skipped ahead of the highest one decoded so far (frames lost, dropped or still on
        the way, assuming the sender numbers every frame it sends).
    late : int
        Frames decoded after a frame with a later sequence number (reordered or delayed on the way): not seen
        before within the last ``SEQ_WINDOW`` (32) numbers, or older than that.
    duplicates : int
        Frames whose sequence number was decoded already, within the last ``SEQ_WINDOW`` numbers.

    Every frame that decodes is returned, late and duplicated ones too (the application's period numbers
    tell it a command or measurement it has already used); ``lost`` is ``missed - late``.
    """

    REASONS = ("cobs", "crc", "length", "version", "type", "payload", "overflow")

    def __init__(self):
        self._buffer = bytearray()
        self._discarding = False
        self._last_seq: int | None = None
        self._seen = 0  # bit i: sequence number _last_seq - i decoded
        self.frames = 0
        self.missed = 0
        self.late = 0
        self.duplicates = 0
        self.errors = dict.fromkeys(self.REASONS, 0)

    @property
    def dropped(self) -> int:
        """Frames dropped, all reasons together."""
        return sum(self.errors.values())

    @property
    def lost(self) -> int:
        """Sequence numbers skipped and not decoded later (``missed - late``, at least 0)."""
        return max(0, self.missed - self.late)

    def _sequence(self, seq: int) -> None:
        """Count ``seq`` against the numbers decoded so far (as the C decoder does)."""
        if self._last_seq is None:
            self._last_seq, self._seen = seq, 1
            return
        ahead = (seq - self._last_seq) % 65536
        if 0 < ahead < 32768:
            self.missed += ahead - 1
            self._seen = ((self._seen << ahead) | 1) & 0xFFFFFFFF if ahead < SEQ_WINDOW else 1
            self._last_seq = seq
            return
        back = (self._last_seq - seq) % 65536
        if back < SEQ_WINDOW and self._seen >> back & 1:
            self.duplicates += 1
        else:
            self.late += 1
            if back < SEQ_WINDOW:
                self._seen |= 1 << back

    def feed(self, data: bytes) -> list[Packet]:
        """Take the next bytes of the stream; return the packets of the frames they complete, in order."""
        packets = []
        parts = bytes(data).split(b"\x00")
        for k, part in enumerate(parts):
            if not self._discarding:
                self._buffer += part
                if len(self._buffer) > MAX_ENCODED:
                    self.errors["overflow"] += 1
                    self._buffer.clear()
                    self._discarding = True
            if k == len(parts) - 1:
                break  # no delimiter after the last part: the frame goes on in the next chunk
            frame = bytes(self._buffer)
            self._buffer.clear()
            if self._discarding:
                self._discarding = False
                continue
            if not frame:
                continue
            try:
                packet = decode_frame(frame)
            except FrameError as err:
                self.errors[err.reason] += 1
                continue
            self._sequence(packet.seq)
            self.frames += 1
            packets.append(packet)
        return packets


# --- plans ------------------------------------------------------------------------------------------------

def split_plan(plan_bytes: bytes, plan_id: int, max_chunk: int = 200) -> list[PlanChunk]:
    """The PLAN_CHUNK messages of a plan, to send once when it is ready.

    Parameters
    ----------
    plan_bytes : bytes
        The plan, serialised by the application (the link does not read it).
    plan_id : int
        The plan's identifier (u16).
    max_chunk : int, default 200
        Plan bytes per chunk, 1 to ``MAX_CHUNK`` (238).

    Returns
    -------
    list of PlanChunk
        ``ceil(len / max_chunk)`` chunks (one, empty, for an empty plan), in order.
    """
    if not 1 <= max_chunk <= MAX_CHUNK:
        raise ValueError(f"max_chunk = {max_chunk} is out of range: valid is [1, {MAX_CHUNK}]")
    data = bytes(plan_bytes)
    count = max(1, math.ceil(len(data) / max_chunk))
    if count > 0xFFFF:
        raise ValueError(f"a plan of {len(data)} bytes needs {count} chunks of {max_chunk}: at most 65535")
    return [PlanChunk(plan_id, i, count, data[i * max_chunk:(i + 1) * max_chunk]) for i in range(count)]


class PlanAssembler:
    """Rebuilds plans from their chunks, received in any order; duplicates are ignored.

    Parameters
    ----------
    keep : int, default 4
        Plans assembled at once; a chunk of a further plan drops the one least recently added to.

    Attributes
    ----------
    duplicates : int
        Chunks ignored: already held, or of a plan already completed.
    restarted : int
        Plans whose assembly restarted because a chunk gave a different chunk count for their id.
    """

    def __init__(self, keep: int = 4):
        self.keep = keep
        self._parts: dict[int, tuple[int, dict[int, bytes]]] = {}
        self._done: list[int] = []  # the ids of the last plans completed, oldest first
        self.duplicates = 0
        self.restarted = 0

    def add(self, chunk: PlanChunk) -> bytes | None:
        """Take one chunk; return the plan's bytes when this chunk completes it, else None."""
        if chunk.plan_id in self._done:
            self.duplicates += 1
            return None
        count, parts = self._parts.get(chunk.plan_id, (chunk.count, {}))
        if count != chunk.count:
            self.restarted += 1
            count, parts = chunk.count, {}
        if chunk.index in parts:
            self.duplicates += 1
            return None
        parts[chunk.index] = chunk.data
        self._parts.pop(chunk.plan_id, None)
        self._parts[chunk.plan_id] = (count, parts)  # most recently touched last
        while len(self._parts) > self.keep:
            del self._parts[next(iter(self._parts))]
        if len(parts) < count:
            return None
        del self._parts[chunk.plan_id]
        self._done = (self._done + [chunk.plan_id])[-self.keep:]
        return b"".join(parts[i] for i in range(count))

    def forget(self, plan_id: int) -> None:
        """Accept ``plan_id`` again (a new plan under an id already completed)."""
        self._parts.pop(plan_id, None)
        self._done = [p for p in self._done if p != plan_id]

    def pending(self) -> dict[int, tuple[int, int]]:
        """Plans in assembly: id -> (chunks held, chunk count)."""
        return {pid: (len(parts), count) for pid, (count, parts) in self._parts.items()}
