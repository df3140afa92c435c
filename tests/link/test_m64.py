"""The emulator's Modem-M64: 8-byte packets, one a second each way in turns,
1.5-2.5 s latency, a few seconds to sync, a finite queue, loss and bursts."""

from __future__ import annotations

import asyncio
import io
import json
from types import SimpleNamespace

import pytest

from rovlink.link.aio import run_channel
from rovlink.link.emulators.m64 import M64Channel, M64Loss, M64Params
from rovlink.link.radio.sim import SimLink
from rovlink.link.transports.transport import inproc_pair


def packet(i: int) -> bytes:
    return b"P" + i.to_bytes(7, "big")


def number(data: bytes) -> int:
    return int.from_bytes(data[1:], "big")


def drain(ch: M64Channel, until: float = float("inf")):
    out = []
    while (t := ch.next_time()) is not None and t <= until:
        out += ch.deliver(t)
    return out


# -- what it accepts ---------------------------------------------------------------


@pytest.mark.parametrize("data, says", [(b"1234567", "exactly 8 bytes, got 7"), (b"123456789", "exactly 8 bytes, got 9"),
                                        (b"", "got 0"), (bytes(8), "all-zero packet")])
def test_only_8_byte_packets_that_are_not_all_zero(data, says):
    ch = M64Channel()
    with pytest.raises(ValueError) as err:
        ch.send("a", data, 0.0)
    assert says in str(err.value)
    with pytest.raises(ValueError):
        ch.send("c", packet(1), 0.0)
    assert ch.counters.sent == 0 and ch.next_time() is None


@pytest.mark.parametrize("kw", [dict(round_s=0), dict(b_offset_s=1.0), dict(b_offset_s=0), dict(queue_packets=0),
                                dict(latency_s=-1)])
def test_impossible_timings_are_refused(kw):
    with pytest.raises(ValueError):
        M64Params(**kw)


def test_a_burst_too_short_for_the_loss_asked_is_refused():
    M64Loss(loss=0.5, burst=1.0)  # every other packet, in bursts of one: possible
    with pytest.raises(ValueError, match="at least 3.00 packets"):
        M64Loss(loss=0.75, burst=2.0)
    with pytest.raises(ValueError):
        M64Loss(loss=0.1, burst=0.5)


# -- timing ------------------------------------------------------------------------


def test_the_link_takes_a_few_seconds_to_establish():
    ch = M64Channel(start=0.0)  # sync_s = 3 s
    assert not ch.is_up(2.9) and ch.is_up(3.0)
    ch.send("a", packet(1), 0.0)
    ch.send("b", packet(2), 0.0)
    got = drain(ch)
    # a's first turn at 3.0, b's at 3.5, each arriving 1.5 s after its turn
    assert [(d.to, number(d.data), d.at) for d in got] == [("b", 1, 4.5), ("a", 2, 5.0)]


def test_one_packet_a_second_each_way_is_64_bits_per_second():
    ch = M64Channel(M64Params(sync_s=1.0), start=0.0)
    n = 30
    for i in range(n):
        assert ch.send("a", packet(i), 0.0)
        assert ch.send("b", packet(100 + i), 0.0)
    got = drain(ch)
    for to, first in (("b", 2.5), ("a", 3.0)):  # a's turns from 1.0, b's from 1.5, each arriving 1.5 s later
        times = [d.at for d in got if d.to == to]
        assert [number(d.data) % 100 for d in got if d.to == to] == list(range(n))  # FIFO
        assert times == pytest.approx([first + k for k in range(n)])  # one a second
        bits_per_s = 8 * 8 * (n - 1) / (times[-1] - times[0])
        assert bits_per_s == pytest.approx(64.0)


def test_latency_is_the_documented_1_5_to_2_5_seconds():
    ch = M64Channel(seed=3, start=0.0)  # up at 3.0
    latencies = []
    t = 10.0
    for i in range(300):
        t += 2.618 + (i % 7) * 0.377  # one at a time, at every phase of the round
        ch.send("a" if i % 2 else "b", packet(i), t)
        [d] = drain(ch, t + 3.0)
        latencies.append(d.at - t)
    assert min(latencies) >= 1.5 - 1e-9 and max(latencies) <= 2.5 + 1e-9
    assert min(latencies) < 1.55 and max(latencies) > 2.45  # the whole range is used
    assert sum(latencies) / len(latencies) == pytest.approx(2.0, abs=0.05)


