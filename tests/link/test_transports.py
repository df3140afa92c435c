"""Transports with real sockets and real pseudo-terminals."""

import asyncio
import os
import random
import socket
import tempfile

import pytest

from rovlink.link.aio import run_channel, run_master, run_slave
from rovlink.link.emulators.channel import Channel, LinkParams
from rovlink.link.radio.frame import FrameDecoder, encode_frame
from rovlink.link.radio.master import ImageComplete, Master, PoseReceived, StopConfirmed
from rovlink.link.radio.messages import ImageSettings, Mode, Poll, Stop
from rovlink.link.radio.slave import BrakeRequested, OrderExecuted, Slave, Status
from rovlink.link.transports.transport import TransportError, free_udp_port, inproc_pair
from rovlink.link.transports.urls import open_transport

from ..helpers import Pty

HOLDING = Status(armed=True, mode=Mode.POS_HOLD, autopilot=True, position_valid=True, attitude_valid=True)


def run(coro, timeout=60):
    return asyncio.run(asyncio.wait_for(coro, timeout))


async def drive(master_ep, slave_ep, seconds, *, stream=b"s" * 300, order=None):
    master = Master(rng=random.Random(0), bitrate_bps=1e6, delay_s=0.0, margin_s=0.2, start_wait_s=0.2)
    slave = Slave(image_source=lambda img, s: stream)
    slave.update_status(HOLDING)
    got = {"poses": 0, "images": [], "executed": [], "stops": [], "confirmed": []}

    def on_master(events, now):
        for e in events:
            if isinstance(e, PoseReceived):
                got["poses"] += 1
            elif isinstance(e, ImageComplete):
                got["images"].append(e.data)
            elif isinstance(e, StopConfirmed):
                got["confirmed"].append(e)

    def on_slave(events, now):
        got["executed"] += [e.order for e in events if isinstance(e, OrderExecuted)]
        got["stops"] += [e for e in events if isinstance(e, BrakeRequested) and e.why == "STOP"]

    if order is not None:
        master.send_order(order)
    tasks = [asyncio.create_task(run_master(master, master_ep, on_master)),
             asyncio.create_task(run_slave(slave, slave_ep, on_slave))]
    await asyncio.sleep(seconds)
    for t in tasks:
        t.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    return got, master, slave


async def udp_pair(pm: int | None = None, ps: int | None = None):
    """Two started UDP endpoints on loopback, each the other's peer: (master's, ROV's),
    on the ports given (free ones otherwise)."""
    pm, ps = pm or free_udp_port(), ps or free_udp_port()
    m = open_transport(f"udp://127.0.0.1:{pm}?peer=127.0.0.1:{ps}")
    s = open_transport(f"udp://127.0.0.1:{ps}?peer=127.0.0.1:{pm}")
    await m.start()
    await s.start()
    return m, s


def test_udp_loopback_master_and_slave():
    async def main():
        m, s = await udp_pair()
        try:
            return await drive(m, s, 1.5, order=ImageSettings(budget_bytes=300))
        finally:
            await m.close()
            await s.close()

    got, master, slave = run(main())
    assert got["poses"] > 10
    assert got["images"] and got["images"][0] == b"s" * 300
    assert got["executed"] == [ImageSettings(budget_bytes=300)]


def test_over_a_fast_link_the_console_polls_no_sooner_than_its_floor_and_a_lost_reply_still_times_out():
    """docs/PROTOCOL.md §5 (decided): the console's loop starts a poll no sooner than
    CONSOLE_POLL_FLOOR_S after the one before.  Over UDP loopback a reply comes within a
    millisecond: without the floor the polls went a thousand a second."""
    from rovlink.link.aio import CONSOLE_POLL_FLOOR_S
    from rovlink.link.radio.events import PollSent, ReplyLost

    async def main():
        m, s = await udp_pair()
        master = Master(rng=random.Random(0), bitrate_bps=1e6, delay_s=0.0, margin_s=0.2)
        slave = Slave(image_source=lambda img, settings: b"s" * 300)
        slave.update_status(HOLDING)
        polls, lost, replies = [], [], [0]

        def on_master(events, now):
            polls.extend(now for e in events if isinstance(e, PollSent))
            lost.extend(now for e in events if isinstance(e, ReplyLost))
            replies[0] += sum(isinstance(e, PoseReceived) for e in events)

        tasks = [asyncio.create_task(run_master(master, m, on_master, poll_floor_s=CONSOLE_POLL_FLOOR_S)),
                 asyncio.create_task(run_slave(slave, s))]
        try:
            await asyncio.sleep(1.0)
            answered = replies[0]
            tasks[1].cancel()  # the ROV goes silent: the reply's timeout, not the floor, says lost
            await asyncio.sleep(0.6)
        finally:
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            await m.close()
            await s.close()
        return polls, lost, answered

    polls, lost, answered = run(main())
    gaps = [b - a for a, b in zip(polls, polls[1:])]
    assert answered >= 10 and len(polls) > 10, (answered, len(polls))
    assert min(gaps) >= CONSOLE_POLL_FLOOR_S - 1e-9, min(gaps)
    assert lost, "the silent ROV's replies were counted lost"


