"""The robot link's traffic against a UART, and the Python codec's time per frame.

1. Framed bytes per second (after COBS and the delimiter) of the N-shape's closed loop at 100 Hz: one
   MEASUREMENT up (robot -> host) and one COMMAND down per period, a HEARTBEAT each way at 10 Hz; against
   115200 baud (11520 B/s each way with 8N1: 10 bits a byte) and faster rates.  The figures follow from
   the frame sizes; they do not depend on the course (only the plans do, and they go once).
2. The time to send a plan of a few sizes in 200-byte chunks on what the downlink leaves free.
3. The Python encoder's and streaming decoder's time per MEASUREMENT frame (median of repeats).

Run: .venv/bin/python benchmarks/bench_link.py [--rate 100] [--heartbeat 10]
"""

import argparse
import statistics
import time

import numpy as np

from rollbot_oc.robot.protocol import Command, Decoder, Heartbeat, Measurement, encode, split_plan

BAUDS = (115200, 230400, 460800, 921600)
BITS_PER_BYTE = 10  # 8N1: start bit, 8 data bits, stop bit


def traffic(rate: float = 100.0, heartbeat: float = 10.0) -> dict:
    """Framed bytes per second each way: ``{"up": B/s, "down": B/s, "frames": {name: bytes}}``."""
    frames = {"MEASUREMENT": len(encode(Measurement(0, 0.0, [0.0] * 11), 0)),
              "COMMAND": len(encode(Command(0, 0.0), 0)),
              "HEARTBEAT": len(encode(Heartbeat(0, 0), 0))}
    return {"up": rate * frames["MEASUREMENT"] + heartbeat * frames["HEARTBEAT"],
            "down": rate * frames["COMMAND"] + heartbeat * frames["HEARTBEAT"], "frames": frames}


def _median_time(fn, repeats: int = 7, number: int = 2000) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(number):
            fn()
        times.append((time.perf_counter() - start) / number)
    return statistics.median(times)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=100.0, help="control rate, Hz (default 100)")
    parser.add_argument("--heartbeat", type=float, default=10.0, help="heartbeat rate each way, Hz (default 10)")
    args = parser.parse_args()

    t = traffic(args.rate, args.heartbeat)
    print("frame sizes on the wire (bytes): " + ", ".join(f"{k} {v}" for k, v in t["frames"].items()))
    print(f"\ntraffic at {args.rate:g} Hz with heartbeats at {args.heartbeat:g} Hz each way")
    print(f"{'baud':>8} {'capacity B/s':>13} {'up B/s':>8} {'up use':>7} {'down B/s':>9} {'down use':>9}")
    for baud in BAUDS:
        capacity = baud / BITS_PER_BYTE
        print(f"{baud:>8} {capacity:>13.0f} {t['up']:>8.0f} {t['up'] / capacity:>7.1%} {t['down']:>9.0f} "
              f"{t['down'] / capacity:>9.1%}")

    spare = BAUDS[0] / BITS_PER_BYTE - t["down"]
    print(f"\nplans sent down at {BAUDS[0]} baud on the {spare:.0f} B/s the downlink leaves free (200-byte chunks)")
    for size in (1_000, 10_000, 100_000):
        framed = sum(len(encode(c, 0)) for c in split_plan(bytes(size), 0))
        print(f"{size:>8} B plan: {framed} B framed, {framed / spare:6.2f} s")

    state = np.linspace(-1.0, 1.0, 11)
    message = Measurement(123, 1.23, state)
    frame = encode(message, 7)
    stream = frame * 100
    encode_s = _median_time(lambda: encode(message, 7))
    decode_s = _median_time(lambda: Decoder().feed(stream), number=20) / 100
    print(f"\nPython codec, MEASUREMENT frame: encode {encode_s * 1e6:.1f} us, "
          f"decode (streaming) {decode_s * 1e6:.1f} us")


if __name__ == "__main__":
    main()
