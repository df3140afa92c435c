"""Master and slave over the emulated channel, in simulated time."""

import dataclasses
import random

import pytest

from rovlink.link.emulators.channel import Channel, LinkParams
from rovlink.link.radio.frame import FrameDecoder, encode_frame
from rovlink.link.radio.master import (
    ImageComplete,
    ImageProgress,
    Master,
    OrderAcknowledged,
    OrderNotSent,
    PoseReceived,
    ReplyLost,
    RequestExpired,
    StopConfirmed,
)
from rovlink.link.radio.master import (
    OrderRejected as MasterOrderRejected,
)
from rovlink.link.radio.messages import (
    ImageSettings,
    Mode,
    Poll,
    Position,
    Reply,
    ReservedOrder,
    Stop,
    Velocity,
)
from rovlink.link.radio.sim import SimLink, accept_at_once
from rovlink.link.radio.slave import (
    ArmRequested,
    BrakeRequested,
    FailsafeCleared,
    FailsafeEntered,
    ImageWanted,
    ModeRequested,
    OrderDeclined,
    OrderExecuted,
    Slave,
    Status,
    VelocityCommanded,
    WishInvalid,
)

READY = Status(armed=True, mode=Mode.MANUAL, autopilot=True, position_valid=True, attitude_valid=True)


class Recorder:
    def __init__(self):
        self.master = []
        self.slave = []

    def m(self, e, now):
        self.master.append((now, e))

    def s(self, e, now):
        self.slave.append((now, e))

    def of(self, side, kind):
        return [e for _, e in getattr(self, side) if isinstance(e, kind)]


def make(ber=0.0, seed=0, source=None, loss=0.0, autopilot=accept_at_once, **master_kw):
    images = {}

    def default_source(img, settings):
        data = random.Random(f"{seed}-{img}-{len(images)}").randbytes(min(settings.budget_bytes, 1500))
        images.setdefault(img, []).append(data)
        return data

    master = Master(rng=random.Random(seed), **master_kw)
    slave = Slave(image_source=source or default_source)
    slave.update_status(READY)
    channel = Channel(LinkParams(ber=ber, loss=loss), seed=seed)
    rec = Recorder()
    sim = SimLink(master, slave, channel, on_master_event=rec.m, on_slave_event=rec.s, autopilot=autopilot)
    polls = []
    next_poll = master.next_poll

    def recording_next_poll(now):
        frame = next_poll(now)
        if frame is not None:
            polls.append((now, Poll.decode(FrameDecoder().feed(frame)[0])))
        return frame

    master.next_poll = recording_next_poll
    sim.polls = polls
    return sim, rec, images


def vehicle(sim, rec):
    """A fake autopilot behind the slave: brakes to POS_HOLD, arms and changes mode at once."""

    def on_slave(e, now):
        rec.s(e, now)
        st = sim.slave.status
        if isinstance(e, BrakeRequested):
            sim.slave.update_status(dataclasses.replace(st, mode=Mode.POS_HOLD))
        elif isinstance(e, ArmRequested):
            sim.slave.update_status(dataclasses.replace(st, armed=e.arm))
        elif isinstance(e, ModeRequested):
            sim.slave.update_status(dataclasses.replace(st, mode=e.mode))

    sim.on_slave_event = on_slave


def test_images_arrive_byte_exact_at_ber_1e_3():
    sim, rec, images = make(ber=1e-3, seed=3)
    sim.run_until(400)
    done = rec.of("master", ImageComplete)
    assert len(done) >= 3
    assert sim.channel.counters.corrupted > 20  # the channel really did damage frames
    assert sim.master.stats.replies_lost > 20
    for event in done:
        assert event.data in images[event.img]  # byte-exact against what the ROV encoded


def test_progress_is_a_growing_prefix_of_the_final_image():
    sim, rec, _ = make(ber=1e-4, seed=5)
    sim.run_until(60)
    done = rec.of("master", ImageComplete)[0]
    progress = [e for e in rec.of("master", ImageProgress) if e.img == done.img]
    sizes = [p.received_bytes for p in progress]
    assert sizes == sorted(sizes) and len(sizes) > 3
    for p in progress:
        assert done.data.startswith(p.prefix)


def count_executed(rec, kind):
    return sum(1 for e in rec.of("slave", OrderExecuted) if isinstance(e.order, kind))


