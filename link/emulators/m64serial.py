"""Two emulated Water Linked Modem-M64s on pseudo-terminals, in real time.

Goals: the real `wlmodem://` transport (link/transports/wlmodem.py) working with no
hardware.  Each emulated modem is a pseudo-terminal (pty) whose slave end is
reachable at a path the user names (a symlink, removed on exit), and it
speaks the Modem-M64 serial protocol there as the modem does; the packets
queued at one modem reach the other through an `M64Channel` (link/emulators/m64.py),
the emulator's model of a modem pair, driven in real time: the model decides
the turns, the latency, the loss and its bursts, and the transmit queue.

    rovlink channel --model m64 --a pty:/tmp/op-modem --b pty:/tmp/rov-modem
    rovlink console --link 'wlmodem:///tmp/op-modem?role=a'
    rovlink rov --link 'wlmodem:///tmp/rov-modem?role=b'

or, in a program (tests use short rounds):

    with M64SerialPair("/tmp/op-modem", "/tmp/rov-modem", params=M64Params(round_s=0.1, ...)) as pair:
        ...  # open wlmodem:///tmp/op-modem?role=a and wlmodem:///tmp/rov-modem?role=b

The protocol (the Modem-M64 serial protocol page, waterlinked.github.io
docs/modem/modem-m64-protocol.md, version 1.0.x; the facts are listed in
link/transports/wlmodem.py's docstring): sentences `w`, `c` (host to modem) or `r`, a
command letter, `,`-separated options, an optional `*xx` CRC-8 checksum
(polynomial 0x07) and LF or CR LF.  The host's checksum is checked when it
sends one (wlmodem sends none); every sentence of the modem carries one, as
the real modem's do, and ends with CR LF.  Answered here:

    wcv            -> wrv,1,0,1              protocol version
    wcn            -> wrn,8                  payload size
    wcs,<a|b>,<1-7> -> wrs,a (ACK) | wrs,n   role and channel
    wcc            -> wrc,<role>,<channel>   (wrc,n before any wcs: see below)
    wcq,8,<8 bytes>[*xx] -> wrq,a | wrq,n    queue a packet (NAK when full)
    wcl            -> wrl,<n>                packets in the transmit queue
    wcf            -> wrf,a                  flush the transmit queue
    wcd            -> wrd,<y|n>,<received>,<lost>,<bit error rate>
    unasked        <- wrp,8,<8 bytes>        a packet from the other modem
    malformed      -> wr?       wrong checksum -> wr!

Choices where the page is silent (so the emulator's, said here once):

- The modems start with no settings: until the host sends `wcs` a modem
  takes no turns and `wcc` answers `wrc,n`.
- Two modems link only when both are configured, on the same channel, with
  different roles; otherwise they never link, and the emulator's log says
  why (different channels; both role a; both role b).  A `wcs` while linked,
  even with the same settings (a host program restarting), makes the pair
  search for each other again: what was on the water is lost and the turns
  resume `sync_s` later; queued packets wait.  A modem whose role changes
  starts with an empty transmit queue.
- While the pair is not linked the model's clock stands still (no turns, no
  arrivals); packets queued meanwhile wait in the modem (NAK once its queue
  of `queue_packets` is full) and enter the model's queue of the modem's
  role when the pair links.  The JSON log's times are the model's clock:
  seconds since the emulator started, not counting the time the modems were
  not a pair.
- The diagnostic counts, per modem, the data packets it received and those
  addressed to it that were lost on the water (the model has no sync
  packets); its bit error rate is 0.0 (the model loses whole packets, it
  flips no bits).
- An all-zero packet is acknowledged and dropped (the real modem sends it,
  and the receiving modem drops it as its own sync packet; here it takes no
  turn); said once in the log.
- A packet that arrives while nobody has the modem's port open is lost at
  the port (counted as received by the modem), as a USB serial adapter that
  nobody reads loses it; bytes are never left waiting for the next opener.

Plan: one thread owns both ptys and the model; it waits (select) on the
ports the hosts have open and on the model's next event, answers commands
as they come, writes arrivals as `wrp` sentences, and looks every 50 ms at
ports nobody has open (a pty master reads EIO until its slave is opened).
"""

