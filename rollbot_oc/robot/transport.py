"""Byte transports of the robot link, named by URLs: UDP datagrams or a serial port.

A transport moves bytes, not messages: ``send(data)`` writes them, ``receive(timeout)`` returns what
arrived (``b""`` if nothing did), and the protocol (``rollbot_oc.robot.protocol``) frames and decodes.
Each transport counts frames (0x00 delimiters) and bytes each way in ``counters``.

URLs
----
``udp://HOST:PORT``
    UDP on HOST (``127.0.0.1`` when left out: ``udp://:9750``).  A link is a pair of endpoints: the
    robot or its emulator *binds* HOST:PORT (``open_link(url, role="bind")``; port 0 takes a free
    port, see ``local_address``) and answers whoever sent to it last; the host *connects*
    (``role="connect"``, the default), sending to HOST:PORT and accepting datagrams from it only.
``serial:///dev/ttyX?baud=115200``
    A serial port (8N1) through pyserial (``pip install 'rollbot_oc[robot]'``); ``baud`` from 300 to
    4000000 baud, 115200 when left out.  The role does not apply.

Either URL takes fault options (``?loss=0.05&jitter=0.02&seed=3``, ``rollbot_oc.robot.faults``): the
transport is then wrapped in a ``FaultyLink`` that loses, corrupts, duplicates, delays and reorders the frames
it sends and cuts the link for a window of time.

``parse_link`` checks a URL and raises one one-line ``ConfigError`` for a bad one.
"""

from __future__ import annotations

import select
import socket
import time
from urllib.parse import parse_qs, urlsplit

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.robot.faults import FAULT_OPTIONS, FaultyLink, parse_faults
from rollbot_oc.robot.link import LinkCounters, LinkSpec, Transport

__all__ = ["LinkSpec", "LinkCounters", "Transport", "UdpTransport", "SerialTransport", "parse_link", "open_link",
           "ROLES", "BAUD_RANGE", "DEFAULT_BAUD", "DEFAULT_HOST"]

DEFAULT_HOST = "127.0.0.1"
DEFAULT_BAUD = 115200
BAUD_RANGE = (300, 4_000_000)  # baud
ROLES = ("connect", "bind")
_MAX_DATAGRAM = 65535


def _bad(url: str, why: str) -> ConfigError:
    return ConfigError(f"link URL {url!r}: {why}; valid are udp://HOST:PORT and serial:///dev/ttyX?baud=115200")


def parse_link(url: str) -> LinkSpec:
    """The link a URL names; ``ConfigError`` (one line) for a bad URL, scheme, host, port, device or baud.

    Parameters
    ----------
    url : str
        ``udp://HOST:PORT`` or ``serial:///dev/ttyX?baud=115200`` (module docstring).

    Returns
    -------
    LinkSpec
    """
    if not isinstance(url, str) or not url or any(c.isspace() for c in url):
        raise _bad(str(url), "not a URL")
    try:
        parts = urlsplit(url)
    except ValueError as err:
        raise _bad(url, str(err)) from None
    scheme = parts.scheme.lower()
    if "://" not in url or scheme not in ("udp", "serial"):
        raise _bad(url, f"unknown scheme {parts.scheme!r}" if parts.scheme else "no scheme")
    try:
        query = parse_qs(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query))
    except ValueError:
        raise _bad(url, f"bad query {parts.query!r}") from None
    if parts.fragment:
        raise _bad(url, f"unexpected fragment {parts.fragment!r}")

    faults = parse_faults(query, f"link URL {url!r}")
    query = {name: values for name, values in query.items() if name not in FAULT_OPTIONS}
    if scheme == "udp":
        if query:
            raise _bad(url, f"unknown option(s) {', '.join(sorted(query))} for udp (valid: the faults' "
                            f"{', '.join(FAULT_OPTIONS)})")
        if parts.path not in ("", "/"):
            raise _bad(url, f"unexpected path {parts.path!r} for udp")
        netloc = parts.netloc
        if "@" in netloc:
            raise _bad(url, "a user name does not apply to udp")
        host, sep, port_text = netloc.rpartition(":")
        if not sep:
            raise _bad(url, "no port")
        host = host.strip("[]") or DEFAULT_HOST
        if not port_text.isdigit():
            raise _bad(url, f"port {port_text!r} is not a number in [0, 65535]")
        port = int(port_text)
        if port > 65535:
            raise _bad(url, f"port {port} is out of range [0, 65535]")
        return LinkSpec("udp", url, host=host, port=port, faults=faults)
    if parts.netloc:
        raise _bad(url, f"a serial URL has no host ({parts.netloc!r}): write serial:///dev/ttyX")
    if not parts.path.startswith("/") or parts.path.endswith("/") or len(parts.path) < 2:
        raise _bad(url, f"device {parts.path!r} is not a path such as /dev/ttyUSB0")
    unknown = sorted(set(query) - {"baud"})
    if unknown:
        raise _bad(url, f"unknown option(s) {', '.join(unknown)} for serial (valid: baud and the faults' "
                        f"{', '.join(FAULT_OPTIONS)})")
    baud_text = query.get("baud", [str(DEFAULT_BAUD)])
    if len(baud_text) != 1 or not baud_text[0].isdigit():
        raise _bad(url, f"baud {'&'.join(baud_text)!r} is not a whole number in [{BAUD_RANGE[0]}, {BAUD_RANGE[1]}]")
    baud = int(baud_text[0])
    if not BAUD_RANGE[0] <= baud <= BAUD_RANGE[1]:
        raise _bad(url, f"baud {baud} is out of range [{BAUD_RANGE[0]}, {BAUD_RANGE[1]}]")
    return LinkSpec("serial", url, device=parts.path, baud=baud, faults=faults)