@pytest.mark.parametrize("seed", range(6))
def test_one_shot_orders_run_exactly_once_across_losses(seed):
    # 30 % packet loss each way, plus bit errors: polls and replies vanish.
    sim, rec, _ = make(ber=1e-4, loss=0.3, seed=seed)
    ids = []
    for k in range(8):
        sim.at(2.0 + k * 0.7, lambda now, k=k: ids.append(sim.master.send_order(Position(100 * k, 0, 0, 0))))
    sim.run_until(200)
    executed = [e.order for e in rec.of("slave", OrderExecuted)]
    assert executed == [Position(100 * k, 0, 0, 0) for k in range(8)]  # once each, in order
    acked = [e.order_id for e in rec.of("master", OrderAcknowledged)]
    assert acked == ids
    assert sim.master.stats.replies_lost > 5
    assert sim.slave.stats.orders_repeated > 0  # a retransmitted poll was answered, not re-run


def test_first_poll_never_carries_a_one_shot_order():
    sim, rec, _ = make()
    sim.master.send_order(Stop())
    frame = sim.master.next_poll(0.0)
    poll = Poll.decode(FrameDecoder().feed(frame)[0])
    assert isinstance(poll.order, Velocity)


def test_orders_survive_a_restart_of_the_rov():
    sim, rec, _ = make(seed=2)
    sim.at(1.0, lambda now: sim.master.send_order(Position(1, 2, 3, 4)))
    sim.run_until(10)
    assert count_executed(rec, Position) == 1
    # The ROV restarts: a fresh slave with ACK 0.  Once the console has heard
    # from it (a reply from before the restart may still be in flight: with a
    # one-bit SEQ nothing can tell that window apart, see link.master), the
    # next order must run exactly once.
    sim.slave = Slave(image_source=sim.slave.image_source, now=sim.now)
    sim.slave.update_status(READY)
    replies = sim.slave.stats.replies_sent
    while sim.slave.stats.replies_sent == replies or sim.master.awaiting_reply:
        sim.run_until(sim.now + 0.05)
    sim.master.send_order(Position(5, 6, 7, 8))
    sim.run_until(sim.now + 20)
    # (1.1: STOP is no longer a sequenced order, so a second POSITION stands in for it.)
    assert [e.order for e in rec.of("slave", OrderExecuted)] == [Position(1, 2, 3, 4), Position(5, 6, 7, 8)]


def test_orders_survive_a_restart_of_the_console():
    sim, rec, _ = make(seed=4)
    sim.at(1.0, lambda now: sim.master.send_order(Position(1, 1, 1, 0)))
    sim.run_until(10)
    # The console restarts: a fresh master learns the ACK from the replies of
    # its first 3 s and must neither replay the order nor lose its own next one.
    # (1.1: STOP is not sequenced any more, so a POSITION stands in for it.)
    sim.master = Master(rng=random.Random(9))
    sim._master_ready_at = sim.now
    sim.master.send_order(Position(5, 5, 5, 0))
    sim.run_until(30)
    assert [e.order for e in rec.of("slave", OrderExecuted)] == [Position(1, 1, 1, 0), Position(5, 5, 5, 0)]


def test_stop_cancels_every_queued_order_which_is_shown_as_not_sent():
    # 1.1 (§3): a STOP cancels the pending order and every queued one, IMAGE
    # settings too (1.0 kept the IMAGE order); queued ones are shown as not sent.
    sim, rec, _ = make(seed=1)
    vehicle(sim, rec)
    sim.run_until(4)
    sim.master.send_order(Position(1, 0, 0, 0))
    sim.master.send_order(Position(2, 0, 0, 0))
    sim.master.send_order(ImageSettings(budget_bytes=500))
    stop_id = sim.master.send_order(Stop())
    sim.run_until(30)
    assert rec.of("slave", OrderExecuted) == []
    assert [e.order for e in rec.of("master", OrderNotSent)] == [
        Position(1, 0, 0, 0), Position(2, 0, 0, 0), ImageSettings(budget_bytes=500)
    ]
    assert [e.order_id for e in rec.of("master", StopConfirmed)] == [stop_id]
    assert not sim.master.stopping