from __future__ import annotations

import json
import logging
import os
import select
import threading
import time
import tty
from collections import deque
from dataclasses import dataclass
from typing import IO, Callable

from .m64 import PACKET_BYTES, M64Channel, M64Loss, M64Params

log = logging.getLogger("rovlink.link.emulators.m64serial")

PROTOCOL_VERSION = b"1,0,1"
CHANNELS = range(1, 8)
MAX_SENTENCE = 128  # bytes without an end of line: noise, dropped with a wr?
PORT_POLL_S = 0.05  # how often a port nobody has open is looked at again
PTY_DIR = "/dev/pts/"


class M64SerialError(Exception):
    """The emulator cannot start; the message says why, in one line."""


def crc8(data: bytes) -> int:
    """The protocol's checksum: CRC-8, polynomial 0x07, initial value 0."""
    c = 0
    for byte in data:
        c ^= byte
        for _ in range(8):
            c = ((c << 1) ^ 0x07) & 0xFF if c & 0x80 else (c << 1) & 0xFF
    return c


def modem_sentence(body: bytes) -> bytes:
    """A sentence as the modem sends it: with its checksum, ended by CR LF."""
    return body + b"*%02x\r\n" % crc8(body)


def take_sentence(buf: bytearray) -> tuple[str, list[bytes]] | str | None:
    """The next host sentence in `buf`, consumed from it.

    Returns (command letter, options) for a good sentence (for `q` the last
    option is the binary payload), "?" for a malformed one, "!" for a wrong
    checksum, None when more bytes are needed.  Bytes before a `w` (line ends,
    noise) are skipped."""
    start = buf.find(b"w")
    if start < 0:
        buf.clear()
        return None
    del buf[:start]
    if len(buf) < 3:
        return None
    if buf[1:2] != b"c":
        return _drop_line(buf)
    letter = chr(buf[2])
    if letter == "q" and buf[3:4] == b",":
        return _take_binary(buf)
    end = buf.find(b"\n")
    if end < 0:
        return _drop_line(buf) if len(buf) > MAX_SENTENCE else None
    line = bytes(buf[:end]).rstrip(b"\r")
    del buf[:end + 1]
    if len(line) >= 6 and line[-3:-2] == b"*":
        line, checksum = line[:-3], line[-2:]
        if checksum.lower() != b"%02x" % crc8(line):
            return "!"
    if len(line) > 3 and line[3:4] != b",":
        return "?"
    return letter, (line[4:].split(b",") if len(line) > 3 else [])


def _take_binary(buf: bytearray) -> tuple[str, list[bytes]] | str | None:
    """`wcq,<n>,<n binary bytes>[*xx]` and its line end: the payload may hold any byte."""
    comma = buf.find(b",", 4)
    if comma < 0:
        return _drop_line(buf) if len(buf) > 8 else None
    size_text = bytes(buf[4:comma])
    if not size_text.isdigit() or int(size_text) > MAX_SENTENCE:
        return _drop_line(buf)
    end = comma + 1 + int(size_text)
    line_end = buf.find(b"\n", end)
    if line_end < 0:
        return _drop_line(buf) if len(buf) > end + 5 else None
    body, tail = bytes(buf[:end]), bytes(buf[end:line_end]).rstrip(b"\r")
    del buf[:line_end + 1]
    if tail:
        if len(tail) != 3 or tail[:1] != b"*":
            return "?"
        if tail[1:].lower() != b"%02x" % crc8(body):
            return "!"
    return "q", [size_text, body[comma + 1:]]


def _drop_line(buf: bytearray) -> str | None:
    end = buf.find(b"\n")
    if end < 0:
        if len(buf) <= MAX_SENTENCE:
            return None
        buf.clear()
    else:
        del buf[:end + 1]
    return "?"


