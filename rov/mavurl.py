"""MAVLink connection strings, checked before pymavlink sees them.

Goal: accept exactly the endpoints the bridge and the simulator mean to use, and
turn anything else into one clear ValueError.  pymavlink's `mavlink_connection`
guesses from the string: an existing file path is opened as a log to replay, and
one under a `bin/` folder is even executed as a child process, which must never
happen because of a typo in `--mavlink`.

Accepted: `udpin:HOST:PORT`, `udpout:HOST:PORT`, `udp:HOST:PORT` (pymavlink's
"listen" spelling), `tcp:HOST:PORT`, `tcpin:HOST:PORT`, and serial devices
`/dev/...` or `COMn`, optionally followed by `,BAUD` (default 115200).

Closed TCP connections: pymavlink's `tcp:` client answers the peer's close (EOF,
reset) by printing "EOF on TCP socket" and returning nothing, again and again, as
fast as the caller asks (a spinning core, 730 000 lines until the heartbeat
timeout).  `open_mavlink` makes such a connection raise `MavlinkClosed` instead,
so that its owner closes it and reopens with its own backoff.  Its `tcpin:`
server likewise spins on a client's EOF; there the client is dropped at once and
the next one accepted.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_NET = re.compile(r"^(udpin|udpout|udp|tcp|tcpin):([^:\s]+):(\d{1,5})$")
_SERIAL = re.compile(r"^(/dev/[^,\s]+|COM\d+)(?:,(\d{3,7}))?$", re.IGNORECASE)

DEFAULT_BAUD = 115200


@dataclass(frozen=True)
class MavlinkUrl:
    kind: str  # udpin, udpout, tcp, tcpin or serial
    device: str  # what pymavlink gets as `device`
    baud: int = DEFAULT_BAUD
    host: str = ""
    port: int = 0


def parse_mavlink_url(url: str) -> MavlinkUrl:
    """Check a connection string; raise ValueError with a one-line reason."""
    if not isinstance(url, str) or not url.strip():
        raise ValueError("empty MAVLink URL")
    url = url.strip()
    match = _NET.match(url)
    if match:
        kind, host, port_text = match.groups()
        port = int(port_text)
        if port > 65535:
            raise ValueError(f"port out of range in MAVLink URL {url!r}")
        if kind == "udp":
            kind = "udpin"
        if kind in ("udpout", "tcp") and port == 0:
            raise ValueError(f"{kind} needs a port to reach, not 0: {url!r}")
        return MavlinkUrl(kind=kind, device=f"{kind}:{host}:{port}", host=host, port=port)
    match = _SERIAL.match(url)
    if match:
        device, baud_text = match.groups()
        return MavlinkUrl(kind="serial", device=device, baud=int(baud_text) if baud_text else DEFAULT_BAUD)
    raise ValueError(
        f"not a MAVLink URL: {url!r} (expected udpin:HOST:PORT, udpout:HOST:PORT, "
        "tcp:HOST:PORT, tcpin:HOST:PORT or a serial device such as /dev/ttyACM0,115200)"
    )


class MavlinkClosed(ConnectionError):
    """The peer closed a TCP MAVLink connection."""


def _raise_closed(why: str):
    def handler() -> None:
        raise MavlinkClosed(why)

    return handler


def _drop_client_on_eof(conn) -> None:
    """A tcpin server: on a client's EOF, close it and wait for the next one."""
    accept = conn.recv

    def recv(n=None):
        port = conn.port
        if port is None:
            return accept(n)
        if n is None:
            n = conn.mav.bytes_needed()
        try:
            data = port.recv(n)
        except BlockingIOError:
            return b""
        except OSError:
            data = b""
        if not data:
            port.close()
            conn.port = None
            conn.fd = conn.listen.fileno()
        return data

    conn.recv = recv


def open_mavlink(url: str | MavlinkUrl, source_system: int, source_component: int):
    """Open a pymavlink connection with the ardupilotmega dialect.  A `tcp:` one raises
    MavlinkClosed (a ConnectionError) from recv and send once the peer has closed."""
    from pymavlink import mavutil

    parsed = url if isinstance(url, MavlinkUrl) else parse_mavlink_url(url)
    extra = {}
    if parsed.kind == "udpin":
        # Forget UDP peers silent for this long, so a reconnecting ground station
        # (new source port) does not keep old addresses fed forever.
        extra["udp_timeout"] = 10
    elif parsed.kind == "tcp":
        # One attempt per open: the caller owns retrying (with backoff), and a
        # blocking retry loop inside pymavlink would delay a clean stop.
        extra["retries"] = 0
    conn = mavutil.mavlink_connection(
        parsed.device,
        baud=parsed.baud,
        dialect="ardupilotmega",
        source_system=source_system,
        source_component=source_component,
        **extra,
    )
    if parsed.kind == "tcp":
        conn.handle_eof = _raise_closed("closed by the peer (EOF)")
        conn.handle_disconnect = _raise_closed("connection reset by the peer")
    elif parsed.kind == "tcpin":
        _drop_client_on_eof(conn)
    return conn


def bound_port(conn) -> int | None:
    """The local port a udpin/tcpin connection listens on (after binding port 0)."""
    for attr in ("listen", "port"):
        sock = getattr(conn, attr, None)
        if sock is not None and hasattr(sock, "getsockname"):
            try:
                return int(sock.getsockname()[1])
            except OSError:
                return None
    return None
