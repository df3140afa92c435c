"""The real wlmodem:// transport against emulated Modem-M64s (link/emulators/m64serial.py).

Two emulated modems on real pseudo-terminals, reached through the symlinks
the emulator makes, speak the Modem-M64 serial protocol to the transport
(link/transports/wlmodem.py, through the `wlmodem` library) and carry its packets through
the emulator's model (link/emulators/m64.py) in real time.  In-process tests use short
rounds; `rovlink channel --model m64` runs as the process a user starts, with
the model's real timing.  Tests wait on conditions with generous timeouts and
check behaviour, never how fast a loaded machine was.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import select
import signal
import subprocess
import sys
import time
import tty

import pytest

from rovlink.link.emulators.m64 import M64Loss, M64Params
from rovlink.link.emulators.m64serial import M64SerialError, M64SerialPair, take_sentence
from rovlink.link.transports.wlmodem import open_wlmodem

from ..helpers import run_async
from ..helpers import until as wait_until

ROVLINK = [sys.executable, "-m", "rovlink"]
LOGGER = "rovlink.link.emulators.m64serial"
WLMODEM_LOGGER = "rovlink.link.transports.wlmodem"
FAST = M64Params(round_s=0.1, b_offset_s=0.05, latency_s=0.15, sync_s=0.3)


def run(coro, timeout=30):
    return run_async(coro, timeout)


def until(cond, timeout=8.0, what="condition"):
    return wait_until(cond, timeout, what)


@pytest.fixture
def paths(tmp_path):
    return str(tmp_path / "op-modem"), str(tmp_path / "rov-modem")


@pytest.fixture
def records():
    return []


@pytest.fixture
def pair(paths, records):
    with M64SerialPair(*paths, params=FAST, log=records.append) as p:
        yield p


def endpoints(paths, *, top="role=a&channel=3", rov="role=b&channel=3"):
    return (open_wlmodem(f"wlmodem://{paths[0]}?{top}&diag=0.05"),
            open_wlmodem(f"wlmodem://{paths[1]}?{rov}&diag=0.05"))


# -- two transports through the emulated pair ----------------------------------------


def test_two_transports_carry_packets_both_ways_with_the_models_timing(pair, paths, records, caplog):
    down = [b"order#%02d" % i for i in range(5)] + [b"w,*\n\r\x00\xffw"]  # bytes the sentences use
    up = [b"status%02d" % i for i in range(6)]

    async def main():
        top, rov = endpoints(paths)
        await top.start()
        await rov.start()
        try:
            await until(lambda: top.link_up and rov.link_up, what="the acoustic link")
            sent_at = time.monotonic()
            for d, u in zip(down, up):
                assert top.send(d) and rov.send(u)
            got_rov, got_top = [], []
            for _ in down:
                got_rov.append((await asyncio.wait_for(rov.recv(), 10), time.monotonic()))
            for _ in up:
                got_top.append((await asyncio.wait_for(top.recv(), 10), time.monotonic()))
            # The modems' own counts, in their diagnostics; their queues drained.
            await until(lambda: top.modem_stats.diagnostic.get("pkt_cnt") == len(up)
                        and rov.modem_stats.diagnostic.get("pkt_cnt") == len(down), what="the diagnostics")
            await until(lambda: top.queue_length() == 0 and rov.queue_length() == 0, what="the queues drained")
            return sent_at, got_rov, got_top, top, rov
        finally:
            await top.close()
            await rov.close()

    with caplog.at_level(logging.INFO):
        sent_at, got_rov, got_top, top, rov = run(main())
    assert [p for p, _ in got_rov] == down and [p for p, _ in got_top] == up
    # Never sooner than the model's latency after the packet was handed over.
    assert all(t - sent_at >= FAST.latency_s for _, t in got_rov + got_top)
    # The model took the turns: one packet a round each way, role a's and role b's
    # turns apart, every packet sent once and delivered.
    tx = {d: [r["t"] for r in records if r["ev"] == "tx" and r["dir"] == d] for d in ("a>b", "b>a")}
    assert len(tx["a>b"]) == len(down) and len(tx["b>a"]) == len(up)
    for times in tx.values():
        assert all(later - earlier >= FAST.round_s - 1e-9 for earlier, later in zip(times, times[1:]))
    assert not set(tx["a>b"]) & set(tx["b>a"])
    assert pair.channel.counters.delivered == len(down) + len(up) and pair.channel.counters.lost == 0
    assert top.modem_stats.packets_queued == len(down) and top.modem_stats.parse_errors == 0
    assert rov.modem_stats.parse_errors == 0
    # The emulator said when the modems paired and when their link came up; the
    # transports saw it down, then up.
    said = [r.getMessage() for r in caplog.records if r.name == LOGGER]
    assert any("the modems are a pair" in m for m in said) and any("acoustic link up" in m for m in said)
    states = [r.getMessage().split("acoustic link ")[1].split(" ")[0] for r in caplog.records
              if r.name == WLMODEM_LOGGER and "acoustic link" in r.getMessage() and paths[0] in r.getMessage()]
    assert states == ["down", "up"]


def test_flush_puts_a_packet_ahead_of_everything_queued_and_queue_length_follows(pair, paths):
    async def main():
        top, rov = endpoints(paths)
        assert top.queue_length() is None  # not open
        await top.start()  # the ROV's modem is not configured yet: nothing leaves
        try:
            for i in range(3):
                assert top.send(b"goto-%03d" % i)
            assert top.queue_length() == 3  # at once: handed over, not yet counted by the modem
            await until(lambda: top.modem_stats.queue_length == 3, what="the modem's count of 3")
            assert top.queue_length() == 3
            top.flush()
            assert top.send(b"STOP!!!!")
            assert top.queue_length() == 1  # at once, before the modem has even flushed
            await until(lambda: top.modem_stats.queue_length == 1, what="the modem's count after the flush")
            await rov.start()
            got = await asyncio.wait_for(rov.recv(), 10)
            await until(lambda: top.queue_length() == 0, what="the queue drained")
            await asyncio.sleep(5 * FAST.round_s)  # rounds more: nothing else comes
            return got, rov.recv_nowait()
        finally:
            await top.close()
            await rov.close()

    got, after = run(main())
    assert got == b"STOP!!!!" and after is None
    assert pair.modems[0].counters.queued == 4 and pair.channel.counters.sent == 1


def test_a_full_modem_queue_naks_and_the_waiting_packets_leave_once_linked(paths, caplog):
    async def main(pair):
        top, rov = endpoints(paths)
        await top.start()
        try:
            for i in range(5):
                top.send(b"packet-%d" % i)
            await until(lambda: top.modem_stats.packets_queued + top.modem_stats.packets_refused == 5)
            await until(lambda: top.queue_length() == 3, what="the queue length")
            assert pair.modems[0].counters.refused == 2
            await rov.start()
            got = [await asyncio.wait_for(rov.recv(), 10) for _ in range(3)]
            return got, top
        finally:
            await top.close()
            await rov.close()

    with caplog.at_level(logging.INFO, logger=WLMODEM_LOGGER):
        with M64SerialPair(*paths, params=M64Params(round_s=0.1, b_offset_s=0.05, latency_s=0.15, sync_s=0.3,
                                                    queue_packets=3)) as pair:
            got, top = run(main(pair))
    assert got == [b"packet-0", b"packet-1", b"packet-2"]
    assert (top.modem_stats.packets_queued, top.modem_stats.packets_refused) == (3, 2)
    assert len([r for r in caplog.records if "refused a packet" in r.getMessage()]) == 1


def test_lost_packets_are_gone_counted_by_the_receiving_modem(paths):
    packets = [b"loss%04d" % i for i in range(16)]

    async def main(pair):
        top, rov = endpoints(paths)
        await top.start()
        await rov.start()
        try:
            for p in packets:
                top.send(p)
            c = pair.channel.counters
            await until(lambda: c.delivered + c.lost == len(packets), what="every packet delivered or lost")
            await until(lambda: rov.modem_stats.packets_received == c.delivered, what="the deliveries")
            await until(lambda: (rov.modem_stats.diagnostic.get("pkt_loss_cnt"), rov.modem_stats.diagnostic.get("pkt_cnt"))
                        == (c.lost, c.delivered), what="the modem's counts")
            got = []
            while (p := rov.recv_nowait()) is not None:
                got.append(p)
            return got, rov.modem_stats.diagnostic
        finally:
            await top.close()
            await rov.close()

    with M64SerialPair(*paths, params=FAST, a_to_b=M64Loss(0.5), b_to_a=M64Loss(0.0), seed=3) as pair:
        got, diag = run(main(pair))
    assert 0 < len(got) < len(packets)
    assert got == [p for p in packets if p in got]  # in order, never twice, nothing made up
    assert diag["pkt_cnt"] == len(got) and diag["pkt_loss_cnt"] == len(packets) - len(got)
    assert pair.modems[0].counters.lost == 0  # nothing was sent the other way


@pytest.mark.parametrize("top, rov, says", [
    ("role=a&channel=3", "role=b&channel=5", "modems on different channels never link"),
    ("role=a&channel=3", "role=a&channel=3", "two modems of the same role never link"),
    ("role=b&channel=3", "role=b&channel=3", "both modems have role b"),
])
def test_modems_configured_apart_never_link_and_the_log_says_why(pair, paths, caplog, top, rov, says):
    async def main():
        a, b = endpoints(paths, top=top, rov=rov)
        await a.start()
        await b.start()
        try:
            await until(lambda: a.link_up is False and b.link_up is False, what="both asked")
            a.send(b"anyone??")
            await asyncio.sleep(4 * FAST.sync_s)
            return a.link_up, b.link_up, b.recv_nowait()
        finally:
            await a.close()
            await b.close()

    with caplog.at_level(logging.INFO, logger=LOGGER):
        assert run(main()) == (False, False, None)
    assert not pair.paired and pair.channel.counters.sent == 0
    warned = [r.getMessage() for r in caplog.records if r.name == LOGGER and r.levelno == logging.WARNING]
    assert any(says in m for m in warned), warned


def test_a_pair_configured_the_other_way_round_links_too(pair, paths):
    async def main():
        top, rov = endpoints(paths, top="role=b&channel=7", rov="role=a&channel=7")
        await top.start()
        await rov.start()
        try:
            top.send(b"from-b!!")
            rov.send(b"from-a!!")
            return await asyncio.wait_for(rov.recv(), 10), await asyncio.wait_for(top.recv(), 10)
        finally:
            await top.close()
            await rov.close()

    assert run(main()) == (b"from-b!!", b"from-a!!")


# -- the serial protocol as the modem speaks it ------------------------------------------


class Port:
    """A host's raw view of an emulated modem's port."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)
        self.buf = b""

    def ask(self, data: bytes) -> bytes:
        os.write(self.fd, data)
        return self.line()

    def line(self, timeout=5.0) -> bytes:
        deadline = time.monotonic() + timeout
        while b"\n" not in self.buf:
            ready, _, _ = select.select([self.fd], [], [], max(0.0, deadline - time.monotonic()))
            if not ready:
                raise AssertionError(f"no answer; have {self.buf!r}")
            self.buf += os.read(self.fd, 4096)
        line, _, self.buf = self.buf.partition(b"\n")
        return line + b"\n"

    def close(self) -> None:
        os.close(self.fd)


