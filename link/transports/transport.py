"""Transports for link frames (asyncio): UDP, serial (pyserial), in-process.

Goals: the protocol machines never see a socket and never crash because a
port vanished.  A transport that fails is reported, closed and reopened with
backoff, and whatever was sent while it was down is counted, not queued (a
stale poll or reply is worse than none on a token-passing link).

Plan: `link.transports.urls.open_transport(url)` parses a URL and returns an `Endpoint`:
    udp://HOST:PORT?peer=HOST:PORT     one frame per datagram, to and from the
                                        peer only: datagrams from any other
                                        address are counted and dropped (logged
                                        at most once a second); peer is required
    serial:///dev/ttyUSB0?baud=9600&crlf=1&mtu=64
                                        raw bytes on a serial line (a single
                                        peer by nature); crlf ends each frame
                                        with CR LF (S100); mtu caps the frame
                                        size the protocol may use
    inproc://NAME                       two in-process ends with the same NAME
    wlmodem:///dev/ttyUSB0?role=a&channel=4
                                        a Water Linked Modem-M64 (link/transports/wlmodem.py):
                                        8-byte packets, 64 bit/s (the acoustic profile)
`Endpoint.start()` opens it under a supervisor task; `send(data)` writes a
frame (never blocks); `await recv()` returns the next chunk of bytes.
"""

from __future__ import annotations

import asyncio
import errno
import logging
import os
import socket
import time
from dataclasses import dataclass, field
from typing import Callable

log = logging.getLogger("rovlink.link.transports.transport")


class TransportError(Exception):
    """A transport URL or operation that cannot work; the message says why."""


PORT_LOCKED = "locked for its own use"  # how a serial port another program holds is said


class PortUnavailable(TransportError):
    """The device or socket itself cannot be opened (absent, no permission, busy): a
    retry a moment later would say the same, so starting says it at once.  A port
    that opens but whose modem does not answer yet is retried within the timeout."""


@dataclass
class TransportStats:
    opens: int = 0
    failures: int = 0
    frames_sent: int = 0
    bytes_sent: int = 0
    bytes_received: int = 0
    dropped_while_down: int = 0
    foreign_dropped: int = 0  # UDP datagrams from an address other than the peer
    last_error: str | None = None
    history: list[tuple[float, str]] = field(default_factory=list)  # (time, "up"/"down: why")


