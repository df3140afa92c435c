"""Transport over a Water Linked Modem-M64 acoustic modem, through `wlmodem`.

Goals: the acoustic link as one more `Endpoint` (link/transports/transport.py): opened
and reopened under the same supervisor, 8-byte packets in and out, the
modem's own state (link up or down, packets received and lost, bit error
rate) in the log once per change, and every way it can go wrong said in one
line: a bad URL, a missing port, a port that answers but is no M64, a modem
that refuses its configuration, a port that vanishes.

    wlmodem:///dev/ttyUSB0?role=a&channel=4
        role     a or b (required): the two modems of a pair take different
                 roles on the same channel; role a always transmits, role b
                 answers once it hears a (the topside is usually a)
        channel  1-7 (default 4, the channel wlmodem's examples use)
        baud     the modem's UART speed (default 115200, the M64's)
        diag     seconds between two diagnostic requests (default 2; the
                 link state is logged when it changes)

The modem, as `wlmodem` 1.3.0 speaks it (wlmodem/protocol.py) and the
Modem-M64 serial protocol page documents it (waterlinked.github.io,
docs/modem/modem-m64-protocol.md, protocol version 1.0.x):

- UART 115200 8-N-1, no flow control.  A sentence is `w`, a direction (`c`
  to the modem, `r` from it), a command letter, `,`-separated options, an
  optional `*xx` checksum (CRC-8, polynomial 0x07, two lower-case hex digits;
  the modem always sends one, wlmodem sends none) and LF or CR LF.
- `wcv` -> `wrv,1,0,1` protocol version (major must be 1); `wcn` -> `wrn,8`
  payload size (8 bytes on the M64); `wcs,<role>,<channel>` -> `wrs,a` (ACK)
  or `wrs,n` (NAK) sets role a/b and channel 1-7 (`wcc` reads them back);
  `wcq,8,<8 binary bytes>` -> `wrq,a`/`wrq,n` queues a packet; `wcl` ->
  `wrl,<n>` packets waiting in the transmit queue; `wcf` -> `wrf,a` flushes
  it; `wcd` -> `wrd,<y|n>,<packets received>,<packets lost>,<bit error
  rate>` (link up?, the loss count counts every undecodable packet, data or
  sync; the rate is in percent per the protocol's draft).  A packet from the
  other modem arrives unasked: `wrp,8,<8 binary bytes>`.  `wr?` and `wr!`
  answer a malformed sentence and a wrong checksum.
- wlmodem: `WlModemBase(iodev)` runs the protocol over any object with
  `in_waiting`, `read(1)`, `write()` and `port`; `connect()` checks the
  version and reads the payload size; `cmd_configure(role, channel)`,
  `cmd_queue_packet(8 bytes)`, `get_data_packet(timeout=0)`,
  `cmd_get_diagnostic()` (a dict: link_up, pkt_cnt, pkt_loss_cnt,
  bit_error_rate), `cmd_get_queue_length()`, `cmd_flush_queue()`.  Its
  requests block, polling the port every millisecond until the answer (or
  0.5 s, 2 s for a configuration); a packet that arrives meanwhile is kept.
- All-zero payloads are reserved: the modem sends them to keep in sync when
  nothing is queued, and the receiver drops them; this transport refuses them.
- The host does not decide when a queued packet leaves; the modems take
  turns, one packet a second each way, 1.5-2.5 s from queue to the other
  host, a few seconds to (re)establish the link (figures and sources in
  link/emulators/m64.py, the emulator's model of the modem).

wlmodem's simulator (`WlModemSimulator`) is no serial device: it subclasses
WlModemBase and answers `request()` in the same process (after a 50 ms
sleep), one modem alone whose queued packets come back to itself, one a
second, once the link is "up" 3 s after a configuration.  Nothing of it goes
over a port; tests/link/test_wlmodem.py bridges it onto a pseudo-terminal to
check this transport against its behaviour, and speaks the documented
protocol for a pair of modems in a small responder of its own.

Plan: the port and the modem belong to one worker thread (wlmodem blocks);
the event loop hands it packets (a deque and a wake-up pipe) and gets back
received packets and failures through `call_soon_threadsafe`.  On every
opening the modem is connected, configured and its transmit queue flushed
(a stale packet is worse than none).  `flush()` empties both queues, so that
`flush(); send(stop)` puts a packet ahead of everything queued.

`queue_length()` answers at once, without asking the modem: a driver that
keeps at most one packet waiting in the modem polls it every 0.2 s or so.
The worker asks (`wcl`) after every run of packets handed to the modem and
after a flush, then every QUEUE_REFRESH_S while the modem's queue is not
known empty (an empty queue cannot fill by itself: then nothing is asked);
the answer is the modem's last count plus every packet handed over since
(acknowledged after that count, being handed over, or still waiting for the
worker), and after `flush()` only the packets sent after it.  So it never
counts less than the modem holds, and counts more only until the next
refresh after the modem transmitted (at most QUEUE_REFRESH_S late).  With
the emulated modems (link/emulators/m64serial.py) all of this runs with no hardware.
"""