def test_the_modem_answers_every_command_with_its_checksum(pair, paths):
    from wlmodem.protocol import WlProtocolParser

    port = Port(paths[0])
    parser = WlProtocolParser()
    payload = b"w,*\n\r\x00\xffw"
    queued = b"wcq,8," + payload
    try:
        dialogue = [
            (b"\nwcv\n", b"wrv,1,0,1*44\r\n"),  # the protocol page's own example and checksum
            (b"wcn\r\n", b"wrn,8*ba\r\n"),
            (b"wcc\n", None),
            (b"wcs,a,9\n", b"wrs,n"),
            (b"wcs,a,4*00\n", b"wr!"),
            (b"wcs,a,4*%02x\n" % parser.crc_func(b"wcs,a,4"), b"wrs,a*01\r\n"),
            (b"wcc\n", b"wrc,a,4"),
            (b"wcx\n", b"wr?"),
            (b"junk\nwcv,\n", b"wrv,1,0,1*44\r\n"),
            (queued + b"\n", b"wrq,a*d7\r\n"),
            (queued + parser.checksum_for_buffer(queued) + b"\r\n", b"wrq,a"),
            (queued + b"*00\n", b"wr!"),
            (b"wcq,7,1234567\n", b"wrq,n"),
            (b"wcq,8,\x00\x00\x00\x00\x00\x00\x00\x00\n", b"wrq,a"),  # a sync packet: taken, never sent
            (b"wcl\n", b"wrl,2"),
            (b"wcd\n", b"wrd,n,0,0,0.0"),
            (b"wcf\n", b"wrf,a"),
            (b"wcl\n", b"wrl,0"),
        ]
        for ask, expected in dialogue:
            answer = port.ask(ask)
            assert answer.endswith(b"\r\n"), answer
            body = answer[:-2]
            parser.parse(body)  # raises on a wrong checksum: the modem always sends a right one
            assert body[-3:-2] == b"*"
            if expected is not None:
                assert answer.startswith(expected), (ask, answer)
        assert port.ask(b"wcc\n").startswith(b"wrc,a,4")
    finally:
        port.close()
    assert pair.modems[0].counters.bad_checksums == 2 and pair.modems[0].counters.zero_packets == 1