def test_stop_abandons_the_order_in_progress_which_is_rejected_reason_1():
    # 1.1: STOP does not wait for the order in flight (1.0 did): the ROV abandons
    # it, its ACK flips with REJECTED, REASON 1, and the operator shows that.
    sim, rec, _ = make(seed=1, autopilot=lambda e, now: None)  # the autopilot never answers
    vehicle(sim, rec)
    sim.run_until(4)
    order_id = sim.master.send_order(Position(1, 0, 0, 0))
    while sim.slave.order_in_progress is None:
        sim.run_until(sim.now + 0.05)
    sim.master.send_order(Position(2, 0, 0, 0))
    sim.master.send_order(Stop())
    sim.run_until(30)
    rejected = rec.of("master", MasterOrderRejected)
    assert [(e.order_id, e.reason) for e in rejected] == [(order_id, 1)]
    assert [e.order for e in rec.of("master", OrderNotSent)] == [Position(2, 0, 0, 0)]
    assert rec.of("master", StopConfirmed)
    assert [e.why for e in rec.of("slave", BrakeRequested)][:1] == ["start"]
    assert "STOP" in [e.why for e in rec.of("slave", BrakeRequested)]


def test_velocity_is_soft_state_in_every_poll():
    sim, rec, _ = make()
    sim.at(1.0, lambda now: sim.master.set_velocity(30, -20, 10, 5, now))
    sim.run_until(10)
    commanded = [e.velocity for e in rec.of("slave", VelocityCommanded)]
    late = commanded[len(commanded) // 2:]
    assert late and all((v.vx, v.vy, v.vz, v.vyaw) == (30, -20, 10, 5) for v in late)
    assert sim.slave.velocity.vx == 30


def test_arm_request_rides_until_the_reply_shows_it_then_stops():
    sim, rec, _ = make()
    vehicle(sim, rec)
    sim.slave.update_status(dataclasses.replace(READY, armed=False))
    sim.at(1.0, lambda now: sim.master.request_arm(True, now))
    sim.run_until(10)
    arms = [p.order.arm for _, p in sim.polls if isinstance(p.order, Velocity)]
    assert 1 in arms
    assert arms[-1] == 0  # no longer requested once the reply showed ARMED
    assert [e.arm for e in rec.of("slave", ArmRequested)] == [True]  # acted on once: the change
    assert not rec.of("master", RequestExpired)


def test_unanswered_mode_request_expires():
    sim, rec, _ = make()
    sim.at(1.0, lambda now: sim.master.request_mode(Mode.GUIDED, now))
    sim.run_until(10)
    assert rec.of("master", RequestExpired)
    modes = [p.order.mode for _, p in sim.polls if isinstance(p.order, Velocity)]
    assert Mode.GUIDED in modes and modes[-1] == Mode.KEEP
    assert [e.mode for e in rec.of("slave", ModeRequested)] == [Mode.GUIDED]  # once, not every poll


def test_failsafe_trips_when_polls_stop_and_is_reported_when_they_return():
    sim, rec, _ = make()
    sim.at(1.0, lambda now: sim.master.set_velocity(100, 0, 0, 0, now))
    sim.run_until(5)
    assert sim.slave.velocity.vx == 100
    sim.master_down = True
    sim.run_until(12)
    entered = [(t, e) for t, e in rec.slave if isinstance(e, FailsafeEntered)]
    assert len(entered) == 1
    assert sim.slave.failsafe and sim.slave.velocity.is_neutral
    # 1.1 (§4): the ROV keeps its image through a failsafe (1.0 dropped it).
    assert sim.slave.held_img is not None
    sim.master_down = False
    sim._master_ready_at = sim.now
    sim.run_until(15)
    assert rec.of("slave", FailsafeCleared)
    replies = [e.reply for e in rec.of("master", PoseReceived)]
    assert any(r.failsafe for r in replies)  # the operator learns of it
    assert not replies[-1].failsafe
    # 1.1 (§5): the old wish (still full ahead) does not resume: HOLD until re-centred.
    assert replies[-1].hold and sim.slave.velocity.is_neutral
    sim.master.set_velocity(0, 0, 0, 0, sim.now)
    sim.run_until(16)
    assert not rec.of("master", PoseReceived)[-1].reply.hold
    sim.master.set_velocity(100, 0, 0, 0, sim.now)
    sim.run_until(17)
    assert sim.slave.velocity.vx == 100


def test_reserved_and_invalid_orders_are_answered_and_rejected_reason_0():
    # 1.1 (§3): a reserved order code consumes its SEQ: ACK flips with REJECTED, REASON 0
    # (1.0 answered and ignored it without a flip).
    slave = Slave(image_source=lambda img, s: b"x" * 10)
    out = slave.receive(Poll(seq=1, order=ReservedOrder(9, b"\x01\x02")).encode(), 0.0)
    reply = Reply.decode(FrameDecoder().feed(out.reply)[0])
    assert (reply.ack, reply.rejected, reply.reason) == (1, True, 0)
    assert isinstance(out.events[-1], OrderDeclined) and out.events[-1].reason == 0
    bad_velocity = bytes([0x01, 0x1F, 0xFF, 0x00, 0x80, 0, 0, 0])  # VX -128: an invalid wish
    out = slave.receive(bad_velocity, 0.1)
    assert out.reply is not None
    assert any(isinstance(e, WishInvalid) for e in out.events)
    assert slave.velocity.is_neutral and slave.ack == 1


def test_corrupted_polls_are_never_answered():
    slave = Slave()
    frame = bytearray(encode_frame(Poll(order=Velocity(10, 0, 0, 0)).encode()))
    frame[4] ^= 0x10
    out = slave.receive_bytes(bytes(frame), 0.0)
    assert out.reply is None and slave.velocity.is_neutral
    bad_header = encode_frame(bytes([0x40, 0, 0]))  # bit 6 set: CRC holds, header does not
    assert slave.receive_bytes(bad_header, 0.0).reply is None
    assert slave.stats.protocol_errors == 1


def test_image_wanted_until_the_node_hands_it_in():
    slave = Slave()  # no synchronous source: the node encodes in a worker
    out = slave.receive(Poll(img=3, offset=0).encode(), 0.0)
    assert any(isinstance(e, ImageWanted) and e.img == 3 for e in out.events)
    assert Reply.decode(FrameDecoder().feed(out.reply)[0]).trunk == b""
    assert slave.image_ready(3, b"stream")
    reply = Reply.decode(FrameDecoder().feed(slave.receive(Poll(img=3, offset=0, size=3).encode(), 0.1).reply)[0])
    assert reply.trunk == b"\x00\x06stream" and reply.first and reply.last
    assert not slave.image_ready(2, b"late")  # an image nobody asks for any more is refused


def test_image_settings_order_applies_to_the_next_image():
    seen = []

    def source(img, settings):
        seen.append(settings)
        return bytes(settings.budget_bytes)

    sim, rec, _ = make(source=source, seed=7)
    sim.run_until(3)
    sim.master.send_order(ImageSettings(roi=(10, 10, 50, 50), shift=6, mono=True, budget_bytes=300))
    sim.run_until(20)
    assert seen[-1] == ImageSettings(roi=(10, 10, 50, 50), shift=6, mono=True, budget_bytes=300)
    complete = rec.of("master", ImageComplete)
    assert complete and len(complete[-1].data) == 300


def test_steering_uses_small_trunks_and_idle_large_ones():
    sim, rec, _ = make()
    sim.run_until(20)
    idle_cycle = sim.master.stats.polls_sent
    sim.master.set_velocity(50, 0, 0, 0, sim.now)
    t0, n0 = sim.now, sim.master.stats.polls_sent
    sim.run_until(t0 + 20)
    steering_polls = sim.master.stats.polls_sent - n0
    assert steering_polls > 2 * idle_cycle  # a shorter cycle while steering


def test_size_adapts_to_a_bad_channel():
    sim, rec, _ = make(ber=1e-3, seed=11)
    sim.run_until(300)
    assert sim.master.estimated_ber() > 2e-4
    assert sim.master._choose_size(sim.now) < 3


def test_baseline_without_retransmission_loses_images():
    master = Master(rng=random.Random(0), retransmit=False, steering_size=1, idle_size=1)
    slave = Slave(image_source=lambda img, s: bytes(1998), trunk_cap=40)
    channel = Channel(LinkParams(ber=1e-4), seed=0)
    sim = SimLink(master, slave, channel)
    sim.run_until(300)
    assert master.stats.images_abandoned > master.stats.images_completed


def test_reply_lost_is_reported_after_the_timeout():
    master = Master(rng=random.Random(0))
    assert master.next_poll(0.0) is not None
    assert master.next_poll(0.1) is None  # the token is with the ROV
    deadline = master.deadline()
    assert master.next_poll(deadline + 0.001) is not None
    assert any(isinstance(e, ReplyLost) for e in master.take_events())
