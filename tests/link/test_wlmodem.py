"""The wlmodem:// transport on real pseudo-terminals.

wlmodem's own simulator (WlModemSimulator) answers in-process and never
touches a port, and it is one modem alone whose packets come back to itself;
so it is tested here through a small bridge that makes it answer on a pty.  A
pair of modems talking to each other is played by `M64Pair`, a responder
written from the Modem-M64 serial protocol page (waterlinked.github.io,
docs/modem/modem-m64-protocol.md): two ptys, commands answered with their
checksums, the roles taking turns once both modems are configured on one
channel with different roles, `wrp` packets sent unasked.  Times are short
(a round of 0.1 s) and the tests wait on conditions, never on the clock.
"""

from __future__ import annotations

import asyncio
import atexit
import itertools
import logging
import os
import select
import shutil
import tempfile
import threading
import time
from collections import deque

import pytest

from rovlink.link.transports.transport import PORT_LOCKED, TransportError
from rovlink.link.transports.wlmodem import PACKET_BYTES, WlModemEndpoint, open_wlmodem

from ..helpers import Pty, run_async
from ..helpers import until as wait_until

LOGGER = "rovlink.link.transports.wlmodem"
TRANSPORT_LOGGER = "rovlink.link.transports.transport"


def run(coro, timeout=25):
    return run_async(coro, timeout)


def until(cond, timeout=5.0, what="condition"):
    return wait_until(cond, timeout, what)


def crc8(data: bytes) -> int:
    """CRC-8, polynomial 0x07, initial 0 (the protocol page's checksum)."""
    c = 0
    for byte in data:
        c ^= byte
        for _ in range(8):
            c = ((c << 1) ^ 0x07) & 0xFF if c & 0x80 else (c << 1) & 0xFF
    return c


def sentence(body: bytes) -> bytes:
    return body + b"*%02x\r\n" % crc8(body)


_LINKS = tempfile.mkdtemp(prefix="rovlink-wlmodem-")
atexit.register(shutil.rmtree, _LINKS, True)
_NAMES = itertools.count()


def make_pty() -> Pty:
    """A pty at a path of its own that the transport opens: a link in a private
    folder, as a udev rule names an adapter (tests.helpers.Pty).  When the pty goes
    (`Pty.down`) the link goes first, so a transport that keeps reopening its path
    never reaches the pty another test (on another worker) got under the same
    /dev/pts number."""
    pty = Pty(os.path.join(_LINKS, f"tty{next(_NAMES)}"))
    pty.up()
    return pty


class _Modem:
    def __init__(self, name: str) -> None:
        self.name = name
        self.pty = make_pty()
        self.fd, self.path = self.pty.master_fd, self.pty.path
        self.buf = bytearray()
        self.role: str | None = None
        self.channel: int | None = None
        self.configured_at = 0.0
        self.queue: deque[bytes] = deque()
        self.received = 0
        self.commands: list[bytes] = []
        self.quiet_until = 0.0
        self.alive = True


