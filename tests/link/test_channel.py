"""The channel emulator: timing, errors, loss, queue, collisions, seeds, log."""

import io
import json

import pytest

from rovlink.link.emulators.channel import Channel, LinkParams


def test_serialisation_and_delay_set_the_arrival_time():
    ch = Channel(LinkParams(bitrate_bps=1900, delay_s=0.085, propagation_s=0.01))
    ch.send("a", bytes(100), 1.0)
    expected = 1.0 + 0.085 + 800 / 1900 + 0.01
    assert ch.next_time() == pytest.approx(expected)
    assert ch.deliver(expected - 1e-6) == []
    [d] = ch.deliver(expected)
    assert d.to == "b" and d.data == bytes(100)


def test_transmit_queue_is_fifo_and_drops_when_full():
    ch = Channel(LinkParams(bitrate_bps=1000, delay_s=0, queue_bytes=250))
    assert ch.send("a", bytes(100), 0.0)
    assert ch.send("a", bytes(100), 0.0)
    assert not ch.send("a", bytes(100), 0.0)  # 300 bytes would not fit
    assert ch.counters.dropped_queue == 1
    times = []
    while ch.next_time() is not None:
        t = ch.next_time()
        times += [d.at for d in ch.deliver(t)]
    assert times == pytest.approx([0.8, 1.6])  # the second waits for the first


def test_bit_errors_flip_real_bits_at_the_given_rate():
    ch = Channel(LinkParams(bitrate_bps=1e9, delay_s=0, ber=1e-3), seed=5)
    flipped = 0
    n = 2000
    for i in range(n):
        ch.send("a", bytes(100), float(i))
        for d in ch.deliver(float(i) + 1):
            flipped += sum(bin(b).count("1") for b in d.data)
    assert flipped == ch.counters.bits_flipped
    expected = n * 800 * 1e-3
    assert 0.85 * expected < flipped < 1.15 * expected


def test_packet_loss_rate():
    ch = Channel(LinkParams(bitrate_bps=1e9, delay_s=0, loss=0.25), seed=2)
    got = 0
    for i in range(4000):
        ch.send("b", b"x", float(i))
        got += len(ch.deliver(float(i) + 1))
    assert 0.7 < got / 4000 < 0.8
    assert ch.counters.lost == 4000 - got


def test_half_duplex_collision_loses_overlapping_frames():
    ch = Channel(LinkParams(bitrate_bps=1000, delay_s=0))
    ch.send("a", bytes(100), 0.0)  # on the air 0..0.8
    ch.send("b", bytes(100), 0.4)  # b talks while a's frame is arriving
    assert ch.deliver(10.0) == []
    assert ch.counters.collisions == 2


def test_full_duplex_has_no_collisions():
    ch = Channel(LinkParams(bitrate_bps=1000, delay_s=0), half_duplex=False)
    ch.send("a", bytes(100), 0.0)
    ch.send("b", bytes(100), 0.4)
    assert len(ch.deliver(10.0)) == 2


def test_same_seed_same_run():
    def run(seed):
        ch = Channel(LinkParams(ber=1e-3, loss=0.1), seed=seed)
        out = []
        for i in range(200):
            ch.send("a", bytes(range(50)), i * 2.0)
            out += [d.data for d in ch.deliver(i * 2.0 + 1.9)]
        return out

    assert run(7) == run(7)
    assert run(7) != run(8)


def test_log_has_every_event_with_its_time():
    buf = io.StringIO()
    ch = Channel(LinkParams(bitrate_bps=1000, delay_s=0, ber=0.01, queue_bytes=100), seed=1, log=buf)
    ch.send("a", bytes(60), 0.0)
    ch.send("a", bytes(60), 0.0)  # dropped: queue full
    ch.deliver(5.0)
    events = [json.loads(line) for line in buf.getvalue().splitlines()]
    assert [e["ev"] for e in events] == ["tx", "drop", "corrupt", "rx"]
    assert events[-1]["t"] == pytest.approx(0.48)


@pytest.mark.parametrize("kw", [dict(bitrate_bps=0), dict(ber=1.0), dict(loss=-0.1), dict(delay_s=-1),
                                dict(queue_bytes=0)])
def test_bad_parameters_raise(kw):
    with pytest.raises(ValueError):
        LinkParams(**kw)