class _Driver:
    """One opening of a concrete transport; raises or calls `failed` on error."""

    async def open(self) -> None:
        raise NotImplementedError

    def write(self, data: bytes) -> None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class Endpoint:
    """A supervised transport: reopened with backoff whenever it fails."""

    def __init__(
        self,
        url: str,
        make_driver: Callable[["Endpoint"], _Driver],
        *,
        max_frame: int | None = None,
        crlf: bool = False,
        backoff_s: tuple[float, float] = (0.05, 2.0),
    ) -> None:
        self.url = url
        self.max_frame = max_frame
        self.crlf = crlf
        self.stats = TransportStats()
        self._make_driver = make_driver
        self._driver: _Driver | None = None
        self._queue: asyncio.Queue[bytes] = asyncio.Queue()
        self._failed = asyncio.Event()
        self._up = asyncio.Event()
        self._task: asyncio.Task | None = None
        self._backoff = backoff_s
        self._closing = False
        self._quiet_until_up = False  # start(wait=True) reports a failure to open itself
        self._open_failed = asyncio.Event()  # an attempt to open failed (start(wait=True) says so at once)

    # -- life cycle ------------------------------------------------------

    async def start(self, *, wait: bool = True, timeout_s: float = 5.0) -> "Endpoint":
        """Open under supervision; with `wait`, until the first opening succeeded, or
        until the port itself failed to open (PortUnavailable, OSError): then at once,
        with its reason (a port that is not there now is not there a few retries
        later; the pilot is told while still at the keyboard)."""
        self._closing = False  # an endpoint closed (a first look at its port) may be started again
        if wait:
            # The caller says why it failed, once: not also the supervisor's log.
            self._quiet_until_up = True
            self._open_failed.clear()
        if self._task is None:
            self._task = asyncio.get_running_loop().create_task(self._supervise(), name=f"transport {self.url}")
        if wait:
            up = asyncio.ensure_future(self._up.wait())
            failed = asyncio.ensure_future(self._open_failed.wait())
            try:
                await asyncio.wait({up, failed}, timeout=timeout_s, return_when=asyncio.FIRST_COMPLETED)
            finally:
                up.cancel()
                failed.cancel()
                self._quiet_until_up = False
            if not self._up.is_set():
                why = self.stats.last_error or f"no answer in {timeout_s:g} s"
                await self.close()  # no supervisor left retrying (or pending when the loop closes)
                raise TransportError(f"{self.url}: could not open: {why}")
        return self

    async def close(self) -> None:
        self._closing = True
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except (asyncio.CancelledError, Exception):
                pass
            self._task = None
        self._up.clear()
        self._drop_driver()

    async def __aenter__(self) -> "Endpoint":
        return await self.start()

    async def __aexit__(self, *exc) -> None:
        await self.close()

    @property
    def is_up(self) -> bool:
        return self._up.is_set()

    async def _supervise(self) -> None:
        delay = self._backoff[0]
        while not self._closing:
            driver = self._make_driver(self)
            try:
                await driver.open()
            except Exception as exc:  # every way a port or socket can fail to open
                # The drivers say why in words (TransportError); "could not open" is the caller's.
                self._note_down(str(exc) or type(exc).__name__)
                if isinstance(exc, (PortUnavailable, OSError)):
                    self._open_failed.set()
                await asyncio.sleep(delay)
                delay = min(delay * 2, self._backoff[1])
                continue
            self._driver = driver
            self._failed.clear()
            self._up.set()
            self.stats.opens += 1
            self.stats.history.append((time.time(), "up"))
            log.info("%s: open", self.url)
            delay = self._backoff[0]
            await self._failed.wait()
            self._up.clear()
            self._drop_driver()

    def _drop_driver(self) -> None:
        driver, self._driver = self._driver, None
        if driver is not None:
            try:
                driver.close()
            except Exception:  # closing a dead port may fail too; it is gone either way
                pass

    def _note_down(self, why: str) -> None:
        if self.stats.last_error != why and not self._quiet_until_up:
            log.warning("%s: %s", self.url, why)
        self.stats.last_error = why
        self.stats.history.append((time.time(), f"down: {why}"))
        del self.stats.history[:-50]

    # -- called by drivers -------------------------------------------------

    def _received(self, data: bytes) -> None:
        if data:
            self.stats.bytes_received += len(data)
            self._queue.put_nowait(bytes(data))

    def _fail(self, why: str) -> None:
        if self._failed.is_set():
            return
        self.stats.failures += 1
        self._note_down(why)
        self._failed.set()
        self._up.clear()

    # -- data --------------------------------------------------------------

    def send(self, frame: bytes) -> bool:
        """Write one frame; False (and counted) if the transport is down."""
        driver = self._driver
        if driver is None or not self._up.is_set():
            self.stats.dropped_while_down += 1
            return False
        data = frame + b"\r\n" if self.crlf else frame
        try:
            driver.write(data)
        except Exception as exc:  # the port vanished under us
            self._fail(f"write failed: {exc}")
            self.stats.dropped_while_down += 1
            return False
        self.stats.frames_sent += 1
        self.stats.bytes_sent += len(data)
        return True

    async def recv(self) -> bytes:
        """The next bytes received (waits across reopenings)."""
        return await self._queue.get()

    def recv_nowait(self) -> bytes | None:
        try:
            return self._queue.get_nowait()
        except asyncio.QueueEmpty:
            return None


# ---------------------------------------------------------------------------
# UDP
# ---------------------------------------------------------------------------


