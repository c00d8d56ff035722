"""The robot link's base: a parsed link URL (``LinkSpec``), its counters (``LinkCounters``) and the byte link every
transport is (``Transport``); ``transport`` has the UDP and serial transports, ``faults`` the fault-injecting one."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["LinkSpec", "LinkCounters", "Transport"]


@dataclass(frozen=True)
class LinkSpec:
    """A parsed link URL.

    Parameters
    ----------
    scheme : str
        ``"udp"`` or ``"serial"``.
    url : str
        The URL as given.
    host : str
        UDP host (``"127.0.0.1"`` by default); empty for serial.
    port : int
        UDP port (0 to 65535; 0: any free port, for binding); 0 for serial.
    device : str
        Serial device path (for example ``/dev/ttyUSB0``); empty for UDP.
    baud : int
        Serial baud rate, baud; 0 for UDP.
    """

    scheme: str
    url: str
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = 0
    faults: object = None  # a faults.FaultSpec from the URL's fault options, or None


@dataclass
class LinkCounters:
    """What a transport has moved: frames (0x00 delimiters) and bytes, each way."""

    frames_sent: int = 0
    bytes_sent: int = 0
    frames_received: int = 0
    bytes_received: int = 0
    bytes_dropped: int = 0  # sent before a bound UDP endpoint knew its peer, or from strangers

    def _sent(self, data: bytes) -> None:
        self.frames_sent += data.count(0)
        self.bytes_sent += len(data)

    def _received(self, data: bytes) -> None:
        self.frames_received += data.count(0)
        self.bytes_received += len(data)


class Transport:
    """A byte link: ``send``, ``receive``, ``close``; a context manager.

    Attributes
    ----------
    spec : LinkSpec
        The link's URL, parsed.
    counters : LinkCounters
        Frames and bytes each way.
    """

    def __init__(self, spec: LinkSpec):
        self.spec = spec
        self.counters = LinkCounters()

    def send(self, data: bytes) -> None:
        """Send bytes (one or more whole frames, as ``protocol.encode`` makes them)."""
        raise NotImplementedError

    def receive(self, timeout: float = 0.0) -> bytes:
        """The bytes that arrived, waiting up to ``timeout`` s for the first; ``b""`` if none did."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the socket or port (again: no effect)."""
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
