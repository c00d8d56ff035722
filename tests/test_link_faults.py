"""The fault-injecting link: each fault, seeded, over loopback UDP, told by the receiving decoder from the
protocol's sequence numbers as the injector counted it; corrupted frames dropped; a disconnect window and the
link's recovery after it; bad fault options in one line."""

import time
from urllib.parse import parse_qs

import pytest

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.robot.faults import FaultSpec, FaultyLink, LinkStats, parse_faults
from rollbot_oc.robot.protocol import Command, Decoder, encode
from rollbot_oc.robot.transport import LinkSpec, Transport, open_link, parse_link

FRAMES = 400


class Memory(Transport):
    """A transport that keeps what it is sent (and has nothing to receive but what a test puts there)."""

    def __init__(self):
        super().__init__(LinkSpec("udp", "memory"))
        self.sent, self.inbox = [], b""

    def send(self, data):
        self.sent.append(bytes(data))
        self.counters._sent(bytes(data))

    def receive(self, timeout=0.0):
        data, self.inbox = self.inbox, b""
        self.counters._received(data)
        return data

    def close(self):
        pass


def frame(seq: int) -> bytes:
    return encode(Command(seq, 0.5 * seq, 0), seq)


def run_faulted(options: str, frames: int = FRAMES, gap: float = 0.0):
    """Send ``frames`` frames through a faulty link (``options``: its URL query) over an in-memory transport (no
    datagram a busy kernel may drop: the counts are exact), then one more around the faults (so that losses at
    the end show); the receiver's decoder and the injector."""
    inner = Memory()
    host = FaultyLink(inner, parse_faults(parse_qs(options), "test"))
    decoder, received, taken = Decoder(), [], 0

    def drain():
        nonlocal taken
        out = []
        while taken < len(inner.sent):  # the delivery thread appends as it sends
            out += decoder.feed(inner.sent[taken])
            taken += 1
        return out

    try:
        for seq in range(frames):
            host.send(frame(seq))
            if gap:
                time.sleep(gap)
            received += drain()
        end = time.monotonic() + 10.0
        while host.pending and time.monotonic() < end:
            time.sleep(0.02)
            received += drain()
        time.sleep(0.02)
        received += drain()
        inner.send(frame(frames))  # the fence: around the faults
        received += drain()
    finally:
        host.close()
    return decoder, host.injected, received


def test_faults_over_loopback_udp_never_raise():
    """The same faults on a real UDP link: frames arrive, decode, and none is corrupted by the transport."""
    with open_link("udp://127.0.0.1:0", role="bind") as robot:
        with open_link(f"udp://127.0.0.1:{robot.local_address[1]}?reorder=0.1&dup=0.05&seed=4") as host:
            decoder, received = Decoder(), []
            for seq in range(50):
                host.send(frame(seq))
                received += decoder.feed(robot.receive(0.0))
            end = time.monotonic() + 5.0
            while host.pending and time.monotonic() < end:
                received += decoder.feed(robot.receive(0.02))
            received += decoder.feed(robot.receive(0.2))
    assert received and decoder.dropped == 0 and {p.seq for p in received} <= set(range(50))


def test_lost_frames_are_counted_by_the_receiver():
    decoder, injected, received = run_faulted("loss=0.1&seed=1")
    assert 20 <= injected.lost <= 60 and injected.frames == FRAMES
    assert decoder.lost == decoder.missed == injected.lost and decoder.late == decoder.duplicates == 0
    assert len(received) == FRAMES - injected.lost + 1 and decoder.dropped == 0


def test_a_corrupted_frame_is_counted_and_dropped():
    decoder, injected, received = run_faulted("corrupt=0.05&seed=2")
    assert injected.corrupted >= 10
    assert decoder.dropped == injected.corrupted  # the CRC (or COBS, or the length) caught every one
    assert decoder.errors["crc"] >= injected.corrupted // 2
    assert decoder.lost == injected.corrupted and len(received) == FRAMES - injected.corrupted + 1
    assert all(p.message == Command(p.seq, 0.5 * p.seq, 0) for p in received)  # nothing corrupted got through


def test_duplicated_frames_are_counted_by_the_receiver():
    decoder, injected, received = run_faulted("dup=0.1&seed=3")
    assert injected.duplicated >= 20
    assert decoder.duplicates == injected.duplicated and decoder.lost == decoder.late == 0
    assert len(received) == FRAMES + injected.duplicated + 1