from __future__ import annotations

import asyncio
import logging
import os
import select
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from urllib.parse import parse_qs, urlsplit

from wlmodem.protocol import WlModemBase, WlProtocolParseError

from .transport import Endpoint, PortUnavailable, TransportError, _Driver, serial_open_error

log = logging.getLogger("rovlink.link.transports.wlmodem")

PACKET_BYTES = 8  # the Modem-M64's payload size
BAUD = 115200
ROLES = ("a", "b")
CHANNELS = range(1, 8)
DEFAULT_CHANNEL = 4
DIAG_S = 2.0
UNANSWERED_LIMIT = 3  # diagnostic requests in a row without an answer: the modem is gone
QUEUE_REFRESH_S = 0.2  # between two `wcl` while the modem's transmit queue is not known empty


@dataclass
class ModemStats:
    """What the modem and this transport did; `link_up` is None until first asked."""

    link_up: bool | None = None
    diagnostic: dict = field(default_factory=dict)  # the modem's last answer to `wcd`
    queue_length: int | None = None  # the modem's last answer to `wcl`
    packets_queued: int = 0  # acknowledged by the modem
    packets_refused: int = 0  # NAK or no answer to `wcq`
    packets_received: int = 0
    packets_flushed: int = 0  # ours dropped by flush() before reaching the modem
    parse_errors: int = 0  # sentences from the modem wlmodem could not parse
    link_history: list[tuple[float, str]] = field(default_factory=list)  # (time, "up"/"down")


class _PortIO:
    """The serial port as wlmodem's io device: `in_waiting` pulls whatever the
    port holds without blocking, so that a vanished device raises here (pyserial
    reports it on read) instead of looking like silence."""

    def __init__(self, port) -> None:
        self.serial = port
        self.port = port.port  # wlmodem logs it
        self._buf = bytearray()

    @property
    def in_waiting(self) -> int:
        if not self._buf:
            self._buf += self.serial.read(4096)  # timeout 0: what is there, or raises
        return len(self._buf)

    @property
    def buffered(self) -> int:
        return len(self._buf)

    def read(self, n: int = 1) -> bytes:
        data = bytes(self._buf[:n])
        del self._buf[:n]
        return data

    def write(self, data) -> int:
        return self.serial.write(bytes(data))