def test_take_sentence_waits_for_whole_sentences_and_binary_payloads():
    buf = bytearray(b"wcq,8,\n\n\n\n\n\n\n")
    assert take_sentence(buf) is None  # 7 of the 8 payload bytes
    buf += b"\n\n"
    assert take_sentence(buf) == ("q", [b"8", b"\n" * 8]) and buf == b""
    buf += b"wcs,b,2"
    assert take_sentence(buf) is None
    buf += b"\r\nwcl\nwr"
    assert take_sentence(buf) == ("s", [b"b", b"2"])
    assert take_sentence(buf) == ("l", [])
    assert take_sentence(buf) is None
    buf += b"v\n" + b"x" * 200
    assert take_sentence(buf) == "?"  # a modem's sentence sent to the modem
    assert take_sentence(buf) is None and buf == b""  # noise without a w


def test_a_packet_that_arrives_while_the_port_is_closed_is_not_left_for_the_next_opener(pair, paths):
    async def main():
        top, rov = endpoints(paths)
        await top.start()
        await rov.start()
        try:
            await until(lambda: top.link_up and rov.link_up, what="the link")
            await rov.close()
            top.send(b"unheard!")
            await until(lambda: pair.modems[1].counters.received == 1, what="the packet at the closed port")
            rov = open_wlmodem(f"wlmodem://{paths[1]}?role=b&channel=3&diag=0.05")
            await rov.start()
            top.send(b"heard!!!")
            return await asyncio.wait_for(rov.recv(), 10)
        finally:
            await top.close()
            await rov.close()

    assert run(main()) == b"heard!!!"
    assert pair.modems[1].counters.written_while_closed == 1