def test_reordered_frames_are_counted_late_by_the_receiver():
    decoder, injected, received = run_faulted("reorder=0.1&seed=4")
    assert injected.reordered >= 20
    assert decoder.late == injected.reordered and decoder.lost == decoder.duplicates == 0
    assert sorted(p.seq for p in received) == list(range(FRAMES + 1))


def test_jitter_delays_frames_without_blocking_the_sender():
    decoder, injected, received = run_faulted("jitter=0.02&seed=5", frames=200, gap=0.002)
    assert injected.delayed == 200 and injected.reordered > 0  # 2 ms apart, up to 20 ms late: some overtaken
    assert decoder.late == injected.reordered and decoder.lost == 0
    assert sorted(p.seq for p in received) == list(range(201))
    with open_link("udp://127.0.0.1:0", role="bind") as robot:
        with open_link(f"udp://127.0.0.1:{robot.local_address[1]}?jitter=5&seed=5") as host:
            host.send(frame(0))
            assert host.pending == 1 and robot.receive(0.0) == b""  # send returned; the frame waits its turn


def test_every_fault_at_once_never_raises_and_is_accounted_for():
    decoder, injected, received = run_faulted("loss=0.05&corrupt=0.02&dup=0.02&reorder=0.02&jitter=0.01&seed=6",
                                               gap=0.001)
    assert decoder.dropped == injected.corrupted
    assert decoder.duplicates == injected.duplicated
    assert decoder.lost == injected.lost + injected.corrupted
    stats = LinkStats(lost=decoder.lost, late=decoder.late).to_dict()
    assert set(stats) >= {"frames_sent", "bytes_sent", "frames_received", "bytes_received", "lost", "late",
                          "duplicated", "corrupted"}


def test_the_same_seed_gives_the_same_faults():
    def faulted(seed):
        memory = Memory()
        link = FaultyLink(memory, FaultSpec(loss=0.1, corrupt=0.1, dup=0.1, seed=seed))
        for seq in range(300):
            link.send(frame(seq))
        return b"".join(memory.sent), link.injected

    assert faulted(7) == faulted(7)
    assert faulted(7)[0] != faulted(8)[0]


def test_a_disconnect_window_cuts_both_ways_then_the_link_recovers():
    now = [0.0]
    memory = Memory()
    link = FaultyLink(memory, parse_link("udp://:9000?disconnect=0.5@1.0").faults, clock=lambda: now[0])
    decoder = Decoder()
    got = []
    for k in range(200):  # 100 Hz for 2 s: cut from 1.0 s to 1.5 s
        now[0] = 0.01 * k
        link.send(frame(k))
        memory.inbox = frame(k)
        got += decoder.feed(link.receive())
    sent = Decoder().feed(b"".join(memory.sent))
    assert [p.seq for p in sent] == [k for k in range(200) if not 100 <= k < 150]
    assert [p.seq for p in got] == [p.seq for p in sent] and link.injected.disconnected == 50
    assert link.injected.bytes_cut == 50 * len(frame(0)) and decoder.lost == 50  # and after it, all again


@pytest.mark.parametrize("query, words", [
    ("loss=1.5", "option loss = '1.5' is out of range [0, 1]"),
    ("jitter=-0.1", "option jitter = '-0.1' is out of range [0, 10]"),
    ("jitter=fast", "option jitter = 'fast' is not a number in [0, 10]"),
    ("dup=nan", "option dup = 'nan' is out of range [0, 1]"),
    ("disconnect=2.0", "write disconnect=D@S"),
    ("disconnect=0@5", "option disconnect = '0' is out of range (0, 3600]"),
    ("disconnect=2@-1", "option disconnect start = '-1' is out of range [0, 86400]"),
    ("seed=x", "option seed = 'x' is not a whole number"),
    ("loss=0.1&loss=0.2", "option loss is given 2 times"),
])
def test_a_bad_fault_option_is_one_line(query, words):
    with pytest.raises(ConfigError) as info:
        parse_link(f"udp://127.0.0.1:9000?{query}")
    assert words in str(info.value) and "\n" not in str(info.value) and "udp://127.0.0.1:9000" in str(info.value)
    with pytest.raises(ConfigError, match="option reorder = 2"):
        FaultSpec(reorder=2)