@dataclass
class ModemCounters:
    received: int = 0  # data packets from the other modem (the diagnostic's packet count)
    lost: int = 0  # packets to this modem lost on the water (the diagnostic's loss count)
    queued: int = 0  # ACKed wcq
    refused: int = 0  # NAKed wcq (queue full, or not 8 bytes)
    zero_packets: int = 0  # all-zero packets acknowledged and dropped
    malformed: int = 0  # answered wr?
    bad_checksums: int = 0  # answered wr!
    written_while_closed: int = 0  # packets that arrived while nobody had the port open


class EmulatedModem:
    """One Modem-M64 as its host sees it: a pty, its settings, its transmit queue
    while it is not part of a linked pair."""

    def __init__(self, name: str, path: str) -> None:
        self.name = name  # "A" or "B": the emulator's names, not roles
        self.path = path  # where the user opens it (a symlink to the pty's slave)
        self.pty: str | None = None  # /dev/pts/N
        self.master = -1
        self.role: str | None = None
        self.channel: int | None = None
        self.side: str | None = None  # the model side whose queue is this modem's (its role, once paired)
        self.held: deque[bytes] = deque()  # queued while not part of a linked pair
        self.host_open = False
        self.buf = bytearray()
        self.counters = ModemCounters()

    def describe(self) -> str:
        settings = f"role {self.role}, channel {self.channel}" if self.role else "not configured"
        return f"modem {self.name} ({self.path}: {settings})"