def test_udp_takes_datagrams_only_from_its_peer_so_a_second_sender_cannot_fake_a_stop_ack(caplog):
    """Issue 11: a second sender's polls flipped ACK so that STOP showed acknowledged and never ran."""

    async def main():
        ps = free_udp_port()  # the ROV's port: the intruder sends to it
        m, s = await udp_pair(ps=ps)
        intruder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        intruder.bind(("127.0.0.1", 0))
        stop_flag = asyncio.Event()

        async def inject():
            seq = 0
            while not stop_flag.is_set():
                # One-shot orders with alternating SEQ: each would flip ACK if taken.
                seq ^= 1
                poll = Poll(seq=seq, order=ImageSettings(budget_bytes=100 + seq), offset=8191)
                intruder.sendto(encode_frame(poll.encode()), ("127.0.0.1", ps))
                await asyncio.sleep(0.005)

        injector = asyncio.create_task(inject())
        try:
            got = await drive(m, s, 3.0, order=Stop())
        finally:
            stop_flag.set()
            await injector
            intruder.close()
            dropped = s.stats.foreign_dropped
            await m.close()
            await s.close()
        return got, dropped

    caplog.set_level("WARNING", logger="rovlink.link.transports.transport")
    (got, master, slave), dropped = run(main())
    assert dropped > 50  # counted and dropped
    logged = [r for r in caplog.records if "not the peer" in r.getMessage()]
    assert 1 <= len(logged) <= 4  # at most once a second over a 3 s run
    assert slave.ack == 0 and slave.stats.orders_executed == 0  # nothing of the intruder's was taken
    assert got["executed"] == []
    assert got["stops"]  # the real peer's STOP ran ...
    assert len(got["confirmed"]) == 1  # ... and was confirmed by a reply to a STOP poll
    assert got["poses"] > 10


def test_udp_needs_a_peer():
    with pytest.raises(TransportError, match="peer"):
        open_transport("udp://127.0.0.1:7000")


def test_udp_through_the_channel_process_model():
    """Master and slave on UDP, with the channel emulator between them (real time)."""

    async def main():
        ports = [free_udp_port() for _ in range(4)]
        m = open_transport(f"udp://127.0.0.1:{ports[0]}?peer=127.0.0.1:{ports[1]}")
        ca = open_transport(f"udp://127.0.0.1:{ports[1]}?peer=127.0.0.1:{ports[0]}")
        cb = open_transport(f"udp://127.0.0.1:{ports[2]}?peer=127.0.0.1:{ports[3]}")
        s = open_transport(f"udp://127.0.0.1:{ports[3]}?peer=127.0.0.1:{ports[2]}")
        for ep in (m, ca, cb, s):
            await ep.start()
        channel = Channel(LinkParams(bitrate_bps=200_000, delay_s=0.005, ber=1e-4), seed=1)
        ch = asyncio.create_task(run_channel(channel, ca, cb))
        try:
            got = await drive(m, s, 3.0, stream=bytes(range(256)) * 4)
        finally:
            ch.cancel()
            for ep in (m, ca, cb, s):
                await ep.close()
        return got, channel

    (got, master, slave), channel = run(main())
    assert channel.counters.delivered > 20
    assert got["images"] and all(img == bytes(range(256)) * 4 for img in got["images"])


def test_inproc_pair():
    async def main():
        a, b = inproc_pair()
        await a.start()
        await b.start()
        return await drive(a, b, 0.8, order=Stop())

    got, _, _ = run(main())
    assert got["poses"] > 5 and got["stops"] and len(got["confirmed"]) == 1