# -- the ports' paths ----------------------------------------------------------------------


def test_each_modem_is_a_symlink_to_a_pty_removed_on_close(paths):
    with M64SerialPair(*paths, params=FAST) as pair:
        for path, m in zip(paths, pair.modems):
            assert os.path.islink(path) and os.readlink(path) == m.pty and m.pty.startswith("/dev/pts/")
        # A second emulator on the same paths is refused: the ptys are in use.
        with pytest.raises(M64SerialError, match="a pseudo-terminal in use"):
            M64SerialPair(*paths).start()
        assert os.path.islink(paths[0])  # and it left them alone
    assert not os.path.lexists(paths[0]) and not os.path.lexists(paths[1])


def test_paths_that_are_not_ours_are_refused_and_a_stale_link_is_replaced(tmp_path, paths):
    taken = tmp_path / "a-file"
    taken.write_text("mine")
    with pytest.raises(M64SerialError) as err:
        M64SerialPair(str(taken), paths[1]).start()
    assert "exists and is not a link this emulator made" in str(err.value) and taken.read_text() == "mine"
    assert not os.path.lexists(paths[1])
    other = tmp_path / "other-link"
    other.symlink_to(taken)
    with pytest.raises(M64SerialError, match="not one this emulator made"):
        M64SerialPair(str(other), paths[1]).start()
    with pytest.raises(M64SerialError, match="no such folder"):
        M64SerialPair(str(tmp_path / "nowhere" / "modem"), paths[1]).start()
    with pytest.raises(M64SerialError, match="two paths"):
        M64SerialPair(paths[0], paths[0])
    os.symlink("/dev/pts/987654", paths[0])  # left by an emulator that was killed
    with M64SerialPair(*paths) as pair:
        assert os.readlink(paths[0]) == pair.modems[0].pty