def test_the_two_roles_take_turns_and_never_send_at_once():
    log = []
    ch = M64Channel(M64Params(sync_s=1.0), start=0.0, log=log.append)
    for i in range(10):
        ch.send("a", packet(i), 0.0)
        ch.send("b", packet(i), 0.0)
    drain(ch)
    tx = [(r["t"], r["dir"]) for r in log if r["ev"] == "tx"]
    assert [d for _, d in tx] == ["a>b", "b>a"] * 10  # turns alternate
    assert [t for t, _ in tx] == pytest.approx([1.0 + k * 0.5 for k in range(20)])  # half a round apart
    assert all(r["arrival"] - r["t"] == pytest.approx(1.5) for r in log if r["ev"] == "tx")


def test_a_side_alone_still_waits_for_its_own_turn():
    ch = M64Channel(M64Params(sync_s=0.0), start=0.0)
    ch.send("b", packet(1), 0.1)  # b's turns: 0.5, 1.5, ...
    ch.send("b", packet(2), 0.1)
    assert [d.at for d in drain(ch)] == pytest.approx([2.0, 3.0])


# -- queue ---------------------------------------------------------------------------


def test_a_full_transmit_queue_drops_what_does_not_fit():
    out = io.StringIO()
    ch = M64Channel(M64Params(queue_packets=128), start=0.0, log=out)
    accepted = [ch.send("a", packet(i), 0.0) for i in range(130)]
    assert accepted == [True] * 128 + [False] * 2
    assert ch.counters.dropped_queue == 2 and ch.queue_length("a") == 128
    assert not ch.send("a", packet(999), 2.9)  # the link is not up yet: nothing has left
    ch.deliver(3.0)  # a's first turn
    assert ch.queue_length("a") == 127 and ch.send("a", packet(1000), 3.2)
    drops = [json.loads(line) for line in out.getvalue().splitlines() if '"drop"' in line]
    assert len(drops) == 3 and drops[0]["why"] == "queue full"


def test_flush_puts_the_next_packet_first():
    ch = M64Channel(M64Params(sync_s=0.0), start=0.0)
    for i in range(5):
        ch.send("a", packet(i), 0.1)
    assert ch.flush("a", 0.2) == 5
    ch.send("a", b"STOP!!!!", 0.2)
    assert [d.data for d in drain(ch)] == [b"STOP!!!!"]


def test_a_lost_link_loses_what_is_on_its_way_and_resumes_after_sync():
    ch = M64Channel(M64Params(sync_s=3.0), start=0.0)
    for i in range(4):
        ch.send("a", packet(i), 0.0)
    got = ch.deliver(4.9)  # turns at 3 and 4: the first arrived at 4.5, the second arrives at 5.5
    assert [number(d.data) for d in got] == [0]
    ch.drop_link(4.9)
    assert not ch.is_up(7.8) and ch.is_up(7.9)
    rest = drain(ch)
    assert [number(d.data) for d in rest] == [2, 3]  # packet 1 was on its way: lost
    assert [d.at for d in rest] == pytest.approx([9.4, 10.4])
    assert ch.counters.lost == 1 and ch.counters.links_dropped == 1


# -- loss ------------------------------------------------------------------------------


def _send_many(ch: M64Channel, n: int) -> list[int]:
    """n packets a>b, one per round (a queue that never runs dry); the numbers received."""
    got = []
    for i in range(n):
        ch.send("a", packet(i), float(i))
        got += [number(d.data) for d in ch.deliver(float(i) + 0.9)]
    got += [number(d.data) for d in drain(ch)]
    return got


def _bursts(got: list[int], n: int) -> list[int]:
    received = set(got)
    runs, run = [], 0
    for i in range(n):
        if i in received:
            if run:
                runs.append(run)
            run = 0
        else:
            run += 1
    return runs + ([run] if run else [])


def test_random_loss_takes_the_fraction_asked():
    n = 20000
    ch = M64Channel(M64Params(sync_s=0.0), M64Loss(loss=0.1), seed=11)
    got = _send_many(ch, n)
    assert got == sorted(got)
    assert 1 - len(got) / n == pytest.approx(0.1, abs=0.01)
    assert ch.counters.lost == n - len(got) and ch.counters.delivered == len(got)
    runs = _bursts(got, n)
    assert sum(runs) / len(runs) == pytest.approx(1 / 0.9, abs=0.05)  # independent: short runs