def test_serial_over_a_pty_with_crlf_survives_the_port_vanishing():
    async def main(tmp):
        pty = Pty(os.path.join(tmp, "ttyROV"))
        pty.up()
        ep = open_transport(f"serial://{pty.path}?baud=9600&crlf=1")
        await ep.start()
        try:
            assert ep.send(encode_frame(b"hello"))
            await asyncio.sleep(0.1)
            assert pty.read() == encode_frame(b"hello") + b"\r\n"
            pty.write(encode_frame(b"from the modem") + b"\r\n")
            data = await asyncio.wait_for(ep.recv(), 2)
            assert FrameDecoder().feed(data) == [b"from the modem"]

            pty.down()  # the USB adapter is pulled
            for _ in range(100):
                if not ep.is_up:
                    break
                ep.send(encode_frame(b"x"))
                await asyncio.sleep(0.02)
            assert not ep.is_up
            assert ep.send(encode_frame(b"lost")) is False
            assert ep.stats.dropped_while_down >= 1
            await asyncio.sleep(0.3)  # reopen attempts fail while it is gone

            pty.up()  # and plugged back in
            for _ in range(200):
                if ep.is_up:
                    break
                await asyncio.sleep(0.02)
            assert ep.is_up and ep.stats.opens >= 2
            assert ep.send(encode_frame(b"again"))
            await asyncio.sleep(0.1)
            assert encode_frame(b"again") + b"\r\n" in pty.read()
        finally:
            await ep.close()
            if pty.master_fd is not None:
                pty.down()

    with tempfile.TemporaryDirectory() as tmp:
        run(main(tmp))


def test_serial_port_absent_at_start_is_reported():
    async def main():
        ep = open_transport("serial:///nonexistent/ttyUSB9")
        with pytest.raises(TransportError, match="could not open"):
            await ep.start(timeout_s=0.3)
        await ep.close()

    run(main())


def test_a_port_that_fails_to_open_is_said_at_once_in_one_clear_line():
    """The first failed opening is the answer (not the last of a few seconds of retries),
    and its reason is said once, in words: not pyserial's "could not open port ...
    [Errno 2] ..." inside our own "could not open"."""
    async def main():
        ep = open_transport("serial:///nonexistent/ttyUSB9")
        with pytest.raises(TransportError) as err:
            await ep.start()  # its usual timeout: several retries' worth
        assert [h for h in ep.stats.history if h[1].startswith("down")] == [ep.stats.history[0]], ep.stats.history
        return str(err.value)

    said = run(main())
    assert said == ("serial:///nonexistent/ttyUSB9: could not open: no serial port /nonexistent/ttyUSB9 "
                    "(is the modem's USB serial adapter plugged in?)"), said


@pytest.mark.parametrize("url,words", [
    ("tcp://1.2.3.4:5", "unknown transport"),
    ("udp://127.0.0.1", "HOST:PORT"),
    ("udp://127.0.0.1:7000?peer=nowhere", "HOST:PORT"),
    ("udp://127.0.0.1:7000?peer=127.0.0.1:7001&color=red", "unknown option"),
    ("serial://", "device path"),
    ("serial:///dev/ttyS0?baud=fast", "baud"),
    ("serial:///dev/ttyS0?mtu=5", "mtu"),
])
def test_bad_urls_say_what_is_wrong(url, words):
    with pytest.raises(TransportError, match=words):
        open_transport(url)


def test_an_mtu_below_the_smallest_reply_is_refused_before_anything_starts():
    # mtu=20 passed here once and then crashed `rovlink rov` with a traceback in the slave.
    from rovlink.link.radio.messages import MIN_FRAME
    from rovlink.link.radio.slave import Slave

    with pytest.raises(TransportError, match=f"mtu must be a frame size of {MIN_FRAME}.."):
        open_transport(f"udp://127.0.0.1:0?peer=127.0.0.1:9&mtu={MIN_FRAME - 1}")
    endpoint = open_transport(f"udp://127.0.0.1:0?peer=127.0.0.1:9&mtu={MIN_FRAME}")
    assert endpoint.max_frame == MIN_FRAME
    Slave(image_source=lambda img, settings: b"", max_frame=endpoint.max_frame)  # the smallest the slave takes