class _WlModemDriver(_Driver):
    def __init__(self, endpoint: "WlModemEndpoint") -> None:
        self.endpoint = endpoint
        self.loop: asyncio.AbstractEventLoop | None = None
        self.port = None
        self.io: _PortIO | None = None
        self.modem = None
        self._ops: deque[tuple[str, bytes | None]] = deque()
        self._stop = threading.Event()
        self._wake_r, self._wake_w = -1, -1
        self._thread: threading.Thread | None = None
        self._abandoned = False  # the opening was cancelled while its thread still ran
        # The transmit queue's length (queue_length()), shared with the event loop under _lock:
        self._lock = threading.Lock()
        self._in_hand: str | None = None  # the op the worker is carrying out
        self._known_length = 0  # the modem's last answer to `wcl` (0 after opening: flushed)
        self._acked_since = 0  # packets the modem acknowledged after that answer
        self._flushing = False  # a flush asked for and not yet done
        self._next_refresh = 0.0

    # -- opening (in a thread: wlmodem and pyserial block) ---------------------

    async def open(self) -> None:
        self.loop = asyncio.get_running_loop()
        try:
            await asyncio.to_thread(self._open_blocking)
        except BaseException:
            self._abandoned = True  # a cancelled wait leaves the thread running: it closes the port itself
            self._close_port()
            raise
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        self._thread = threading.Thread(target=self._run, name=f"wlmodem {self.endpoint.path}", daemon=True)
        self._thread.start()

    def _open_blocking(self) -> None:
        import serial  # pyserial

        ep = self.endpoint
        port = serial.Serial(exclusive=True)  # one program per modem: a second console or ROV is told, not mixed in
        port.port = ep.path
        port.baudrate = ep.baud
        port.timeout = 0
        port.write_timeout = 2.0
        try:
            port.open()
        except serial.SerialException as exc:
            raise PortUnavailable(serial_open_error(ep.path, exc)) from None
        self.port = port
        self.io = _PortIO(port)
        modem = WlModemBase(self.io)
        try:
            self._configure(modem)
        except BaseException:
            self._close_port()
            raise
        if self._abandoned:
            self._close_port()
            raise TransportError("opening abandoned")
        self.modem = modem
        log.info("%s: Modem-M64 configured: role %s, channel %d", ep.url, ep.role, ep.channel)

    def _configure(self, modem: WlModemBase) -> None:
        ep = self.endpoint
        try:
            if not modem.connect():
                raise TransportError(f"no Water Linked modem answers on {ep.path} (no valid reply to the version "
                                     f"and payload-size requests at {ep.baud} baud)")
            if modem.payload_size != PACKET_BYTES:
                raise TransportError(f"the modem on {ep.path} carries {modem.payload_size}-byte packets; this "
                                     f"transport speaks the Modem-M64's {PACKET_BYTES}")
            if not modem.cmd_configure(ep.role, ep.channel):
                raise TransportError(f"the modem on {ep.path} refused role {ep.role} on channel {ep.channel} "
                                     "(NAK or no answer)")
            if not modem.cmd_flush_queue():
                raise TransportError(f"the modem on {ep.path} did not flush its transmit queue")
        except WlProtocolParseError as exc:
            raise TransportError(f"the device on {ep.path} answers garbage, not the Water Linked protocol: {exc}") from None

    # -- the worker thread -----------------------------------------------------

    def _run(self) -> None:
        ep = self.endpoint
        next_diag = time.monotonic()
        unanswered = 0
        try:
            while not self._stop.is_set():
                self._do_ops()
                self._read_packets()
                now = time.monotonic()
                if now >= next_diag:
                    unanswered = 0 if self._diagnose() else unanswered + 1
                    if unanswered >= UNANSWERED_LIMIT:
                        raise TransportError(f"the modem on {ep.path} stopped answering "
                                             f"({UNANSWERED_LIMIT} diagnostic requests unanswered)")
                    next_diag = now + ep.diag_s
                elif self._queue_unknown() and now >= self._next_refresh:
                    self._refresh_queue_length()
                if self._ops or (self.io is not None and self.io.buffered):
                    continue
                wake_at = min(next_diag, self._next_refresh) if self._queue_unknown() else next_diag
                timeout = max(0.0, wake_at - time.monotonic())
                ready, _, _ = select.select([self.port.fileno(), self._wake_r], [], [], timeout)
                if self._wake_r in ready:
                    try:
                        os.read(self._wake_r, 4096)
                    except BlockingIOError:
                        pass
        except Exception as exc:  # the port vanished, or the modem went silent
            if not self._stop.is_set():
                why = str(exc) if isinstance(exc, TransportError) else f"modem port {ep.path} failed: {exc}"
                self._report(ep._fail, why)
        finally:
            self._close_port()

    def _do_ops(self) -> None:
        ep = self.endpoint
        handed = False
        while not self._stop.is_set():
            with self._lock:
                if not self._ops:
                    break
                op, packet = self._ops.popleft()
                self._in_hand = op
            handed = True
            try:
                done = self.modem.cmd_flush_queue() if op == "flush" else self.modem.cmd_queue_packet(packet)
            except WlProtocolParseError as exc:  # a garbled answer: not an acknowledgement
                ep.modem_stats.parse_errors += 1
                log.debug("%s: unparsable answer from the modem: %s", ep.url, exc)
                done = False
            with self._lock:
                self._in_hand = None
                if op == "flush":
                    if done:
                        self._known_length, self._acked_since = 0, 0
                    self._flushing = any(o == "flush" for o, _ in self._ops)
                elif done:
                    self._acked_since += 1
            if op == "flush":
                if done:
                    ep.modem_stats.queue_length = 0
                else:
                    log.warning("%s: the modem did not flush its transmit queue", ep.url)
                continue
            if done:
                ep.modem_stats.packets_queued += 1
                ep._refusing = False
            else:
                ep.modem_stats.packets_refused += 1
                if not ep._refusing:  # once per run of refusals
                    log.warning("%s: the modem refused a packet (transmit queue full? %s waiting at last count)",
                                ep.url, ep.modem_stats.queue_length)
                    ep._refusing = True
        if handed and not self._stop.is_set():
            self._refresh_queue_length()

    def _queue_unknown(self) -> bool:
        """Whether the modem's transmit queue may hold packets (so is worth asking about)."""
        return self._known_length > 0 or self._acked_since > 0

    def _refresh_queue_length(self) -> None:
        """Ask the modem (`wcl`) how many packets wait in its transmit queue."""
        self._next_refresh = time.monotonic() + QUEUE_REFRESH_S
        try:
            length = self.modem.cmd_get_queue_length()
        except (WlProtocolParseError, ValueError, IndexError, TypeError) as exc:  # a malformed answer
            self.endpoint.modem_stats.parse_errors += 1
            log.debug("%s: malformed queue length: %s", self.endpoint.url, exc)
            return
        self._note_queue_length(length)

    def _note_queue_length(self, length: int) -> None:
        if length < 0:  # no answer
            return
        with self._lock:  # every acknowledgement so far came before this answer
            self._known_length, self._acked_since = length, 0
        self.endpoint.modem_stats.queue_length = length

    def queue_length(self) -> int:
        with self._lock:
            pending = sum(1 for op, _ in self._ops if op == "queue")
            if self._flushing:
                return pending
            in_hand = 1 if self._in_hand == "queue" else 0
            return self._known_length + self._acked_since + in_hand + pending

    def _read_packets(self) -> None:
        ep = self.endpoint
        while not self._stop.is_set():
            try:
                packet = self.modem.get_data_packet(timeout=0)
            except WlProtocolParseError as exc:
                ep.modem_stats.parse_errors += 1
                log.debug("%s: unparsable sentence from the modem: %s", ep.url, exc)
                continue
            if packet:
                ep.modem_stats.packets_received += 1
                self._report(ep._received, bytes(packet))
            elif not self.io.buffered:
                return

    def _diagnose(self) -> bool:
        ep = self.endpoint
        stats = ep.modem_stats
        try:
            diag = self.modem.cmd_get_diagnostic()
            length = self.modem.cmd_get_queue_length()
        except (WlProtocolParseError, ValueError, IndexError, TypeError) as exc:  # a malformed answer
            stats.parse_errors += 1
            log.debug("%s: malformed diagnostic: %s", ep.url, exc)
            return True
        self._note_queue_length(length)
        if not diag:
            return False
        stats.diagnostic = diag
        log.debug("%s: diagnostic %s, %s queued", ep.url, diag, stats.queue_length)
        up = bool(diag.get("link_up"))
        if up != stats.link_up:
            # Down at the start is expected (the modems take a few seconds to sync): said, not warned.
            level = logging.WARNING if stats.link_up is not None and not up else logging.INFO
            log.log(level, "%s: acoustic link %s (role %s, channel %d; packets received %s, lost %s, "
                    "bit error rate %s %%, %s queued)", ep.url, "up" if up else "down", ep.role, ep.channel,
                    diag.get("pkt_cnt"), diag.get("pkt_loss_cnt"), diag.get("bit_error_rate"), stats.queue_length)
            stats.link_up = up
            stats.link_history.append((time.time(), "up" if up else "down"))
            del stats.link_history[:-50]
        return True

    def _report(self, fn, *args) -> None:
        loop = self.loop
        if loop is None or loop.is_closed():
            return
        try:
            loop.call_soon_threadsafe(fn, *args)
        except RuntimeError:  # the loop closed meanwhile
            pass

    # -- called from the event loop ----------------------------------------------

    def write(self, data: bytes) -> None:
        if self._thread is None or not self._thread.is_alive():
            raise TransportError(f"modem port {self.endpoint.path} is not open")
        with self._lock:
            self._ops.append(("queue", bytes(data)))
        self._wake()

    def flush(self) -> int:
        with self._lock:
            dropped = sum(1 for op, _ in self._ops if op == "queue")
            self._ops.clear()
            self._ops.append(("flush", None))
            self._flushing = True
        self._wake()
        return dropped

    def _wake(self) -> None:
        try:
            os.write(self._wake_w, b"x")
        except (BlockingIOError, OSError):
            pass  # already awake, or closing

    def close(self) -> None:
        self._stop.set()
        self._wake()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=3.0)
        if thread is None or not thread.is_alive():
            self._close_port()
        for fd in (self._wake_r, self._wake_w):
            if fd >= 0:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._wake_r = self._wake_w = -1

    def _close_port(self) -> None:
        port, self.port = self.port, None
        if port is not None:
            try:
                port.close()
            except Exception:  # a vanished port may fail to close; it is gone either way
                pass


