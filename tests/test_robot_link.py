"""The robot link: the protocol's round trips and corruption counting, Python against the C codec (ctypes),
the UDP and serial transports, link URLs, and the link's traffic against a 115200-baud UART."""

import ctypes
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rollbot_oc.model.codegen import compiler
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.robot import protocol as P
from rollbot_oc.robot.protocol import (
    Command, Decoder, Heartbeat, Measurement, Mode, PlanAssembler, PlanChunk, decode_frame, encode, split_plan,
)
from rollbot_oc.robot.transport import LinkSpec, open_link, parse_link

ROOT = Path(__file__).resolve().parents[1]
C_DIR = ROOT / "rollbot_oc" / "robot" / "c"

u8, u16, u32 = (st.integers(0, (1 << b) - 1) for b in (8, 16, 32))
f64 = st.floats(allow_nan=True, allow_infinity=True)
finite = st.floats(allow_nan=False, allow_infinity=False)
messages = st.one_of(
    st.builds(Heartbeat, u32, u8),
    st.builds(Measurement, u32, f64, st.lists(f64, min_size=11, max_size=11)),
    st.builds(Command, u32, f64, u8),
    st.integers(1, 65535).flatmap(lambda count: st.builds(
        PlanChunk, u16, st.integers(0, count - 1), st.just(count), st.binary(max_size=P.MAX_CHUNK))),
    st.builds(Mode, u8, u32, u8),
)


def same(a, b) -> bool:
    """Equal messages, NaN included (compared by their payloads)."""
    return type(a) is type(b) and a.pack() == b.pack()


# --- protocol -------------------------------------------------------------------------------------------------

@given(messages, u16)
def test_every_message_round_trips(message, seq):
    frame = encode(message, seq)
    assert frame.endswith(b"\x00") and 0 not in frame[:-1]
    assert len(frame) == len(message.pack()) + 12  # header 6, CRC 4, COBS 1, delimiter 1
    packet = decode_frame(frame[:-1])
    assert packet.seq == seq and same(packet.message, message)
    if not any(np.isnan(getattr(message, "state", ()) + (getattr(message, "time", 0.0),
                                                           getattr(message, "acceleration", 0.0)))):
        assert packet.message == message


def test_frame_sizes():
    assert [len(encode(m, 0)) for m in (Heartbeat(0, 0), Measurement(0, 0.0, [0.0] * 11), Command(0, 0.0),
                                        PlanChunk(0, 0, 1, b""), Mode(0, 0))] == [17, 68, 25, 18, 18]
    assert len(encode(PlanChunk(0, 0, 1, bytes(range(1, 239))), 0)) == 18 + P.MAX_CHUNK
    assert P.MAX_ENCODED == 256


@given(st.binary(max_size=600))
def test_cobs_round_trips(data):
    encoded = P.cobs_encode(data)
    assert 0 not in encoded and len(encoded) <= len(data) + len(data) // 254 + 1
    assert P.cobs_decode(encoded) == data


@given(st.lists(st.tuples(messages, u16), min_size=1, max_size=8), st.lists(st.integers(0, 2000), max_size=12))
def test_any_chunking_of_a_stream_decodes(sent, cuts):
    stream = b"".join(encode(m, s) for m, s in sent)
    cuts = sorted({c % (len(stream) + 1) for c in cuts})
    decoder = Decoder()
    got = []
    for a, b in zip([0] + cuts, cuts + [len(stream)]):
        got += decoder.feed(stream[a:b])
    assert [p.seq for p in got] == [s for _, s in sent]
    assert all(same(p.message, m) for p, (m, _) in zip(got, sent))
    assert decoder.frames == len(sent) and decoder.dropped == 0


def three_frames(middle: bytes) -> tuple[list, Decoder]:
    before, after = encode(Command(7, 1.5, 2), 10), encode(Heartbeat(123, 1), 12)
    decoder = Decoder()
    return decoder.feed(before + middle + after), decoder


