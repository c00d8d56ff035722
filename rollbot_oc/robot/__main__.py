"""Link monitor: ``python -m rollbot_oc.robot URL [--bind] [--seconds S]``.

Opens the link, prints each message it decodes (one line each: sequence number, type, fields) and, at
the end, the transport's and the decoder's counters.  A bad URL is one line on stderr, exit status 2.
"""

from __future__ import annotations

import argparse
import sys
import time

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.robot.protocol import Decoder
from rollbot_oc.robot.transport import open_link

__all__ = ["main"]

PROG = "python -m rollbot_oc.robot"


def main(argv: list[str] | None = None) -> int:
    """Run the monitor with ``argv`` (default ``sys.argv[1:]``); returns the exit status (0, 2 for a bad URL)."""
    parser = argparse.ArgumentParser(prog=PROG, description="Print the messages that arrive on a robot link.")
    parser.add_argument("url", help="udp://HOST:PORT or serial:///dev/ttyX?baud=115200")
    parser.add_argument("--bind", action="store_true", help="UDP: bind HOST:PORT (the robot's end) rather than "
                        "send to it")
    parser.add_argument("--seconds", type=float, default=float("inf"), metavar="S",
                        help="stop after S seconds (default: at Ctrl-C)")
    args = parser.parse_args(argv)
    try:
        link = open_link(args.url, role="bind" if args.bind else "connect")
    except ConfigError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    decoder = Decoder()
    end = time.monotonic() + args.seconds
    try:
        with link:
            while time.monotonic() < end:
                for packet in decoder.feed(link.receive(min(0.1, max(0.0, end - time.monotonic())))):
                    print(f"{packet.seq:5d} {packet.message}", flush=True)
    except KeyboardInterrupt:
        pass
    print(f"{link.counters}; decoded {decoder.frames}, missed {decoder.missed}, dropped {decoder.errors}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