class WlModemEndpoint(Endpoint):
    """An Endpoint whose frames are the Modem-M64's 8-byte packets."""

    def __init__(self, url: str, path: str, role: str, channel: int, *, baud: int = BAUD,
                 diag_s: float = DIAG_S, **kw) -> None:
        super().__init__(url, lambda ep: _WlModemDriver(ep), max_frame=PACKET_BYTES, **kw)  # type: ignore[arg-type]
        self.path = path
        self.role = role
        self.channel = channel
        self.baud = baud
        self.diag_s = diag_s
        self.modem_stats = ModemStats()
        self._refusing = False

    def send(self, frame: bytes) -> bool:
        """Queue one 8-byte packet at the modem; False (and counted) if the port is down.

        Anything but 8 bytes, or 8 zero bytes (the modem's own sync packet, which
        the receiving modem drops), raises TransportError: a caller's mistake."""
        if len(frame) != PACKET_BYTES:
            raise TransportError(f"{self.url}: the Modem-M64 carries packets of exactly {PACKET_BYTES} bytes, "
                                 f"got {len(frame)}")
        if not any(frame):
            raise TransportError(f"{self.url}: an all-zero packet is the Modem-M64's own sync packet; "
                                 "the receiving modem would drop it")
        return super().send(frame)

    def flush(self) -> int:
        """Drop every packet not yet on the water, ours and the modem's (`wcf`).

        `flush(); send(p)` puts p ahead of everything queued.  Returns the number
        of our own packets dropped (not yet handed to the modem); the modem does
        not say how many of its own it dropped."""
        driver = self._driver
        if not isinstance(driver, _WlModemDriver) or not self.is_up:
            return 0
        dropped = driver.flush()
        self.modem_stats.packets_flushed += dropped
        return dropped

    def queue_length(self) -> int | None:
        """Packets waiting in the modem's transmit queue, at once and without asking
        the modem: its last `wcl` answer (refreshed after every packet handed to it,
        after a flush, and every QUEUE_REFRESH_S while not known empty) plus every
        packet handed over since; after `flush()`, only the packets sent after it.
        Never less than the modem holds; more by the packets it transmitted since
        the last refresh.  None while the port is not open."""
        driver = self._driver
        if not isinstance(driver, _WlModemDriver) or not self.is_up:
            return None
        return driver.queue_length()

    @property
    def link_up(self) -> bool | None:
        """The modem's own view: in sync with the other modem (None: not asked yet)."""
        return self.modem_stats.link_up if self.is_up else None