# -- rovlink channel --model m64, as a user runs it -------------------------------------------


def test_rovlink_channel_m64_carries_packets_between_two_real_transports(tmp_path, paths):
    log = tmp_path / "m64.jsonl"
    proc = subprocess.Popen(ROVLINK + ["channel", "--model", "m64", "--a", f"pty:{paths[0]}", "--b", f"pty:{paths[1]}",
                                       "--seed", "1", "--log", str(log)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    down, up = [b"goto-001", b"goto-002"], [b"status01", b"status02"]

    async def main():
        top = open_wlmodem(f"wlmodem://{paths[0]}?role=a&channel=2&diag=0.2")
        rov = open_wlmodem(f"wlmodem://{paths[1]}?role=b&channel=2&diag=0.2")
        await top.start()
        await rov.start()
        try:
            for d, u in zip(down, up):
                top.send(d)
                rov.send(u)
            got_rov = [await asyncio.wait_for(rov.recv(), 20) for _ in down]
            got_top = [await asyncio.wait_for(top.recv(), 20) for _ in up]
            return got_rov, got_top, top.link_up
        finally:
            await top.close()
            await rov.close()

    try:
        banner = proc.stderr.readline()  # printed once both modems are there
        assert banner.startswith("channel: M64 emulator: modem A at "), banner
        got_rov, got_top, up_seen = run(main(), timeout=60)
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=15)
    assert (got_rov, got_top, up_seen) == (down, up, True)
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    assert "the modems are a pair" in err and "acoustic link up" in err
    assert "channel: done: m64: sent 4 delivered 4 lost 0" in err.splitlines()[-1]
    events = [json.loads(line) for line in log.read_text().splitlines()]
    kinds = {(e["ev"], e.get("dir")) for e in events}
    assert {("tx", "a>b"), ("rx", "a>b"), ("tx", "b>a"), ("rx", "b>a")} <= kinds
    assert not os.path.lexists(paths[0]) and not os.path.lexists(paths[1])


@pytest.mark.parametrize("args, status, says", [
    (["--model", "m64", "--a", "udp://127.0.0.1:1?peer=127.0.0.1:2", "--b", "pty:/tmp/x"], 2, "--a pty:PATH"),
    (["--model", "m64", "--a", "pty:/tmp/x", "--b", "pty:"], 2, "pty: needs the path"),
    (["--model", "m64", "--a", "pty:/tmp/x", "--b", "pty:/tmp/x"], 2, "the same path"),
    (["--model", "m64", "--a", "pty:/tmp/x", "--b", "pty:/tmp/y", "--bitrate", "1000", "--full-duplex"], 2,
     "--bitrate, --full-duplex: radio options"),
    (["--model", "m64", "--a", "pty:/tmp/x", "--b", "pty:/tmp/y", "--loss", "0.75", "--burst", "2"], 2,
     "the burst must be at least 3.00 packets"),
    (["--model", "m64", "--a", "pty:/tmp/x", "--b", "pty:/tmp/y", "--burst", "0.5"], 2, "at least 1 packet"),
    (["--model", "m64", "--a", "pty:/nonexistent-folder/x", "--b", "pty:/tmp/y"], 1, "no such folder"),
    (["--model", "m64", "--a", "pty:/etc/passwd", "--b", "pty:/tmp/y"], 1, "exists and is not a link"),
    (["--model", "sonar", "--a", "pty:/tmp/x", "--b", "pty:/tmp/y"], 2, "invalid choice"),
    (["--a", "pty:/tmp/x", "--b", "udp://127.0.0.1:1?peer=127.0.0.1:2"], 2, "use it with --model m64"),
])
def test_bad_channel_arguments_give_one_line(args, status, says):
    out = subprocess.run(ROVLINK + ["channel"] + args, capture_output=True, text=True, timeout=60)
    assert out.returncode == status, out.stderr
    assert len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert "error:" in out.stderr and says in out.stderr, out.stderr