@given(st.integers(0, 8 * 67 - 1))  # every bit of the 68-byte frame but its delimiter
def test_a_flipped_bit_is_counted_and_dropped(bit):
    frame = bytearray(encode(Measurement(11, 0.11, np.linspace(-1, 1, 11)), 11))
    frame[bit // 8] ^= 1 << (bit % 8)
    got, decoder = three_frames(bytes(frame))
    assert [p.seq for p in got] == [10, 12]
    assert 1 <= decoder.dropped <= 2  # two if the flip made a 0x00 (the frame is split in two)
    assert decoder.missed == 1


@given(st.integers(1, 66), st.booleans())
def test_a_truncated_frame_is_counted_and_dropped(keep, lost_in_the_middle):
    frame = encode(Measurement(11, 0.11, np.linspace(-1, 1, 11)), 11)
    # a frame cut short (the delimiter still comes), or one with a byte lost on the way
    broken = frame[:keep] + b"\x00" if not lost_in_the_middle else frame[:keep] + frame[keep + 1:]
    got, decoder = three_frames(broken)
    assert [p.seq for p in got] == [10, 12]
    assert decoder.dropped == 1 and decoder.frames == 2


@given(st.binary(min_size=1, max_size=700))
def test_garbage_between_frames_is_counted_and_dropped(garbage):
    # noise ended by a delimiter; without one it would run into the next frame and cost it (docs/robot_link.md)
    got, decoder = three_frames(garbage + b"\x00")
    assert [p.seq for p in got] == [10, 12]
    assert decoder.dropped == sum(1 for piece in garbage.split(b"\x00") if piece)


@given(st.binary(max_size=2000), st.integers(1, 64))
def test_the_decoder_never_raises(data, size):
    decoder = Decoder()
    for i in range(0, len(data), size):
        decoder.feed(data[i:i + size])
    assert decoder.frames + decoder.dropped <= data.count(0) + 1


def test_lost_late_and_duplicated_frames_are_told_by_their_sequence_numbers():
    order = [0, 1, 3, 2, 2, 6, 4, 9, 1, 8, 8]  # 5 and 7 lost; 2, 4 and 8 late; 2, 1 and 8 again
    decoder = Decoder()
    got = decoder.feed(b"".join(encode(Heartbeat(s, 0), s) for s in order))
    assert [p.seq for p in got] == order  # every frame that decodes is returned
    # ahead: 1->3 skips 1, 3->6 skips 2, 6->9 skips 2
    assert (decoder.missed, decoder.late, decoder.duplicates) == (5, 3, 3)
    assert decoder.lost == 2
    wrapped = Decoder()
    wrapped.feed(b"".join(encode(Heartbeat(0, 0), s % 65536) for s in range(65530, 65545)))
    assert (wrapped.missed, wrapped.late, wrapped.duplicates) == (0, 0, 0)  # through the wrap


def test_bad_headers_are_counted_by_reason():
    def frame(version=P.VERSION, kind=1, length=5, payload=b"\x01\x00\x00\x00\x02", crc=None):
        body = P._HEADER.pack(version, kind, 0, length) + payload
        return P.cobs_encode(body + P._CRC.pack(P.crc32(body) if crc is None else crc)) + b"\x00"

    decoder = Decoder()
    stream = (frame(version=2) + frame(kind=9) + frame(length=4) + frame(crc=1) + frame(payload=b"\x01" * 4, length=4)
              + frame(kind=4, payload=b"\0\0\x05\0\x05\0", length=6) + b"\xff" * 300 + b"\x00" + b"\x03\x00" + frame())
    got = decoder.feed(stream)
    assert [p.message for p in got] == [Heartbeat(1, 2)]
    assert decoder.errors == {"version": 1, "type": 1, "length": 1, "crc": 1, "payload": 2, "overflow": 1, "cobs": 1}


def test_out_of_range_fields_are_refused():
    with pytest.raises(ValueError, match="u8"):
        Heartbeat(0, 256)
    with pytest.raises(ValueError, match="full state"):
        Measurement(0, 0.0, [0.0] * 10)
    with pytest.raises(ValueError, match="u16"):
        encode(Mode(1, 2), 65536)
    with pytest.raises(ValueError, match="index"):
        PlanChunk(0, 3, 3, b"")


@given(st.binary(max_size=3000), st.integers(1, P.MAX_CHUNK), u16, st.randoms(use_true_random=False))
def test_plans_are_rebuilt_from_chunks_in_any_order(plan, max_chunk, plan_id, rng):
    chunks = split_plan(plan, plan_id, max_chunk)
    assert len(chunks) == max(1, -(-len(plan) // max_chunk)) and all(len(c.data) <= max_chunk for c in chunks)
    shuffled = chunks + rng.sample(chunks, k=min(3, len(chunks)))  # with duplicates
    rng.shuffle(shuffled)
    assembler = PlanAssembler()
    rebuilt = [out for c in shuffled if (out := assembler.add(c)) is not None]
    assert rebuilt == [plan]
    assert assembler.duplicates == len(shuffled) - len(chunks) and assembler.pending() == {}


def test_plans_interleave_through_the_link():
    plans = {1: bytes(range(256)) * 5, 2: b"second plan"}
    stream = b"".join(encode(c, i) for i, c in enumerate(
        c for pair in zip(split_plan(plans[1], 1), split_plan(plans[2], 2, max_chunk=4)) for c in pair))
    assembler, done = PlanAssembler(), {}
    for packet in Decoder().feed(stream):
        if (plan := assembler.add(packet.message)) is not None:
            done[packet.message.plan_id] = plan
    assert done == {2: plans[2]} and assembler.pending() == {1: (3, 7)}
    with pytest.raises(ValueError, match="max_chunk"):
        split_plan(b"x", 0, max_chunk=P.MAX_CHUNK + 1)


# --- the C codec, through ctypes ---------------------------------------------------------------------------

class CHeartbeat(ctypes.Structure):
    _fields_ = [("time_ms", ctypes.c_uint32), ("mode", ctypes.c_uint8)]


class CMeasurement(ctypes.Structure):
    _fields_ = [("period", ctypes.c_uint32), ("time", ctypes.c_double), ("state", ctypes.c_double * 11)]


class CCommand(ctypes.Structure):
    _fields_ = [("period", ctypes.c_uint32), ("acceleration", ctypes.c_double), ("status", ctypes.c_uint8)]


class CPlanChunk(ctypes.Structure):
    _fields_ = [("plan_id", ctypes.c_uint16), ("index", ctypes.c_uint16), ("count", ctypes.c_uint16),
                ("length", ctypes.c_uint16), ("data", ctypes.c_uint8 * P.MAX_CHUNK)]


class CMode(ctypes.Structure):
    _fields_ = [("mode", ctypes.c_uint8), ("tick", ctypes.c_uint32), ("reason", ctypes.c_uint8)]


class CBody(ctypes.Union):
    _fields_ = [("heartbeat", CHeartbeat), ("measurement", CMeasurement), ("command", CCommand),
                ("plan_chunk", CPlanChunk), ("mode", CMode)]


class CMessage(ctypes.Structure):
    _fields_ = [("type", ctypes.c_uint8), ("seq", ctypes.c_uint16), ("body", CBody)]


REASONS = ("cobs", "crc", "length", "version", "type", "payload", "overflow")


class CDecoder(ctypes.Structure):
    _fields_ = [("buf", ctypes.c_uint8 * P.MAX_ENCODED), ("len", ctypes.c_uint16), ("discarding", ctypes.c_uint8),
                ("have_seq", ctypes.c_uint8), ("last_seq", ctypes.c_uint16), ("frames", ctypes.c_uint32),
                ("missed", ctypes.c_uint32), ("late", ctypes.c_uint32), ("duplicates", ctypes.c_uint32),
                ("seen", ctypes.c_uint32)] + [(f"err_{r}", ctypes.c_uint32) for r in REASONS]


SIZES = """#include "rollbot_link.h"
size_t rl_sizeof_message(void) { return sizeof(rl_message_t); }
size_t rl_sizeof_decoder(void) { return sizeof(rl_decoder_t); }
"""


@pytest.fixture(scope="module")
def clib(tmp_path_factory):
    cc = compiler()
    if cc is None:
        pytest.skip("no C compiler ($CC, gcc, clang, cc): the C codec cannot be built here")
    folder = tmp_path_factory.mktemp("rollbot_link")
    (folder / "sizes.c").write_text(SIZES)
    library = folder / "librollbot_link.so"
    built = subprocess.run([cc, "-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Wconversion", "-Werror", "-O2",
                            "-shared", "-fPIC", "-I", str(C_DIR), str(C_DIR / "rollbot_link.c"),
                            str(folder / "sizes.c"), "-o", str(library)], capture_output=True, text=True)
    assert built.returncode == 0, built.stderr
    lib = ctypes.CDLL(str(library))
    lib.rl_encode.restype = ctypes.c_int32
    lib.rl_encode.argtypes = [ctypes.POINTER(CMessage), ctypes.c_char_p, ctypes.c_size_t]
    lib.rl_decode_frame.restype = ctypes.c_int32
    lib.rl_decode_frame.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.POINTER(CMessage)]
    lib.rl_crc32.restype = ctypes.c_uint32
    lib.rl_crc32.argtypes = [ctypes.c_char_p, ctypes.c_size_t]
    for name in ("rl_cobs_encode", "rl_cobs_decode"):
        getattr(lib, name).restype = ctypes.c_int32
        getattr(lib, name).argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_char_p, ctypes.c_size_t]
    lib.rl_decoder_push.argtypes = [ctypes.POINTER(CDecoder), ctypes.c_uint8, ctypes.POINTER(CMessage)]
    lib.rl_decoder_dropped.restype = ctypes.c_uint32
    lib.rl_decoder_dropped.argtypes = [ctypes.POINTER(CDecoder)]
    for name in ("rl_sizeof_message", "rl_sizeof_decoder"):
        getattr(lib, name).restype = ctypes.c_size_t
    assert lib.rl_sizeof_message() == ctypes.sizeof(CMessage)  # the ctypes mirror has the C layout
    assert lib.rl_sizeof_decoder() == ctypes.sizeof(CDecoder)
    return lib


def to_c(message, seq) -> CMessage:
    c = CMessage(type=int(message.TYPE), seq=seq)
    if isinstance(message, Heartbeat):
        c.body.heartbeat = CHeartbeat(message.time_ms, message.mode)
    elif isinstance(message, Measurement):
        c.body.measurement = CMeasurement(message.period, message.time, (ctypes.c_double * 11)(*message.state))
    elif isinstance(message, Command):
        c.body.command = CCommand(message.period, message.acceleration, message.status)
    elif isinstance(message, PlanChunk):
        chunk = c.body.plan_chunk
        chunk.plan_id, chunk.index, chunk.count, chunk.length = (message.plan_id, message.index, message.count,
                                                                 len(message.data))
        ctypes.memmove(chunk.data, message.data, len(message.data))
    else:
        c.body.mode = CMode(message.mode, message.tick, message.reason)
    return c


def from_c(c: CMessage):
    body = c.body
    if c.type == P.MessageType.HEARTBEAT:
        return Heartbeat(body.heartbeat.time_ms, body.heartbeat.mode)
    if c.type == P.MessageType.MEASUREMENT:
        return Measurement(body.measurement.period, body.measurement.time, list(body.measurement.state))
    if c.type == P.MessageType.COMMAND:
        return Command(body.command.period, body.command.acceleration, body.command.status)
    if c.type == P.MessageType.PLAN_CHUNK:
        chunk = body.plan_chunk
        return PlanChunk(chunk.plan_id, chunk.index, chunk.count, bytes(chunk.data[:chunk.length]))
    return Mode(body.mode.mode, body.mode.tick, body.mode.reason)


def c_encode(lib, message, seq) -> bytes:
    out = ctypes.create_string_buffer(P.MAX_ENCODED + 1)
    n = lib.rl_encode(ctypes.byref(to_c(message, seq)), out, len(out))
    assert n > 0
    return out.raw[:n]


@given(messages, u16)
def test_c_and_python_encode_alike_and_decode_each_other(clib, message, seq):
    frame = encode(message, seq)
    assert c_encode(clib, message, seq) == frame  # byte for byte
    decoded = CMessage()
    assert clib.rl_decode_frame(frame[:-1], len(frame) - 1, ctypes.byref(decoded)) == 0  # C decodes Python's
    assert decoded.seq == seq and same(from_c(decoded), message)
    packet = decode_frame(c_encode(clib, message, seq)[:-1])  # Python decodes C's
    assert packet.seq == seq and same(packet.message, message)


@given(st.binary(max_size=600))
def test_c_cobs_and_crc_match(clib, data):
    out = ctypes.create_string_buffer(len(data) + len(data) // 254 + 1)
    n = clib.rl_cobs_encode(data, len(data), out, len(out))
    assert out.raw[:n] == P.cobs_encode(data)
    back = ctypes.create_string_buffer(max(1, len(data)))
    m = clib.rl_cobs_decode(out.raw[:n], n, back, len(back))
    assert back.raw[:m] == data
    assert clib.rl_crc32(data, len(data)) == P.crc32(data)
    assert clib.rl_cobs_encode(data, len(data), out, n - 1) == -8  # RL_ERR_BUFFER: never past the buffer


@given(st.lists(st.one_of(st.tuples(messages, u16), st.binary(max_size=300)), max_size=10))
def test_c_stream_decoder_counts_as_python(clib, parts):
    """A stream of frames and garbage: the C decoder decodes the same frames and counts the same drops."""
    stream = b"".join(encode(*p) if isinstance(p, tuple) else p for p in parts)
    python = Decoder()
    expected = python.feed(stream)
    dec, msg, got = CDecoder(), CMessage(), []
    for byte in stream:
        if clib.rl_decoder_push(ctypes.byref(dec), byte, ctypes.byref(msg)) == 1:
            got.append((msg.seq, from_c(msg)))
    assert [s for s, _ in got] == [p.seq for p in expected]
    assert all(same(m, p.message) for (_, m), p in zip(got, expected))
    assert {r: getattr(dec, f"err_{r}") for r in REASONS} == python.errors
    assert (dec.frames, dec.missed, dec.late, dec.duplicates, clib.rl_decoder_dropped(ctypes.byref(dec))) == (
        python.frames, python.missed, python.late, python.duplicates, python.dropped)


# --- transports ----------------------------------------------------------------------------------------------

def receive_packets(link, decoder, count, timeout=5.0) -> list:
    got, end = [], time.monotonic() + timeout
    while len(got) < count and time.monotonic() < end:
        got += decoder.feed(link.receive(0.05))
    return got


def test_udp_loopback_round_trip():
    with open_link("udp://127.0.0.1:0", role="bind") as robot:
        port = robot.local_address[1]
        with open_link(f"udp://:{port}") as host:
            robot.send(encode(Heartbeat(0, 0), 0))  # no peer yet: dropped, counted
            assert robot.counters.bytes_dropped == 17 and robot.counters.frames_sent == 0
            host.send(encode(Command(1, 2.5, 0), 0) + encode(Mode(3, 1, 4), 1))
            got = receive_packets(robot, Decoder(), 2)
            assert [p.message for p in got] == [Command(1, 2.5, 0), Mode(3, 1, 4)]
            state = np.arange(11.0)
            robot.send(encode(Measurement(2, 0.02, state), 0))
            (back,) = receive_packets(host, Decoder(), 1)
            assert back.message == Measurement(2, 0.02, state)
            assert (host.counters.frames_sent, host.counters.bytes_sent) == (2, 25 + 18)
            assert (robot.counters.frames_received, robot.counters.bytes_received) == (2, 25 + 18)
            assert (host.counters.frames_received, host.counters.bytes_received) == (1, 68)


def test_serial_over_a_pseudo_terminal():
    pytest.importorskip("serial", reason="pyserial is not installed (pip install 'rollbot_oc[robot]')")
    import tty

    robot_fd, host_fd = os.openpty()
    tty.setraw(robot_fd)
    try:
        with open_link(f"serial://{os.ttyname(host_fd)}?baud=115200") as host:
            assert host._port.baudrate == 115200
            plan = bytes(range(256)) * 4
            frames = b"".join(encode(c, i) for i, c in enumerate(split_plan(plan, 9)))
            host.send(frames)
            received = b""
            while len(received) < len(frames):
                received += os.read(robot_fd, 4096)
            assembler = PlanAssembler()
            assert [assembler.add(p.message) for p in Decoder().feed(received)][-1] == plan
            os.write(robot_fd, encode(Measurement(5, 0.05, np.ones(11)), 5) + b"\x00\x01\x02\x00")
            decoder = Decoder()
            (packet,) = receive_packets(host, decoder, 1)
            assert packet.message == Measurement(5, 0.05, np.ones(11))
            assert host.counters.frames_sent == 6 and host.counters.bytes_sent == len(frames)
            assert host.counters.bytes_received >= 68
    finally:
        os.close(robot_fd)
        os.close(host_fd)


@pytest.mark.parametrize("url, words", [
    ("tcp://127.0.0.1:9000", "unknown scheme 'tcp'"),
    ("127.0.0.1:9000", "no scheme"),
    ("udp://127.0.0.1", "no port"),
    ("udp://127.0.0.1:99999", "port 99999 is out of range"),
    ("udp://127.0.0.1:abc", "port 'abc' is not a number"),
    ("udp://127.0.0.1:9000?rate=3", "unknown option"),
    ("serial:///dev/ttyUSB0?baud=fast", "baud 'fast' is not a whole number"),
    ("serial:///dev/ttyUSB0?baud=12", "baud 12 is out of range"),
    ("serial://dev/ttyUSB0", "has no host"),
    ("serial:///dev/ttyUSB0?parity=E", "unknown option"),
    ("", "not a URL"),
])
def test_a_bad_url_is_one_line(url, words):
    with pytest.raises(ConfigError) as info:
        parse_link(url)
    message = str(info.value)
    assert words in message and "\n" not in message and info.value.__cause__ is None
    assert info.value.__suppress_context__ or info.value.__context__ is None


def test_good_urls():
    assert parse_link("udp://:9750") == LinkSpec("udp", "udp://:9750", host="127.0.0.1", port=9750)
    spec = parse_link("serial:///dev/ttyACM0")
    assert (spec.device, spec.baud) == ("/dev/ttyACM0", 115200)
    assert parse_link("serial:///dev/ttyS1?baud=921600").baud == 921600


def test_the_monitor_reports_a_bad_url_in_one_line_without_traceback():
    done = subprocess.run([sys.executable, "-m", "rollbot_oc.robot", "udp://localhost:70000"], capture_output=True,
                          text=True, timeout=60, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr and "70000" in done.stderr
    missing = subprocess.run([sys.executable, "-m", "rollbot_oc.robot", "serial:///dev/no-such-tty", "--seconds", "0"],
                             capture_output=True, text=True, timeout=60, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert missing.returncode == 2 and missing.stderr.count("\n") == 1 and "Traceback" not in missing.stderr


# --- traffic --------------------------------------------------------------------------------------------------

def test_the_100_hz_traffic_fits_115200_baud():
    """Per period one MEASUREMENT up and one COMMAND down, a HEARTBEAT each way at 10 Hz: framed bytes per second
    against 11520 B/s each way (115200 baud, 8N1: 10 bits a byte); benchmarks/bench_link.py prints the table."""
    measurement, command = encode(Measurement(0, 0.0, [0.0] * 11), 0), encode(Command(0, 0.0), 0)
    heartbeat = encode(Heartbeat(0, 0), 0)
    up, down = 100 * len(measurement) + 10 * len(heartbeat), 100 * len(command) + 10 * len(heartbeat)
    assert (up, down) == (100 * 68 + 10 * 17, 100 * 25 + 10 * 17) == (6970, 2670)
    assert up / (115200 / 10) < 0.61  # the state in single precision: 60.5 % of the line, room for MODE and plans