def open_wlmodem(url: str) -> WlModemEndpoint:
    """Parse a wlmodem:// URL; raises TransportError saying what is wrong."""
    parts = urlsplit(url)
    if parts.scheme != "wlmodem":
        raise TransportError(f"not a wlmodem:// URL: {url!r}")
    path = parts.path or parts.netloc
    if not path or path == "/":
        raise TransportError(f"wlmodem URL needs a serial device, e.g. wlmodem:///dev/ttyUSB0?role=a&channel=4, got {url!r}")
    if parts.netloc and parts.path:
        raise TransportError(f"wlmodem URL takes a device path after three slashes, e.g. "
                             f"wlmodem:///dev/ttyUSB0?role=a, got {url!r}")
    try:
        raw = parse_qs(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query))
    except ValueError:
        raise TransportError(f"malformed query in {url!r}: use ?role=a&channel=4") from None
    repeated = sorted(k for k, v in raw.items() if len(v) > 1)
    if repeated:
        raise TransportError(f"option(s) {', '.join(repeated)} given more than once in {url!r}")
    query = {k: v[0] for k, v in raw.items()}

    role = query.pop("role", None)
    if role is None:
        raise TransportError(f"wlmodem URL needs ?role=a or ?role=b (the two modems of a pair take different roles), "
                             f"got {url!r}")
    role = role.lower()
    if role not in ROLES:
        raise TransportError(f"role must be a or b, got {role!r}")
    channel_text = query.pop("channel", str(DEFAULT_CHANNEL))
    if not channel_text.isdigit() or int(channel_text) not in CHANNELS:
        raise TransportError(f"channel must be 1-7 (both modems of a pair on the same one), got {channel_text!r}")
    baud_text = query.pop("baud", str(BAUD))
    if not baud_text.isdigit() or int(baud_text) <= 0:
        raise TransportError(f"baud must be a positive integer (the Modem-M64 talks at {BAUD}), got {baud_text!r}")
    diag_text = query.pop("diag", str(DIAG_S))
    try:
        diag_s = float(diag_text)
    except ValueError:
        diag_s = -1.0
    if not 0.05 <= diag_s <= 3600:
        raise TransportError(f"diag must be the seconds between diagnostic requests, 0.05-3600, got {diag_text!r}")
    if query:
        raise TransportError(f"unknown option(s) {', '.join(sorted(query))} in {url!r} "
                             "(wlmodem:// takes role, channel, baud and diag)")
    return WlModemEndpoint(url, path, role, int(channel_text), baud=int(baud_text), diag_s=diag_s)