class M64Pair:
    """Two Modem-M64s on ptys ("top" and "rov"), from the documented protocol."""

    def __init__(self, *, round_s=0.1, latency_s=0.05, sync_s=0.2, queue_depth=64) -> None:
        self.modems = {name: _Modem(name) for name in ("top", "rov")}
        self.round_s, self.latency_s, self.sync_s, self.queue_depth = round_s, latency_s, sync_s, queue_depth
        self.in_reach = True  # False: the modems cannot hear each other (search mode)
        self.delivered: list[tuple[str, bytes]] = []
        self._pending: list[tuple[float, _Modem, bytes]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def path(self, name: str) -> str:
        return self.modems[name].path

    def vanish(self, name: str) -> None:
        """The modem's USB adapter is pulled: its pty goes away."""
        m = self.modems[name]
        m.alive = False
        m.pty.down()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        for m in self.modems.values():
            if m.alive:
                m.alive = False
                m.pty.down()

    def link_up(self, now: float) -> bool:
        a, b = self.modems.values()
        return (self.in_reach and a.role is not None and b.role is not None and a.role != b.role
                and a.channel == b.channel and now >= max(a.configured_at, b.configured_at) + self.sync_s)

    # -- the thread --------------------------------------------------------------

    def _run(self) -> None:
        next_turn, turn = time.monotonic(), "a"
        while not self._stop.is_set():
            now = time.monotonic()
            fds = [m.fd for m in self.modems.values() if m.alive and now >= m.quiet_until]
            ready, _, _ = select.select(fds, [], [], 0.01)
            now = time.monotonic()
            for m in self.modems.values():
                if m.alive and m.fd in ready:
                    try:
                        m.buf += os.read(m.fd, 4096)
                    except OSError:  # EIO: nobody has the port open right now
                        m.quiet_until = now + 0.02
                    self._commands(m, now)
            if now >= next_turn:
                if self.link_up(now):
                    sender = next((m for m in self.modems.values() if m.role == turn), None)
                    other = next((m for m in self.modems.values() if m is not sender), None)
                    if sender is not None and sender.queue:
                        self._pending.append((now + self.latency_s, other, sender.queue.popleft()))
                turn = "b" if turn == "a" else "a"
                next_turn += self.round_s / 2
            for item in [p for p in self._pending if p[0] <= now]:
                self._pending.remove(item)
                _, to, payload = item
                if any(payload) and to.alive:  # all zeros: a sync packet, filtered by the receiver
                    to.received += 1
                    self.delivered.append((to.name, payload))
                    self._write(to, sentence(b"wrp,8," + payload))

    def _write(self, m: _Modem, data: bytes) -> None:
        try:
            os.write(m.fd, data)
        except OSError:
            pass

    def _reply(self, m: _Modem, cmd: bytes, *fields: bytes) -> None:
        body = b"wr" + cmd + b"".join(b"," + f for f in fields)
        self._write(m, sentence(body))

    def _commands(self, m: _Modem, now: float) -> None:
        buf = m.buf
        while True:
            start = buf.find(b"w")
            if start < 0:
                buf.clear()
                return
            del buf[:start]
            if len(buf) < 3:
                return
            if buf[1:2] != b"c":
                del buf[:1]
                self._reply(m, b"?")
                continue
            cmd = bytes(buf[2:3])
            if cmd == b"q":
                comma = buf.find(b",", 4)
                if comma < 0:
                    return
                size = int(buf[4:comma])
                end = comma + 1 + size
                nl = buf.find(b"\n", end)
                if nl < 0:
                    return
                payload, tail = bytes(buf[comma + 1:end]), bytes(buf[end:nl]).rstrip(b"\r")
                checked = bytes(buf[:end])
                del buf[:nl + 1]
                m.commands.append(b"wcq")
                if tail and tail != b"*%02x" % crc8(checked):
                    self._reply(m, b"!")
                elif size != 8 or len(m.queue) >= self.queue_depth:
                    self._reply(m, b"q", b"n")
                else:
                    m.queue.append(payload)
                    self._reply(m, b"q", b"a")
                continue
            nl = buf.find(b"\n")
            if nl < 0:
                return
            line = bytes(buf[:nl]).rstrip(b"\r")
            del buf[:nl + 1]
            if len(line) >= 6 and line[-3:-2] == b"*":
                line, csum = line[:-3], line[-2:]
                if csum != b"%02x" % crc8(line):
                    self._reply(m, b"!")
                    continue
            m.commands.append(line[:3])
            fields = line[4:].split(b",") if line[3:4] == b"," else []
            if cmd == b"v":
                self._reply(m, cmd, b"1", b"0", b"1")
            elif cmd == b"n":
                self._reply(m, cmd, b"8")
            elif cmd == b"c":
                self._reply(m, cmd, (m.role or "a").encode(), str(m.channel or 1).encode())
            elif cmd == b"s":
                if len(fields) == 2 and fields[0] in (b"a", b"b") and fields[1] in [b"%d" % c for c in range(1, 8)]:
                    m.role, m.channel, m.configured_at = fields[0].decode(), int(fields[1]), now
                    self._reply(m, cmd, b"a")
                else:
                    self._reply(m, cmd, b"n")
            elif cmd == b"l":
                self._reply(m, cmd, b"%d" % len(m.queue))
            elif cmd == b"f":
                m.queue.clear()
                self._reply(m, cmd, b"a")
            elif cmd == b"d":
                up = b"y" if self.link_up(now) else b"n"
                self._reply(m, cmd, up, b"%d" % m.received, b"0", b"0.0")
            else:
                self._reply(m, b"?")


@pytest.fixture
def pair():
    p = M64Pair()
    yield p
    p.close()


def link_states(caplog, url: str) -> list[str]:
    return [r.getMessage().split("acoustic link ")[1].split(" ")[0] for r in caplog.records
            if r.name == LOGGER and "acoustic link" in r.getMessage() and r.getMessage().startswith(url)]


def link_messages(caplog, state: str, url: str) -> list[str]:
    return [r.getMessage() for r in caplog.records
            if r.name == LOGGER and f"acoustic link {state}" in r.getMessage() and r.getMessage().startswith(url)]


# -- the responder speaks the documented protocol ---------------------------------


def test_the_checksum_reproduces_the_protocol_pages_examples_and_agrees_with_wlmodem():
    from wlmodem.protocol import WlProtocolParser

    documented = {b"wrv,1,0,1": 0x44, b"wrn,8": 0xBA, b"wrs,a": 0x01, b"wrq,a": 0xD7,
                  b"wrp,8,HelloTop": 0xBB, b"wrp,8,HelloSea": 0x58}
    parser = WlProtocolParser()
    for body, expected in documented.items():
        assert crc8(body) == expected
        assert parser.checksum_for_buffer(body) == b"*%02x" % expected


# -- URLs ----------------------------------------------------------------------------


def test_a_good_url_gives_an_endpoint_of_8_byte_frames():
    ep = open_wlmodem("wlmodem:///dev/ttyUSB0?role=A&channel=7&diag=0.5")
    assert isinstance(ep, WlModemEndpoint)
    assert (ep.path, ep.role, ep.channel, ep.baud, ep.diag_s) == ("/dev/ttyUSB0", "a", 7, 115200, 0.5)
    assert ep.max_frame == PACKET_BYTES == 8
    assert open_wlmodem("wlmodem:///dev/ttyUSB1?role=b").channel == 4


@pytest.mark.parametrize("url, says", [
    ("wlmodem:///dev/ttyUSB0", "needs ?role=a or ?role=b"),
    ("wlmodem:///dev/ttyUSB0?role=c", "role must be a or b"),
    ("wlmodem:///dev/ttyUSB0?role=a&channel=0", "channel must be 1-7"),
    ("wlmodem:///dev/ttyUSB0?role=a&channel=8", "channel must be 1-7"),
    ("wlmodem:///dev/ttyUSB0?role=a&channel=four", "channel must be 1-7"),
    ("wlmodem:///dev/ttyUSB0?role=a&baud=0", "baud must be a positive integer"),
    ("wlmodem:///dev/ttyUSB0?role=a&diag=often", "diag must be the seconds"),
    ("wlmodem:///dev/ttyUSB0?role=a&diag=0", "diag must be the seconds"),
    ("wlmodem:///dev/ttyUSB0?role=a&mtu=8", "unknown option(s) mtu"),
    ("wlmodem:///dev/ttyUSB0?role=a&role=b", "role given more than once"),
    ("wlmodem:///dev/ttyUSB0?role", "malformed query"),
    ("wlmodem://?role=a", "needs a serial device"),
    ("wlmodem://dev/ttyUSB0?role=a", "three slashes"),
    ("serial:///dev/ttyUSB0?role=a", "not a wlmodem:// URL"),
])
def test_bad_urls_are_refused_saying_why(url, says):
    with pytest.raises(TransportError) as err:
        open_wlmodem(url)
    assert says in str(err.value)
    assert "\n" not in str(err.value)


# -- ports that are not there or not modems ---------------------------------------------


def test_a_missing_port_is_said_once(caplog, tmp_path):
    path = tmp_path / "ttyUSB9"

    async def main():
        ep = open_wlmodem(f"wlmodem://{path}?role=a")
        with pytest.raises(TransportError) as err:
            await ep.start(timeout_s=0.3)
        assert str(err.value) == (f"wlmodem://{path}?role=a: could not open: no serial port {path} "
                                  "(is the modem's USB serial adapter plugged in?)")
        # Under the supervisor it is retried with backoff, and said once.
        ep = open_wlmodem(f"wlmodem://{path}?role=a")
        await ep.start(wait=False)
        await until(lambda: len(ep.stats.history) >= 4, what="four attempts to open")
        await ep.close()

    with caplog.at_level(logging.INFO):
        run(main())
    said = [r for r in caplog.records if str(path) in r.getMessage() and r.levelno >= logging.WARNING]
    assert len(said) == 1 and "no serial port" in said[0].getMessage()


def test_a_port_that_does_not_answer_is_no_modem():
    pty = make_pty()
    path = pty.path

    async def main():
        ep = open_wlmodem(f"wlmodem://{path}?role=a")
        with pytest.raises(TransportError) as err:
            await ep.start(timeout_s=1.2)
        return str(err.value)

    try:
        msg = run(main())
    finally:
        pty.down()
    assert f"no Water Linked modem answers on {path}" in msg


def test_a_modem_another_program_holds_is_refused_saying_so(pair):
    """One program per modem: a second console (or ROV) on a port in use is told at
    once, and never mixes its packets into the first one's link."""
    url = f"wlmodem://{pair.path('top')}?role=a&channel=3"

    async def main():
        first = open_wlmodem(url)
        await first.start()
        try:
            second = open_wlmodem(url)
            with pytest.raises(TransportError) as err:
                await second.start(timeout_s=1.0)
            assert str(err.value) == (f"{url}: could not open: {pair.path('top')} is in use: another program "
                                      f"holds it ({PORT_LOCKED})")
        finally:
            await first.close()
        again = open_wlmodem(url)  # released with the first's close
        await again.start()
        await again.close()

    run(main())


# -- a pair of modems ---------------------------------------------------------------


def test_two_modems_configure_link_up_and_carry_packets_both_ways(pair, caplog):
    top_url = f"wlmodem://{pair.path('top')}?role=a&channel=3&diag=0.05"
    rov_url = f"wlmodem://{pair.path('rov')}?role=b&channel=3&diag=0.05"
    down_to_rov = [b"order#%02d" % i for i in range(4)] + [b"w,*\n\r\x00\xffw"]  # bytes the framing uses
    up_to_top = [b"status%02d" % i for i in range(4)]

    async def main():
        top, rov = open_wlmodem(top_url), open_wlmodem(rov_url)
        await top.start()
        await rov.start()
        try:
            await until(lambda: top.link_up and rov.link_up, what="the acoustic link")
            for p in down_to_rov:
                assert top.send(p)
            for p in up_to_top:
                assert rov.send(p)
            got_rov = [await asyncio.wait_for(rov.recv(), 5) for _ in down_to_rov]
            got_top = [await asyncio.wait_for(top.recv(), 5) for _ in up_to_top]
            await until(lambda: top.modem_stats.diagnostic.get("pkt_cnt") == len(up_to_top), what="diagnostic")
            pair.in_reach = False  # out of reach: the modems lose each other
            await until(lambda: top.link_up is False and rov.link_up is False, what="the link to drop")
            pair.in_reach = True
            await until(lambda: top.link_up and rov.link_up, what="the link back")
            return got_rov, got_top, top, rov
        finally:
            await top.close()
            await rov.close()

    with caplog.at_level(logging.INFO, logger=LOGGER):
        got_rov, got_top, top, rov = run(main())
    assert got_rov == down_to_rov and got_top == up_to_top
    assert (pair.modems["top"].role, pair.modems["top"].channel) == ("a", 3)
    assert (pair.modems["rov"].role, pair.modems["rov"].channel) == ("b", 3)
    # Configured as the protocol page says: version, payload size, settings, flush.
    assert pair.modems["top"].commands[:4] == [b"wcv", b"wcn", b"wcs", b"wcf"]
    assert top.modem_stats.packets_queued == len(down_to_rov) and top.modem_stats.packets_received == len(up_to_top)
    assert top.stats.frames_sent == len(down_to_rov)
    assert top.modem_stats.parse_errors == rov.modem_stats.parse_errors == 0
    # The link's state is in the log, once per change: down while the modems
    # sync, up, down out of reach, up again.
    for url in (top_url, rov_url):
        assert link_states(caplog, url) == ["down", "up", "down", "up"]
    [first_up] = link_messages(caplog, "up", top_url)[:1]
    assert "role a, channel 3" in first_up


def test_packets_of_other_sizes_and_all_zeros_are_refused_without_hurting_the_link(pair):
    async def main():
        ep = open_wlmodem(f"wlmodem://{pair.path('top')}?role=a")
        await ep.start()
        try:
            for bad, says in [(b"1234567", "exactly 8 bytes, got 7"), (b"123456789", "exactly 8 bytes, got 9"),
                              (b"", "got 0"), (bytes(8), "all-zero packet")]:
                with pytest.raises(TransportError) as err:
                    ep.send(bad)
                assert says in str(err.value)
            assert ep.send(b"12345678")
            await until(lambda: ep.modem_stats.packets_queued == 1, what="the packet queued")
            return ep
        finally:
            await ep.close()

    ep = run(main())
    assert ep.stats.failures == 0 and ep.stats.opens == 1
    assert list(pair.modems["top"].queue) == [b"12345678"]


def test_a_full_modem_queue_refuses_packets_counted_and_said_once(caplog):
    # wlmodem waits 0.5 s for the modem's answer to each packet; a test process starved
    # of the CPU for longer (two browsers on the other worker) sees a late answer as a
    # refusal and the next request take it: the counts still add up, but the split and
    # the "once per run" may differ.  So: every attempt must add up, one of three must
    # show the modem's own answer exactly.
    def attempt():
        pair = M64Pair(queue_depth=2)  # the other modem is never configured: nothing leaves

        async def main():
            ep = open_wlmodem(f"wlmodem://{pair.path('top')}?role=a&diag=0.05")
            await ep.start()
            try:
                for i in range(5):
                    assert ep.send(b"packet-%d" % i)
                await until(lambda: ep.modem_stats.packets_queued + ep.modem_stats.packets_refused == 5)
                await until(lambda: ep.modem_stats.queue_length == 2, what="the queue length")
                return ep
            finally:
                await ep.close()

        caplog.clear()
        try:
            with caplog.at_level(logging.INFO, logger=LOGGER):
                ep = run(main())
        finally:
            pair.close()
        assert list(pair.modems["top"].queue) == [b"packet-0", b"packet-1"]
        refused = [r for r in caplog.records if "refused a packet" in r.getMessage()]
        return (ep.modem_stats.packets_queued, ep.modem_stats.packets_refused), len(refused)

    seen = []
    for _ in range(3):
        seen.append(attempt())
        if seen[-1] == ((2, 3), 1):
            break
    assert seen[-1] == ((2, 3), 1), seen


def test_flush_puts_a_packet_ahead_of_everything_queued(pair):
    async def main():
        pair.in_reach = False
        top = open_wlmodem(f"wlmodem://{pair.path('top')}?role=a&diag=0.05")
        rov = open_wlmodem(f"wlmodem://{pair.path('rov')}?role=b&diag=0.05")
        await top.start()
        await rov.start()
        try:
            for i in range(3):
                top.send(b"goto-%03d" % i)
            await until(lambda: len(pair.modems["top"].queue) == 3, what="three packets in the modem")
            assert top.flush() == 0  # none of ours was still waiting: the modem's three go with its wcf
            top.send(b"STOP!!!!")
            pair.in_reach = True
            got = await asyncio.wait_for(rov.recv(), 5)
            await asyncio.sleep(0.3)  # three more rounds: nothing else comes
            assert top.modem_stats.packets_flushed == 0
            return got, rov.recv_nowait()
        finally:
            await top.close()
            await rov.close()

    got, after = run(main())
    assert got == b"STOP!!!!" and after is None


def test_a_vanished_port_is_said_clearly_and_once(pair, caplog):
    path = pair.path("rov")
    url = f"wlmodem://{path}?role=b&diag=0.05"

    async def main():
        ep = open_wlmodem(url)
        await ep.start()
        try:
            pair.vanish("rov")
            await until(lambda: not ep.is_up, what="the transport to go down")
            await until(lambda: len(ep.stats.history) >= 5, what="attempts to reopen")
            assert not ep.send(b"12345678")  # down: counted, not queued
            return ep
        finally:
            await ep.close()

    with caplog.at_level(logging.INFO):
        ep = run(main())
    assert ep.stats.failures == 1 and ep.stats.dropped_while_down == 1
    said = [r.getMessage() for r in caplog.records if r.name == TRANSPORT_LOGGER and r.levelno >= logging.WARNING]
    assert said[0].startswith(f"{url}: modem port {path} failed")
    assert len(said) == 2, said  # the failure, then the reopening's failure once however often it is retried
    assert path in said[1] and ("no serial port" in said[1] or "cannot be opened" in said[1])


# -- wlmodem's own simulator, bridged onto a pty ------------------------------------------


class SimulatorOnPty:
    """wlmodem's WlModemSimulator answering on a pty: host sentences are read
    with wlmodem's parser, handed to the simulator's request(), and its answers
    (and the packets it hands back, one per `next_duration`) written back."""

    def __init__(self, **sim_kw) -> None:
        from wlmodem import WlModemSimulator
        from wlmodem.protocol import WlModemBase

        self.sim = WlModemSimulator(**sim_kw)
        self.pty = make_pty()
        self.fd, self.path = self.pty.master_fd, self.pty.path
        self.reader = WlModemBase(self)  # wlmodem's parser over this pty
        self._buf = bytearray()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    # the io device wlmodem's parser reads
    port = "simulator pty"

    @property
    def in_waiting(self) -> int:
        return len(self._buf)

    def read(self, n=1) -> bytes:
        data = bytes(self._buf[:n])
        del self._buf[:n]
        return data

    def _send(self, cmd: int, options) -> None:
        from wlmodem.protocol import DIR_RESP

        options = [bytes(o) if isinstance(o, (bytes, bytearray)) else str(o).encode() for o in options]
        try:
            os.write(self.fd, bytes(self.sim.parser.do_frame(cmd, DIR_RESP, options, checksum=True)))
        except OSError:
            pass

    def _run(self) -> None:
        from wlmodem.protocol import RESP_GOT_PACKET, WlProtocolParseError

        while not self._stop.is_set():
            ready, _, _ = select.select([self.fd], [], [], 0.01)
            if ready:
                try:
                    self._buf += os.read(self.fd, 4096)
                except OSError:
                    time.sleep(0.01)
            while self._buf:
                try:
                    msg = self.reader.get_packet()
                except WlProtocolParseError:
                    continue
                if msg is None:
                    break
                answer = self.sim.request(msg.cmd, msg.options)
                if answer is not None:
                    self._send(answer.cmd, answer.options or [])
            packet = self.sim.get_data_packet(timeout=0)
            if packet:
                self._send(RESP_GOT_PACKET, [b"8", packet])

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.pty.down()


def test_the_transport_against_wlmodems_simulator(caplog):
    # The simulator is one modem alone: what it is given comes back to it, one
    # packet per next_duration, once its link is "up" link_up_duration after
    # the configuration (3 s and 1 s by default; shortened here).
    bridge = SimulatorOnPty(link_up_duration=1.0, next_duration=0.05)
    url = f"wlmodem://{bridge.path}?role=a&channel=2&diag=0.1"
    packets = [b"simpkt%02d" % i for i in range(3)]

    async def main():
        ep = open_wlmodem(url)
        await ep.start()
        try:
            await until(lambda: ep.link_up is False, what="the link down after configuring")
            for p in packets:
                assert ep.send(p)
            await until(lambda: ep.modem_stats.queue_length == 3, what="three packets in the queue")
            await until(lambda: ep.link_up, what="the simulator's link up")
            got = [await asyncio.wait_for(ep.recv(), 5) for _ in packets]
            return got, ep
        finally:
            await ep.close()

    try:
        with caplog.at_level(logging.INFO, logger=LOGGER):
            got, ep = run(main())
    finally:
        bridge.close()
    assert got == packets
    assert ep.modem_stats.packets_queued == 3 and ep.stats.failures == 0
    assert [m.split(": ")[1].split(" (")[0] for m in (r.getMessage() for r in caplog.records)
            if "acoustic link" in m] == ["acoustic link down", "acoustic link up"]