class UdpTransport(Transport):
    """UDP endpoint: one datagram per ``send``.

    Parameters
    ----------
    spec : LinkSpec
        A ``udp`` link.
    role : {"connect", "bind"}
        ``bind``: listen on HOST:PORT and answer the last sender; ``connect``: send to HOST:PORT (from a
        free local port) and accept datagrams from it only.
    """

    def __init__(self, spec: LinkSpec, role: str = "connect"):
        super().__init__(spec)
        if role not in ROLES:
            raise ConfigError(f"link role {role!r}: valid are {', '.join(ROLES)}")
        self.role = role
        try:
            infos = socket.getaddrinfo(spec.host, spec.port, type=socket.SOCK_DGRAM)
        except socket.gaierror as err:
            raise ConfigError(f"link URL {spec.url!r}: host {spec.host!r} not found ({err.strerror})") from None
        family, _, _, _, address = infos[0]
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            if role == "bind":
                self._sock.bind(address)
                self.peer = None
            else:
                if spec.port == 0:
                    raise ConfigError(f"link URL {spec.url!r}: port 0 can only be bound, not connected to")
                self.peer = address  # the socket takes a free local port at its first send
        except OSError as err:
            self._sock.close()
            raise ConfigError(f"link URL {spec.url!r}: cannot {role} ({err.strerror or err})") from None
        except ConfigError:
            self._sock.close()
            raise
        self._sock.setblocking(False)

    @property
    def local_address(self) -> tuple:
        """The local (host, port) of the socket (the port a bound ``udp://...:0`` took)."""
        return self._sock.getsockname()[:2]

    def send(self, data: bytes) -> None:
        data = bytes(data)
        if not data:
            return
        if self.peer is None:
            self.counters.bytes_dropped += len(data)
            return
        self._sock.sendto(data, self.peer)
        self.counters._sent(data)

    def receive(self, timeout: float = 0.0) -> bytes:
        received = bytearray()
        deadline = time.monotonic() + max(0.0, timeout)
        while True:
            wait = 0.0 if received else max(0.0, deadline - time.monotonic())
            ready, _, _ = select.select([self._sock], [], [], wait)
            if not ready:
                break
            try:
                data, sender = self._sock.recvfrom(_MAX_DATAGRAM)
            except (BlockingIOError, ConnectionRefusedError):
                continue
            if self.role == "bind":
                self.peer = sender
            elif sender[:2] != self.peer[:2]:
                self.counters.bytes_dropped += len(data)
                continue
            received += data
        data = bytes(received)
        self.counters._received(data)
        return data

    def close(self) -> None:
        self._sock.close()


class SerialTransport(Transport):
    """Serial port, 8N1, through pyserial.

    Parameters
    ----------
    spec : LinkSpec
        A ``serial`` link (its device and baud rate).
    """

    def __init__(self, spec: LinkSpec):
        super().__init__(spec)
        try:
            import serial  # optional extra [robot]: only a serial link needs pyserial
        except ImportError:
            raise ConfigError(f"link URL {spec.url!r}: serial links need pyserial "
                              "(pip install 'rollbot_oc[robot]')") from None
        self._serial_error = serial.SerialException
        try:
            self._port = serial.Serial(spec.device, baudrate=spec.baud, bytesize=serial.EIGHTBITS,
                                       parity=serial.PARITY_NONE, stopbits=serial.STOPBITS_ONE, timeout=0,
                                       write_timeout=None)
        except (serial.SerialException, OSError, ValueError) as err:
            raise ConfigError(f"link URL {spec.url!r}: cannot open {spec.device} "
                              f"({str(err).splitlines()[0] if str(err) else type(err).__name__})") from None

    def send(self, data: bytes) -> None:
        data = bytes(data)
        if not data:
            return
        self._port.write(data)
        self.counters._sent(data)

    def receive(self, timeout: float = 0.0) -> bytes:
        port = self._port
        data = b""
        waiting = port.in_waiting
        if waiting:
            data = port.read(waiting)
        elif timeout > 0:
            port.timeout = timeout
            try:
                data = port.read(1)
            finally:
                port.timeout = 0
            if data and port.in_waiting:
                data += port.read(port.in_waiting)
        self.counters._received(data)
        return data

    def close(self) -> None:
        self._port.close()


def open_link(url: str, role: str = "connect") -> Transport:
    """The transport a URL names, open.

    Parameters
    ----------
    url : str
        ``udp://HOST:PORT`` or ``serial:///dev/ttyX?baud=115200``.
    role : {"connect", "bind"}, default "connect"
        For UDP: the host connects, the robot (or its emulator) binds.  Ignored for serial.

    Returns
    -------
    Transport
        ``UdpTransport`` or ``SerialTransport``, in a ``faults.FaultyLink`` if the URL has fault options;
        ``ConfigError`` (one line) if the URL is bad or the link cannot be opened.
    """
    spec = parse_link(url)
    if role not in ROLES:
        raise ConfigError(f"link role {role!r}: valid are {', '.join(ROLES)}")
    link = UdpTransport(spec, role) if spec.scheme == "udp" else SerialTransport(spec)
    if spec.faults is not None:
        return FaultyLink(link, spec.faults)
    return link