def _hostport(text: str, what: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise TransportError(f"{what} must be HOST:PORT, got {text!r}")
    return host.strip("[]"), int(port)


FOREIGN_LOG_INTERVAL_S = 1.0


class _UdpDriver(_Driver, asyncio.DatagramProtocol):
    """One UDP socket talking to one peer: a token-passing link has exactly two
    ends, and a datagram from anyone else (a second console, an injected poll)
    must never reach the protocol machine (it would flip ACK or feed the failsafe)."""

    def __init__(self, endpoint: Endpoint, local: tuple[str, int], peer: tuple[str, int]) -> None:
        self.endpoint = endpoint
        self.local = local
        self.peer = peer
        self._peer_addrs: set[tuple[str, int]] = set()
        self._foreign_logged_at = -float("inf")
        self._foreign_since_log = 0
        self.transport: asyncio.DatagramTransport | None = None

    async def open(self) -> None:
        loop = asyncio.get_running_loop()
        # The peer's name resolved once per opening: datagrams are matched by address.
        infos = await loop.getaddrinfo(self.peer[0], self.peer[1], type=socket.SOCK_DGRAM)
        self._peer_addrs = {(info[4][0], info[4][1]) for info in infos}
        self.transport, _ = await loop.create_datagram_endpoint(lambda: self, local_addr=self.local)

    @property
    def local_address(self) -> tuple[str, int]:
        assert self.transport is not None
        return self.transport.get_extra_info("sockname")[:2]

    def write(self, data: bytes) -> None:
        if self.transport is None:
            raise TransportError("udp socket not open")
        self.transport.sendto(data, self.peer)

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()

    def datagram_received(self, data: bytes, addr) -> None:
        if (addr[0], addr[1]) in self._peer_addrs:
            self.endpoint._received(data)
            return
        stats = self.endpoint.stats
        stats.foreign_dropped += 1
        self._foreign_since_log += 1
        now = time.monotonic()
        if now - self._foreign_logged_at >= FOREIGN_LOG_INTERVAL_S:
            log.warning(
                "%s: dropped %d datagram(s) from %s:%s, not the peer %s:%s (%d in all)",
                self.endpoint.url, self._foreign_since_log, addr[0], addr[1], self.peer[0], self.peer[1],
                stats.foreign_dropped,
            )
            self._foreign_logged_at = now
            self._foreign_since_log = 0

    def error_received(self, exc: Exception) -> None:
        # ICMP "port unreachable" when the peer is not up yet: not a failure
        # of ours, the next poll or reply simply finds it later.
        self.endpoint.stats.last_error = f"udp: {exc}"

    def connection_lost(self, exc: Exception | None) -> None:
        if exc is not None:
            self.endpoint._fail(f"udp socket lost: {exc}")


class UdpEndpoint(Endpoint):
    def __init__(self, url: str, local: tuple[str, int], peer: tuple[str, int], **kw) -> None:
        super().__init__(url, lambda ep: _UdpDriver(ep, local, peer), **kw)

    @property
    def local_address(self) -> tuple[str, int] | None:
        driver = self._driver
        return driver.local_address if isinstance(driver, _UdpDriver) else None


# ---------------------------------------------------------------------------
# Serial
# ---------------------------------------------------------------------------


class _SerialDriver(_Driver):
    def __init__(self, endpoint: Endpoint, path: str, baud: int) -> None:
        self.endpoint = endpoint
        self.path = path
        self.baud = baud
        self.port = None
        self._fd: int | None = None

    async def open(self) -> None:
        import serial  # pyserial

        port = serial.Serial(exclusive=True)  # one program per modem: a second console or ROV is told, not mixed in
        port.port = self.path
        port.baudrate = self.baud
        port.timeout = 0
        port.write_timeout = 2.0
        try:
            port.open()
        except serial.SerialException as exc:
            raise PortUnavailable(serial_open_error(self.path, exc)) from None
        self.port = port
        self._fd = port.fileno()
        asyncio.get_running_loop().add_reader(self._fd, self._readable)

    def _readable(self) -> None:
        try:
            data = self.port.read(max(1, self.port.in_waiting))
            if not data:
                # Readable but empty: the other side of a pty closed, or the
                # USB adapter went away.
                raise OSError("device reports readiness to read but returned no data")
        except Exception as exc:
            self._remove_reader()
            self.endpoint._fail(f"serial read failed: {exc}")
            return
        self.endpoint._received(data)

    def _remove_reader(self) -> None:
        if self._fd is not None:
            try:
                asyncio.get_running_loop().remove_reader(self._fd)
            except Exception:
                pass
            self._fd = None

    def write(self, data: bytes) -> None:
        self.port.write(data)

    def close(self) -> None:
        self._remove_reader()
        if self.port is not None:
            try:
                self.port.close()
            finally:
                self.port = None


# ---------------------------------------------------------------------------
# In-process
# ---------------------------------------------------------------------------


class _InprocDriver(_Driver):
    def __init__(self, endpoint: "InprocEndpoint") -> None:
        self.endpoint = endpoint

    async def open(self) -> None:
        return None

    def write(self, data: bytes) -> None:
        peer = self.endpoint.peer
        if peer is None or not peer.is_up:
            raise TransportError("the other in-process end is not open")
        peer._received(data)

    def close(self) -> None:
        return None


class InprocEndpoint(Endpoint):
    def __init__(self, url: str, **kw) -> None:
        super().__init__(url, lambda ep: _InprocDriver(ep), **kw)  # type: ignore[arg-type]
        self.peer: InprocEndpoint | None = None


_INPROC: dict[str, list[InprocEndpoint]] = {}


def inproc_pair(name: str = "pair", **kw) -> tuple[InprocEndpoint, InprocEndpoint]:
    """Two connected in-process ends (not registered by name)."""
    a, b = InprocEndpoint(f"inproc://{name}", **kw), InprocEndpoint(f"inproc://{name}", **kw)
    a.peer, b.peer = b, a
    return a, b


# ---------------------------------------------------------------------------


def serial_open_error(path: str, exc: Exception) -> str:
    """Why a serial port did not open, in a pilot's words (pyserial's own text
    repeats "could not open" and the errno twice)."""
    code = getattr(exc, "errno", None)
    if code == errno.ENOENT or not os.path.exists(path):
        return f"no serial port {path} (is the modem's USB serial adapter plugged in?)"
    if code in (errno.EACCES, errno.EPERM):
        return f"no permission to open {path} (is this user in the port's group, e.g. dialout?)"
    if code == errno.EBUSY:
        return f"{path} is busy (another program has it open)"
    if code in (errno.EAGAIN, errno.EWOULDBLOCK):
        return f"{path} is in use: another program holds it ({PORT_LOCKED})"
    return f"serial port {path} cannot be opened: {os.strerror(code) if code else exc}"


def port_change(endpoint, was: bool | None) -> tuple[bool | None, str | None]:
    """The port of `endpoint` now (its `is_up`; None for an endpoint that has no
    such notion) and, when it changed from `was`, what to tell the pilot: that it
    went down, with the transport's reason, or that it is open again (nothing
    for the first look at a port that is up)."""
    up = getattr(endpoint, "is_up", None)
    if up is None or up == was:
        return was, None
    if not up:
        return False, f"MODEM PORT DOWN: {port_down_reason(endpoint)}; opening it again"
    return True, None if was is None else "modem port open again"


def port_down_reason(endpoint) -> str | None:
    """Why the port of `endpoint` is down (the transport's last error), or None
    while it is up (or for an endpoint with no notion of a port)."""
    if endpoint is None or getattr(endpoint, "is_up", True):
        return None
    return getattr(getattr(endpoint, "stats", None), "last_error", None) or "no reason given"


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port free right now on host (for tests and the demo)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]