class M64SerialPair:
    """Two emulated Modem-M64s at `path_a` and `path_b`, linked through an M64Channel.

    `params`, `a_to_b`, `b_to_a`, `seed`: the model's (link/emulators/m64.py); the model's
    side "a" is the modem configured with role a, whichever path it is on.
    `log`: every model event as a JSON line to a file, or a callable taking
    the record.  `start()` creates the ptys and their symlinks and starts the
    thread; `close()` (or leaving a `with` block) stops it and removes them."""

    def __init__(
        self,
        path_a: str,
        path_b: str,
        *,
        params: M64Params | None = None,
        a_to_b: M64Loss | None = None,
        b_to_a: M64Loss | None = None,
        seed: int | None = 0,
        log: Callable[[dict], None] | IO[str] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if os.path.abspath(path_a) == os.path.abspath(path_b):
            raise M64SerialError(f"the two modems need two paths, got {path_a} twice")
        self.params = params or M64Params()
        self.modems = (EmulatedModem("A", path_a), EmulatedModem("B", path_b))
        self._user_log = log
        self.channel = M64Channel(self.params, a_to_b, b_to_a, seed=seed, log=self._on_record)
        self._clock = clock
        self._started = False  # the model's clock has begun (first pairing)
        self._paired = False
        self._t0 = 0.0
        self._paused_at: float | None = None  # real time the model's clock stopped (not a pair)
        self._paused_total = 0.0
        self._up_due: float | None = None  # real time the link comes up
        self._announced_up = False
        self._zero_said = False
        self._stop = threading.Event()
        self._wake_r = self._wake_w = -1
        self._thread: threading.Thread | None = None

    # -- life cycle ------------------------------------------------------------

    def start(self) -> "M64SerialPair":
        try:
            for m in self.modems:
                _claim(m.path)
            for m in self.modems:
                self._open_pty(m)
        except BaseException:
            self._release()
            raise
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._t0 = self._paused_at = self._clock()
        self._thread = threading.Thread(target=self._run, name="m64 emulator", daemon=True)
        self._thread.start()
        log.info("emulated Modem-M64s at %s (%s) and %s (%s)", self.modems[0].path, self.modems[0].pty,
                 self.modems[1].path, self.modems[1].pty)
        return self

    def close(self) -> None:
        self._stop.set()
        if self._wake_w >= 0:
            try:
                os.write(self._wake_w, b"x")
            except OSError:
                pass
        if self._thread is not None:
            self._thread.join(timeout=3.0)
        self._release()
        for fd in (self._wake_r, self._wake_w):
            if fd >= 0:
                os.close(fd)
        self._wake_r = self._wake_w = -1

    def __enter__(self) -> "M64SerialPair":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def _open_pty(self, m: EmulatedModem) -> None:
        master, slave = os.openpty()
        try:
            tty.setraw(slave)  # no echo, no line editing until the host sets its own
            m.pty = os.ttyname(slave)
        finally:
            os.close(slave)  # the pty lives while its master is open; the host opens the slave by name
        os.set_blocking(master, False)
        m.master = master
        try:
            os.symlink(m.pty, m.path)
        except OSError as exc:
            raise M64SerialError(f"cannot create {m.path}: {exc.strerror}") from None

    def _release(self) -> None:
        for m in self.modems:
            if m.pty is not None:
                try:
                    if os.path.islink(m.path) and os.readlink(m.path) == m.pty:
                        os.unlink(m.path)
                except OSError:
                    pass
            if m.master >= 0:
                os.close(m.master)
                m.master = -1
            m.host_open = False

    # -- what others may read (from any thread) ---------------------------------------

    @property
    def paired(self) -> bool:
        """Both modems configured on one channel with different roles."""
        return self._paired

    @property
    def link_up(self) -> bool:
        """Paired and in sync (what the diagnostics answer)."""
        return self._paired and self._up_due is not None and self._clock() >= self._up_due

    def status_line(self) -> str:
        c = self.channel.counters
        refused = sum(m.counters.refused for m in self.modems)
        ends = ", ".join(f"{m.name}: {m.role + ' ch ' + str(m.channel) if m.role else 'not configured'}"
                         f"{'' if m.host_open else ' (port closed)'}" for m in self.modems)
        return (f"m64: sent {c.sent} delivered {c.delivered} lost {c.lost} refused {refused}, "
                f"link {'up' if self.link_up else 'down'} ({ends})")

    # -- time --------------------------------------------------------------------------

    def _model_now(self, now: float) -> float:
        ref = self._paused_at if self._paused_at is not None else now
        return ref - self._t0 - self._paused_total

    def _real(self, model_time: float) -> float:
        return model_time + self._t0 + self._paused_total

    # -- the thread --------------------------------------------------------------------

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                self._look_at_ports()
                fds = [m.master for m in self.modems if m.host_open] + [self._wake_r]
                ready, _, _ = select.select(fds, [], [], self._timeout(self._clock()))
                if self._stop.is_set():
                    return
                if self._wake_r in ready:
                    try:
                        os.read(self._wake_r, 64)
                    except BlockingIOError:
                        pass
                for m in self.modems:
                    if m.host_open and m.master in ready:
                        self._read(m)
                self._step(self._clock())
        except Exception:  # a bug: said, and the ports go away (the hosts see the modems vanish)
            log.exception("the M64 emulator failed")

    def _timeout(self, now: float) -> float | None:
        waits = []
        if self._paired:
            nxt = self.channel.next_time()
            if nxt is not None:
                waits.append(self._real(nxt) - now)
            if not self._announced_up and self._up_due is not None:
                waits.append(self._up_due - now)
        if not all(m.host_open for m in self.modems):
            waits.append(PORT_POLL_S)
        return max(0.0, min(waits)) if waits else None

    def _look_at_ports(self) -> None:
        for m in self.modems:
            poller = select.poll()
            poller.register(m.master, select.POLLIN)
            hung_up = any(ev & select.POLLHUP for _, ev in poller.poll(0))
            if hung_up == m.host_open:  # changed
                self._host(m, not hung_up)

    def _host(self, m: EmulatedModem, is_open: bool) -> None:
        m.host_open = is_open
        m.buf.clear()
        log.debug("%s: port %s by its host", m.describe(), "opened" if is_open else "closed")

    def _read(self, m: EmulatedModem) -> None:
        try:
            data = os.read(m.master, 4096)
        except BlockingIOError:
            return
        except OSError:  # EIO: the host closed the port
            self._host(m, False)
            return
        now = self._clock()
        self._step(now)  # arrivals due first, and the model's queues current for wcl
        m.buf += data
        while (taken := take_sentence(m.buf)) is not None:
            if taken == "?":
                m.counters.malformed += 1
                self._reply(m, b"wr?")
            elif taken == "!":
                m.counters.bad_checksums += 1
                self._reply(m, b"wr!")
            else:
                self._command(m, *taken, now)

    def _write(self, m: EmulatedModem, data: bytes) -> bool:
        if not m.host_open:
            return False
        try:
            os.write(m.master, data)
        except BlockingIOError:  # the host reads nothing: the UART's bytes are lost
            return False
        except OSError:
            self._host(m, False)
            return False
        return True

    def _reply(self, m: EmulatedModem, body: bytes) -> None:
        self._write(m, modem_sentence(body))

    def _step(self, now: float) -> None:
        """Arrivals due by `now`, written to their modems; the link-up note."""
        if not self._paired:
            return
        for d in self.channel.deliver(self._model_now(now)):
            m = self._owner(d.to)
            if m is None:
                continue
            m.counters.received += 1
            if not self._write(m, modem_sentence(b"wrp,%d," % len(d.data) + d.data)):
                m.counters.written_while_closed += 1
        if not self._announced_up and self._up_due is not None and now >= self._up_due:
            self._announced_up = True
            log.info("acoustic link up: %s and %s", *(m.describe() for m in self.modems))

    def _owner(self, side: str) -> EmulatedModem | None:
        return next((m for m in self.modems if m.side == side), None)

    def _on_record(self, record: dict) -> None:
        if record.get("ev") == "loss":  # "a>b": lost on its way to the modem of role b
            m = self._owner(record["dir"][-1])
            if m is not None:
                m.counters.lost += 1
        user = self._user_log
        if user is None:
            return
        if callable(user):
            user(record)
        else:
            user.write(json.dumps(record, separators=(",", ":")) + "\n")

    # -- the commands --------------------------------------------------------------------

    def _command(self, m: EmulatedModem, letter: str, options: list[bytes], now: float) -> None:
        if letter == "v":
            self._reply(m, b"wrv," + PROTOCOL_VERSION)
        elif letter == "n":
            self._reply(m, b"wrn,%d" % PACKET_BYTES)
        elif letter == "s":
            settings = _settings(options)
            if settings is None:
                self._reply(m, b"wrs,n")
            else:
                self._configure(m, *settings, now)
                self._reply(m, b"wrs,a")
        elif letter == "c":
            self._reply(m, b"wrc,%s,%d" % (m.role.encode(), m.channel) if m.role else b"wrc,n")
        elif letter == "q":
            self._reply(m, b"wrq,a" if self._queue(m, options, now) else b"wrq,n")
        elif letter == "l":
            self._reply(m, b"wrl,%d" % self._queue_length(m))
        elif letter == "f":
            self._flush(m, now)
            self._reply(m, b"wrf,a")
        elif letter == "d":
            up = b"y" if self.link_up else b"n"
            self._reply(m, b"wrd,%s,%d,%d,0.0" % (up, m.counters.received, m.counters.lost))
        else:
            m.counters.malformed += 1
            self._reply(m, b"wr?")

    def _queue(self, m: EmulatedModem, options: list[bytes], now: float) -> bool:
        if len(options) != 2 or options[0] != b"%d" % PACKET_BYTES or len(options[1]) != PACKET_BYTES:
            m.counters.refused += 1
            return False
        payload = options[1]
        if not any(payload):
            m.counters.zero_packets += 1
            if not self._zero_said:
                log.warning("%s: an all-zero packet queued: the receiving modem drops it as a sync packet "
                            "(acknowledged and dropped here)", m.describe())
                self._zero_said = True
            return True
        if m.side is not None:
            ok = self.channel.send(m.side, payload, self._model_now(now))
        else:
            ok = len(m.held) < self.params.queue_packets
            if ok:
                m.held.append(payload)
        if ok:
            m.counters.queued += 1
        else:
            m.counters.refused += 1
        return ok

    def _queue_length(self, m: EmulatedModem) -> int:
        return self.channel.queue_length(m.side) if m.side is not None else len(m.held)

    def _flush(self, m: EmulatedModem, now: float) -> None:
        m.held.clear()
        if m.side is not None:
            self.channel.flush(m.side, self._model_now(now))

    def _configure(self, m: EmulatedModem, role: str, channel: int, now: float) -> None:
        was_paired = self._paired
        if m.role is not None and role != m.role:  # its queue belonged to the other role's turns
            self._flush(m, now)
            m.side = None
        m.role, m.channel = role, channel
        log.info("%s configured", m.describe())
        why = self._why_not_paired()
        self._paired = why is None
        model_now = self._model_now(now)
        if was_paired and self._paired:
            self.channel.drop_link(model_now)
            self._link_coming(now, f"{m.describe()} re-configured: the modems search for each other again")
        elif was_paired:
            self.channel.drop_link(model_now)  # what is on the water is lost
            self._paused_at = now
            self._up_due = None
            log.warning("acoustic link down: %s", why)
        elif self._paired:
            self._paused_total += now - self._paused_at
            self._paused_at = None
            model_now = self._model_now(now)
            if not self._started:
                self.channel.is_up(model_now)  # the model's clock begins: in sync sync_s from now
                self._started = True
            for each in self.modems:
                if each.side is None:
                    each.side = each.role
                    while each.held:
                        self.channel.send(each.side, each.held.popleft(), model_now)
            self._link_coming(now, "the modems are a pair")
        else:
            log.log(logging.WARNING if all(x.role for x in self.modems) else logging.INFO, "%s", why)

    def _link_coming(self, now: float, what: str) -> None:
        self._up_due = now + self.params.sync_s
        self._announced_up = False
        log.info("%s: %s, %s; link up in %g s", what, *(x.describe() for x in self.modems), self.params.sync_s)

    def _why_not_paired(self) -> str | None:
        a, b = self.modems
        if a.role is None or b.role is None:
            return f"{(b if a.role else a).describe()}: waiting for its configuration"
        if a.channel != b.channel:
            return (f"modem {a.name} on channel {a.channel} and modem {b.name} on channel {b.channel}: "
                    "modems on different channels never link")
        if a.role == b.role:
            return f"both modems have role {a.role}: two modems of the same role never link (one must be a, the other b)"
        return None


def _settings(options: list[bytes]) -> tuple[str, int] | None:
    if len(options) != 2:
        return None
    role, channel = options[0].decode("ascii", "replace").lower(), options[1]
    if role not in ("a", "b") or not channel.isdigit() or int(channel) not in CHANNELS:
        return None
    return role, int(channel)


def _claim(path: str) -> None:
    """Make room for the symlink at `path`: only a link an earlier emulator left
    (to a pty that is gone) is replaced; anything else is refused."""
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise M64SerialError(f"cannot create {path}: no such folder {folder}")
    if os.path.islink(path):
        target = os.readlink(path)
        if target.startswith(PTY_DIR) and not os.path.exists(target):
            os.unlink(path)  # ours, left by an emulator that did not end cleanly
            log.info("removed %s, a stale link to %s", path, target)
            return
        if target.startswith(PTY_DIR):
            raise M64SerialError(f"{path} is a link to {target}, a pseudo-terminal in use (another emulator "
                                 f"running?): stop it, or remove {path} if it is stale")
        raise M64SerialError(f"{path} exists (a link to {target}, not one this emulator made): "
                             "choose another path or remove it")
    if os.path.lexists(path):
        raise M64SerialError(f"{path} exists and is not a link this emulator made: choose another path or remove it")
