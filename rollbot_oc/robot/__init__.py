"""The link between a host (planner, supervisor) and the robot or its emulator.

Two concepts, one module each,: the wire protocol (``protocol``: versioned, CRC-checked messages in COBS
frames, with a streaming decoder and the chunking of plans) and the byte transports named by URLs
(``transport``: ``udp://HOST:PORT``, ``serial:///dev/ttyX?baud=115200``); ``faults`` wraps a transport in
a link that loses, corrupts, duplicates, delays and reorders frames on purpose (seeded) and gives the link's
statistics.  The robot's side of the protocol is in C (``c/rollbot_link.h``, ``c/rollbot_link.c``: C99, no heap).  ``docs/robot_link.md``
gives the frame layout and the link's traffic against a 115200-baud UART.
"""

from rollbot_oc.robot.protocol import (
    Command, Decoder, Heartbeat, Measurement, MessageType, Mode, Packet, PlanAssembler, PlanChunk, encode,
    split_plan,
)
from rollbot_oc.robot.transport import LinkCounters, LinkSpec, Transport, open_link, parse_link
from rollbot_oc.robot.faults import FaultSpec, FaultyLink, LinkStats

__all__ = [
    "MessageType", "Heartbeat", "Measurement", "Command", "PlanChunk", "Mode", "Packet", "encode", "Decoder",
    "split_plan", "PlanAssembler", "LinkSpec", "LinkCounters", "Transport", "parse_link", "open_link",
    "FaultSpec", "FaultyLink", "LinkStats",
]