def test_bursts_have_the_mean_length_asked():
    n = 40000
    ch = M64Channel(M64Params(sync_s=0.0), M64Loss(loss=0.1, burst=5.0), seed=7)
    got = _send_many(ch, n)
    runs = _bursts(got, n)
    assert 1 - len(got) / n == pytest.approx(0.1, abs=0.015)
    assert sum(runs) / len(runs) == pytest.approx(5.0, rel=0.1)
    assert ch.counters.bursts == pytest.approx(len(runs), abs=1)


def test_each_direction_has_its_own_loss():
    ch = M64Channel(M64Params(sync_s=0.0), a_to_b=M64Loss(loss=1.0), b_to_a=M64Loss(loss=0.0), seed=1)
    for i in range(20):
        ch.send("a", packet(i), float(i))
        ch.send("b", packet(i), float(i))
    got = drain(ch)
    assert {d.to for d in got} == {"a"} and len(got) == 20


def test_a_seed_reproduces_a_run_and_the_log_is_json_lines():
    def once(seed):
        out = io.StringIO()
        ch = M64Channel(M64Params(sync_s=0.0), M64Loss(loss=0.3, burst=2.0), seed=seed, log=out)
        return _send_many(ch, 500), out.getvalue()

    (got1, log1), (got2, log2), (got3, _) = once(5), once(5), once(6)
    assert got1 == got2 and log1 == log2 and got1 != got3
    events = {json.loads(line)["ev"] for line in log1.splitlines()}
    assert {"link", "queue", "tx", "rx", "loss"} <= events


# -- the drivers use it unchanged ---------------------------------------------------------


class EightByteMaster:
    """A stand-in for link.master: one 8-byte poll at a time, the next when answered."""

    def __init__(self) -> None:
        self.n = 0
        self.sent_at: dict[int, float] = {}
        self.round_trips: list[float] = []
        self.waiting = False

    def next_poll(self, now):
        if self.waiting:
            return b""
        self.n += 1
        self.waiting = True
        self.sent_at[self.n] = now
        return b"poll" + self.n.to_bytes(4, "big")

    def take_events(self):
        return []

    def deadline(self):
        return self.sent_at[self.n] + 30.0 if self.waiting else None  # give up after 30 s (never, here)

    def receive_bytes(self, data, now):
        assert data[:4] == b"rply"
        self.round_trips.append(now - self.sent_at[int.from_bytes(data[4:], "big")])
        self.waiting = False
        return []


class EchoSlave:
    failsafe_at = None

    def receive_bytes(self, data, now):
        return SimpleNamespace(events=[], reply=b"rply" + data[4:])

    def tick(self, now):
        return []


def test_simlink_drives_it_unchanged():
    master = EightByteMaster()
    sim = SimLink(master, EchoSlave(), M64Channel(seed=0))
    sim.run_until(120.0)
    assert len(master.round_trips) >= 20
    first, *rest = master.round_trips
    assert 3.0 + 3.0 <= first <= 3.0 + 5.0  # the first waited for the link (3 s)
    # There and back: each way 1.5-2.5 s.  (Here every poll leaves just after
    # the master's turn and every reply just after the slave's: the worst case.)
    assert all(3.0 <= rtt <= 5.0 for rtt in rest)


def test_run_channel_drives_it_in_real_time():
    fast = M64Params(round_s=0.1, b_offset_s=0.05, latency_s=0.05, sync_s=0.1)

    async def main():
        a_user, a_chan = inproc_pair("m64-a")
        b_user, b_chan = inproc_pair("m64-b")
        for ep in (a_user, a_chan, b_user, b_chan):
            await ep.start()
        task = asyncio.create_task(run_channel(M64Channel(fast), a_chan, b_chan))
        try:
            for i in range(3):
                a_user.send(packet(i))
                b_user.send(packet(10 + i))
            got_b = [await asyncio.wait_for(b_user.recv(), 5) for _ in range(3)]
            got_a = [await asyncio.wait_for(a_user.recv(), 5) for _ in range(3)]
            return got_a, got_b
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            for ep in (a_user, a_chan, b_user, b_chan):
                await ep.close()

    got_a, got_b = asyncio.run(asyncio.wait_for(main(), 20))
    assert got_b == [packet(i) for i in range(3)] and got_a == [packet(10 + i) for i in range(3)]
