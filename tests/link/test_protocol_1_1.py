"""docs/PROTOCOL.md 1.1, rule by rule, on the sans-I/O machines with a fake clock."""

import dataclasses
import random

import pytest

from rovlink.link.emulators.channel import Channel, LinkParams
from rovlink.link.radio.frame import FrameDecoder, encode_frame
from rovlink.link.radio.master import (
    ImageAbandoned,
    ImageComplete,
    ImageProgress,
    Master,
    OrderAcknowledged,
    OrderCancelled,
    OrderNotSent,
    PoseReceived,
    RequestExpired,
    StopConfirmed,
    StopNotCarriedOut,
)
from rovlink.link.radio.master import (
    OrderRejected as MasterRejected,
)
from rovlink.link.radio.messages import (
    NO_IMAGE_DATA,
    Arm,
    ImageSettings,
    Mode,
    NoOrder,
    Poll,
    Position,
    Reply,
    ReservedOrder,
    Stop,
    Velocity,
)
from rovlink.link.radio.sim import SimLink
from rovlink.link.radio.slave import (
    ArmRequested,
    BrakeRequested,
    FailsafeCleared,
    FailsafeEntered,
    ImageWanted,
    ModeRequested,
    OrderAbandoned,
    OrderDeclined,
    OrderExecuted,
    OrderStarted,
    Slave,
    Status,
    VelocityCommanded,
    WishInvalid,
)

READY = Status(armed=True, mode=Mode.MANUAL, autopilot=True, position_valid=True, attitude_valid=True)
TARGET = Position(100, 200, 300, 0)


def ready_slave(**kw):
    slave = Slave(**kw)
    slave.update_status(READY)
    return slave


def send(slave, poll, now):
    """One poll in; (reply or None, events)."""
    payload = poll.encode() if isinstance(poll, Poll) else poll
    out = slave.receive(payload, now)
    reply = Reply.decode(FrameDecoder().feed(out.reply)[0]) if out.reply else None
    return reply, out.events


def of(events, kind):
    return [e for e in events if isinstance(e, kind)]


def centred(slave, now=0.0):
    """Past the start hold: a neutral VELOCITY."""
    return send(slave, Poll(order=Velocity()), now)


# ---------------------------------------------------------------------------
# The ROV: start, HOLD, ARM/MODE, the wish
# ---------------------------------------------------------------------------


def test_rov_brakes_and_holds_at_start():
    slave = ready_slave()
    reply, events = send(slave, Poll(), 0.0)
    assert [(e.why, e.hold) for e in of(events, BrakeRequested)] == [("start", True)]
    assert reply.hold and reply.ack == 0 and not reply.rejected


def test_hold_ignores_a_moving_wish_until_a_neutral_one():
    slave = ready_slave()
    reply, events = send(slave, Poll(order=Velocity(60, 0, 0, 0)), 0.0)
    assert of(events, VelocityCommanded)[0].velocity.is_neutral and reply.hold
    reply, _ = send(slave, Poll(order=Velocity(0, 0, 0, 0)), 0.1)
    assert not reply.hold
    _, events = send(slave, Poll(order=Velocity(60, 0, 0, 0)), 0.2)
    assert of(events, VelocityCommanded)[0].velocity.vx == 60


def test_arm_and_mode_act_only_when_they_change_and_the_first_velocity_only_sets_the_reference():
    slave = ready_slave()
    _, events = send(slave, Poll(order=Velocity(arm=Arm.ARM, mode=Mode.MANUAL)), 0.0)
    assert not of(events, ArmRequested) and not of(events, ModeRequested)  # a request in flight at start
    _, events = send(slave, Poll(order=Velocity(arm=Arm.ARM, mode=Mode.MANUAL)), 0.1)
    assert not of(events, ArmRequested)  # repeated: no change
    send(slave, Poll(order=Velocity()), 0.2)  # the operator returns the fields to 0
    _, events = send(slave, Poll(order=Velocity(arm=Arm.ARM, mode=Mode.STABILIZE)), 0.3)
    assert [e.arm for e in of(events, ArmRequested)] == [True]
    assert [e.mode for e in of(events, ModeRequested)] == [Mode.STABILIZE]
    for t in (0.4, 0.5, 0.6):  # the soft state repeats it: never acted on again
        _, events = send(slave, Poll(order=Velocity(arm=Arm.ARM, mode=Mode.STABILIZE)), t)
        assert not of(events, ArmRequested) and not of(events, ModeRequested)


def test_hold_does_not_change_the_arm_rule():
    slave = ready_slave()
    send(slave, Poll(order=Velocity(50, 0, 0, 0)), 0.0)  # reference, still held
    _, events = send(slave, Poll(order=Velocity(50, 0, 0, 0, arm=Arm.ARM)), 0.1)
    assert [e.arm for e in of(events, ArmRequested)] == [True] and slave.hold


def test_disarm_acts_whenever_it_arrives_also_first_after_a_stop():
    slave = ready_slave()
    centred(slave)
    send(slave, Poll(order=Stop()), 0.1)
    _, events = send(slave, Poll(order=Velocity(arm=Arm.DISARM)), 0.2)
    assert [e.arm for e in of(events, ArmRequested)] == [False]
    _, events = send(slave, Poll(order=Velocity(arm=Arm.DISARM)), 0.3)
    assert [e.arm for e in of(events, ArmRequested)] == [False]


def test_a_stop_resets_the_reference():
    slave = ready_slave()
    centred(slave)
    send(slave, Poll(order=Stop()), 0.1)
    _, events = send(slave, Poll(order=Velocity(mode=Mode.MANUAL)), 0.2)
    assert not of(events, ModeRequested)  # first VELOCITY after the STOP: reference only


@pytest.mark.parametrize("body,why", [
    (bytes([0x00, 0x80, 0, 0, 0]), "-128"),
    (bytes([0xC0, 0, 0, 0, 0]), "ARM 3"),
    (bytes([0x07, 0, 0, 0, 0]), "MODE 7"),
])
def test_an_invalid_wish_is_neutral_acts_on_nothing_and_does_not_feed_the_failsafe(body, why):
    slave = ready_slave()
    centred(slave, 0.0)
    send(slave, Poll(order=Velocity(40, 0, 0, 0)), 0.1)
    reply, events = send(slave, bytes([0x01, 0x1F, 0xFF]) + body, 2.0)
    assert why in of(events, WishInvalid)[0].why
    assert slave.velocity.is_neutral and not reply.rejected and reply.ack == 0
    assert not of(events, ArmRequested) and not of(events, ModeRequested)
    assert slave.silent_for(2.0) == pytest.approx(1.9)  # the timer still counts from 0.1
    assert of(slave.tick(3.1), FailsafeEntered)


def test_an_invalid_wish_neither_sets_the_reference_nor_re_centres():
    slave = ready_slave()
    send(slave, bytes([0x01, 0x1F, 0xFF, 0x07, 0, 0, 0, 0]), 0.0)  # MODE 7, axes zero
    assert slave.hold  # not counted as re-centring
    _, events = send(slave, Poll(order=Velocity(mode=Mode.MANUAL)), 0.1)
    assert not of(events, ModeRequested)  # this one is the first valid VELOCITY: reference only


def test_velocity_lapses_after_1_5_s_without_a_valid_velocity_and_keeps_the_reference():
    slave = ready_slave()
    centred(slave, 0.0)
    send(slave, Poll(order=Velocity(50, 0, 0, 0, mode=Mode.MANUAL)), 0.1)
    send(slave, Poll(), 1.0)  # NONE polls feed the failsafe but carry no wish
    assert slave.tick(1.5) == [] and slave.velocity.vx == 50
    events = slave.tick(1.6)
    assert [e.velocity.is_neutral for e in of(events, VelocityCommanded)] == [True]
    assert not slave.failsafe and not slave.hold
    _, events = send(slave, Poll(order=Velocity(50, 0, 0, 0, mode=Mode.MANUAL)), 1.7)
    assert not of(events, ModeRequested) and slave.velocity.vx == 50  # same reference, no new HOLD


def test_a_position_target_stands_while_wishes_are_zero_and_a_moving_wish_replaces_it():
    slave = ready_slave()
    centred(slave)
    _, events = send(slave, Poll(seq=1, order=TARGET), 0.1)
    token = of(events, OrderStarted)[0].token
    slave.order_outcome(token, True, None, 0.2)
    assert slave.standing == "position"
    _, events = send(slave, Poll(seq=1, order=Velocity()), 0.3)
    assert not of(events, VelocityCommanded)[0].replaces_target and slave.standing == "position"
    _, events = send(slave, Poll(seq=1, order=Velocity(0, 30, 0, 0)), 0.4)
    assert of(events, VelocityCommanded)[0].replaces_target and slave.standing is None


def test_a_mode_request_acted_on_ends_the_standing_brake_an_arm_request_does_not():
    slave = ready_slave()
    centred(slave)
    send(slave, Poll(order=Stop()), 0.1)
    send(slave, Poll(order=Velocity()), 0.2)  # re-centred; the brake stands
    send(slave, Poll(order=Velocity(arm=Arm.ARM)), 0.3)
    assert slave.standing == "brake"
    send(slave, Poll(order=Velocity(mode=Mode.MANUAL)), 0.4)
    assert slave.standing is None


# ---------------------------------------------------------------------------
# The ROV: one-shot orders, ACK, REJECTED, REASON
# ---------------------------------------------------------------------------


def test_structural_faults_are_counted_and_never_answered():
    slave = ready_slave()
    for payload in (
        bytes([0x45, 0, 0]),  # HELLO bit in 1.1
        bytes([0x05, 0, 0]) + bytes(10),  # reserved order body over 9 bytes
        bytes([0x02, 0, 0]) + bytes(8),  # POSITION body of 8
        bytes([0x04, 0, 0, 1]),  # STOP with a body
    ):
        assert slave.receive(payload, 0.0).reply is None
    assert slave.stats.protocol_errors == 4 and slave.stats.polls == 0


def test_a_reserved_order_is_rejected_reason_0_and_consumes_its_seq():
    slave = ready_slave()
    reply, events = send(slave, Poll(seq=1, order=ReservedOrder(12, b"\x01" * 9)), 0.0)
    assert (reply.ack, reply.rejected, reply.reason) == (1, True, 0)
    assert [e.reason for e in of(events, OrderDeclined)] == [0]
    reply, events = send(slave, Poll(seq=1, order=ReservedOrder(12, b"\x01" * 9)), 0.1)
    assert not of(events, OrderDeclined) and reply.rejected  # a repeat: answered, not taken again


@pytest.mark.parametrize("body", [
    bytes([0x40]) + bytes(8),  # BODY without RELATIVE
    bytes([0x00]) + bytes(6) + (18001).to_bytes(2, "big"),  # YAW out of range
])
def test_an_invalid_position_is_rejected_reason_0_and_does_not_feed_the_failsafe(body):
    slave = ready_slave()
    reply, events = send(slave, bytes([0x82, 0x1F, 0xFF]) + body, 1.0)
    assert (reply.ack, reply.rejected, reply.reason) == (1, True, 0)
    assert not of(events, OrderStarted)
    assert slave.silent_for(1.0) == 1.0


def test_an_invalid_image_order_is_rejected_reason_0():
    slave = ready_slave()
    roi = ((50 << 30) | (10 << 20) | (40 << 10) | 20).to_bytes(5, "big")  # X1 <= X0
    reply, _ = send(slave, bytes([0x83, 0x1F, 0xFF]) + roi + bytes([0, 0x01, 0x00]), 0.0)
    assert (reply.ack, reply.rejected, reply.reason) == (1, True, 0)
    assert slave.settings.budget_bytes == 2000  # unchanged


@pytest.mark.parametrize("status,why", [
    (dataclasses.replace(READY, autopilot=False), "no autopilot"),
    (dataclasses.replace(READY, position_valid=False), "no position estimate"),
    (dataclasses.replace(READY, armed=False), "disarmed"),
])
def test_a_position_impossible_now_is_rejected_reason_1(status, why):
    slave = Slave()
    slave.update_status(status)
    reply, events = send(slave, Poll(seq=1, order=TARGET), 0.0)
    assert (reply.ack, reply.rejected, reply.reason) == (1, True, 1)
    assert of(events, OrderDeclined)[0].why == why and not of(events, OrderStarted)


def test_ack_flips_when_the_autopilot_accepts_and_the_order_is_never_started_twice():
    slave = ready_slave()
    reply, events = send(slave, Poll(seq=1, order=TARGET), 0.0)
    assert reply.ack == 0  # outcome not known yet
    token = of(events, OrderStarted)[0].token
    reply, events = send(slave, Poll(seq=1, order=TARGET), 0.3)  # the operator repeats the poll
    assert reply.ack == 0 and not of(events, OrderStarted)
    assert of(slave.order_outcome(token, True, None, 0.5), OrderExecuted)
    reply, _ = send(slave, Poll(seq=1, order=TARGET), 0.6)
    assert (reply.ack, reply.rejected) == (1, False)


def test_an_autopilot_refusal_is_reason_2_and_no_answer_in_2_s_too():
    slave = ready_slave()
    _, events = send(slave, Poll(seq=1, order=TARGET), 0.0)
    slave.order_outcome(of(events, OrderStarted)[0].token, False, None, 0.5)
    reply, _ = send(slave, Poll(seq=1), 0.6)
    assert (reply.ack, reply.rejected, reply.reason) == (1, True, 2)
    _, events = send(slave, Poll(seq=0, order=TARGET), 1.0)
    assert of(events, OrderStarted)
    assert slave.tick(2.9) == []
    events = slave.tick(3.0)
    assert of(events, OrderAbandoned) and [e.reason for e in of(events, OrderDeclined)] == [2]
    reply, _ = send(slave, Poll(seq=0), 3.1)
    assert (reply.ack, reply.rejected, reply.reason) == (0, True, 2)


def test_rejected_and_reason_describe_the_order_named_by_ack_until_the_next_flip():
    slave = ready_slave()
    send(slave, Poll(seq=1, order=ReservedOrder(7)), 0.0)
    for t in (0.1, 0.2):
        reply, _ = send(slave, Poll(seq=1, order=Velocity()), t)
        assert reply.rejected and reply.reason == 0
    reply, _ = send(slave, Poll(seq=0, order=ImageSettings(budget_bytes=500)), 0.3)
    assert (reply.ack, reply.rejected, reply.reason) == (0, False, 0)


def test_the_same_seq_with_another_order_supersedes_the_order_in_progress():
    slave = ready_slave()
    _, events = send(slave, Poll(seq=1, order=TARGET), 0.0)
    old = of(events, OrderStarted)[0].token
    _, events = send(slave, Poll(seq=1, size=3, order=TARGET, img=3, offset=0), 0.1)
    assert not of(events, OrderStarted)  # IMG, OFFSET and SIZE do not count
    other = Position(1, 1, 1, 0)
    reply, events = send(slave, Poll(seq=1, order=other), 0.2)
    assert reply.ack == 0  # no flip for the abandoned one
    assert [e.token for e in of(events, OrderAbandoned)] == [old]
    new = of(events, OrderStarted)[0]
    assert new.order == other
    slave.order_outcome(new.token, True, None, 0.3)
    reply, _ = send(slave, Poll(seq=1, order=other), 0.4)
    assert (reply.ack, reply.rejected) == (1, False)
    # The superseded one accepted late: a newer POSITION was taken since, so no brake.
    assert slave.order_outcome(old, True, None, 0.5) == []


def test_stop_is_not_sequenced_abandons_the_order_in_progress_reason_1_and_sets_hold():
    slave = ready_slave()
    centred(slave)
    _, events = send(slave, Poll(seq=1, order=TARGET), 0.1)
    token = of(events, OrderStarted)[0].token
    reply, events = send(slave, Poll(seq=0, order=Stop()), 0.2)  # STOP carries SEQ = ACK
    assert (reply.ack, reply.rejected, reply.reason, reply.hold) == (1, True, 1, True)
    assert [e.token for e in of(events, OrderAbandoned)] == [token]
    assert [(e.why, e.hold) for e in of(events, BrakeRequested)] == [("STOP", True)]
    reply, events = send(slave, Poll(seq=1, order=Stop()), 0.3)  # acts on every poll, never flips
    assert reply.ack == 1 and of(events, BrakeRequested)
    reply, events = send(slave, Poll(seq=0, order=Stop()), 0.4)
    assert reply.ack == 1 and of(events, BrakeRequested)
    # A late accept of the abandoned order: brake as for STOP, without HOLD.
    send(slave, Poll(seq=1, order=Velocity()), 0.5)
    assert not slave.hold
    events = slave.order_outcome(token, True, None, 0.6)
    assert [(e.why, e.hold) for e in events] == [("late accept", False)] and not slave.hold


def test_a_refusal_of_an_abandoned_order_changes_nothing():
    slave = ready_slave()
    _, events = send(slave, Poll(seq=1, order=TARGET), 0.0)
    send(slave, Poll(seq=0, order=Stop()), 0.1)
    assert slave.order_outcome(of(events, OrderStarted)[0].token, False, 2, 0.2) == []
    assert (slave.ack, slave.reason) == (1, 1)


# ---------------------------------------------------------------------------
# The ROV: failsafe
# ---------------------------------------------------------------------------


def test_failsafe_abandons_brakes_reports_then_holds_until_re_centred_and_keeps_the_image():
    slave = ready_slave(image_source=lambda img, s: bytes(300), failsafe_s=1.0)  # shorter than the 2 s wait
    centred(slave, 0.0)
    send(slave, Poll(seq=0, size=0, order=Velocity(80, 0, 0, 0), img=2, offset=0), 0.5)
    _, events = send(slave, Poll(seq=1, order=TARGET), 1.0)
    assert of(events, OrderStarted)
    assert slave.tick(1.9) == []
    events = slave.tick(2.0)
    assert of(events, FailsafeEntered) and [e.reason for e in of(events, OrderDeclined)] == [1]
    assert slave.velocity.is_neutral and slave.hold and slave.standing == "brake"
    assert slave.held_img == 2
    reply, events = send(slave, Poll(seq=1, order=Velocity(80, 0, 0, 0), img=2, offset=24), 9.0)
    assert reply.failsafe and reply.hold and (reply.ack, reply.reason) == (1, 1)
    assert of(events, FailsafeCleared) and of(events, VelocityCommanded)[0].velocity.is_neutral
    assert reply.offset == 24  # the image held before the failsafe is still served
    reply, _ = send(slave, Poll(seq=1, order=Velocity(80, 0, 0, 0)), 9.1)
    assert not reply.failsafe and reply.hold and slave.velocity.is_neutral
    reply, _ = send(slave, Poll(seq=1, order=Velocity()), 9.2)
    assert not reply.hold


def test_only_a_poll_that_decodes_completely_clears_the_failsafe():
    slave = ready_slave()
    slave.tick(5.0)
    assert slave.failsafe
    reply, events = send(slave, bytes([0x01, 0x1F, 0xFF, 0, 0x80, 0, 0, 0]), 5.1)
    assert reply.failsafe and slave.failsafe and not of(events, FailsafeCleared)
    reply, events = send(slave, Poll(seq=1, order=ReservedOrder(6)), 5.2)
    assert slave.failsafe  # rejected REASON 0: does not feed the timer either
    _, events = send(slave, Poll(), 5.3)
    assert of(events, FailsafeCleared) and not slave.failsafe


# ---------------------------------------------------------------------------
# The ROV: images
# ---------------------------------------------------------------------------


def test_offset_8191_and_budget_0_never_start_a_capture():
    calls = []
    slave = ready_slave(image_source=lambda img, s: calls.append(img) or bytes(100))
    reply, events = send(slave, Poll(img=1, offset=NO_IMAGE_DATA), 0.0)
    assert not reply.has_trunk and not calls and slave.held_img is None
    send(slave, Poll(seq=1, order=ImageSettings(budget_bytes=0), img=1, offset=0), 0.1)
    reply, _ = send(slave, Poll(seq=1, img=1, offset=0), 0.2)
    assert not reply.has_trunk and not calls


def test_a_nonzero_offset_of_an_image_not_held_is_a_new_capture_sent_from_offset_0():
    slave = ready_slave()  # the node encodes: nothing is ready at once
    reply, events = send(slave, Poll(size=0, img=4, offset=500), 0.0)  # e.g. after a ROV restart
    assert of(events, ImageWanted) and not reply.has_trunk
    reply, events = send(slave, Poll(size=0, img=4, offset=500), 0.1)  # being encoded counts as held
    assert not of(events, ImageWanted) and not reply.has_trunk
    assert slave.image_ready(4, bytes(range(200)))
    reply, _ = send(slave, Poll(size=0, img=4, offset=500), 0.2)
    assert reply.first and reply.offset == 0 and reply.trunk[:2] == (200).to_bytes(2, "big")
    reply, _ = send(slave, Poll(size=0, img=4, offset=24), 0.3)
    assert reply.offset == 24 and not reply.first


def test_an_offset_at_or_past_the_end_of_the_image_held_is_a_new_capture():
    captures = []

    def source(img, settings):
        captures.append(img)
        return bytes([len(captures)]) * 50

    slave = ready_slave(image_source=source)
    reply, _ = send(slave, Poll(size=3, img=5, offset=0), 0.0)
    assert reply.last and len(reply.trunk) == 52
    reply, _ = send(slave, Poll(size=3, img=5, offset=52), 0.1)
    assert captures == [5, 5] and reply.first and reply.trunk[2] == 2


def test_the_rov_receive_len_cap_is_the_largest_poll():
    slave = ready_slave()
    assert slave.decoder.max_len == 12
    out = slave.receive_bytes(encode_frame(bytes([0x00, 0x1F, 0xFF]) + bytes(10)), 0.0)
    assert out.reply is None and slave.decoder.counters.oversize == 1


# ---------------------------------------------------------------------------
# The operator
# ---------------------------------------------------------------------------


def reply_frame(**kw):
    return encode_frame(Reply(**kw).encode())


def polls_of(master, now):
    frame = master.next_poll(now)
    return Poll.decode(FrameDecoder().feed(frame)[0]) if frame else None


def answer(master, now, **kw):
    return master.receive_bytes(reply_frame(**kw), now)


def started_master(**kw):
    """A master that has heard its first reply at 0 and is past the 3 s start rule at 3.0."""
    master = Master(rng=random.Random(0), first_img=0, **kw)
    polls_of(master, 0.0)
    answer(master, 0.01, mode=Mode.MANUAL, autopilot=True)
    return master


def test_operator_sends_no_one_shot_order_until_3_s_after_its_first_reply_but_stop_at_once():
    master = Master(rng=random.Random(0))
    master.send_order(TARGET)
    assert isinstance(polls_of(master, 0.0).order, Velocity)  # no reply yet
    answer(master, 0.1, ack=1)
    for t in (0.2, 1.0, 3.0):
        poll = polls_of(master, t)
        assert isinstance(poll.order, Velocity) and poll.seq == 1  # SEQ = ACK
        answer(master, t + 0.05, ack=1)
    poll = polls_of(master, 3.2)
    assert poll.order == TARGET and poll.seq == 0  # ACK taken from the last reply of the 3 s
    fresh = Master(rng=random.Random(0))
    polls_of(fresh, 0.0)
    answer(fresh, 0.1, ack=1)
    fresh.send_order(Stop())
    assert isinstance(polls_of(fresh, 0.2).order, Stop)


def test_while_an_order_is_pending_every_other_poll_carries_the_wish():
    master = started_master()
    master.set_velocity(20, 0, 0, 0, 3.0)
    master.send_order(TARGET)
    kinds = []
    t = 3.1
    for _ in range(6):
        poll = polls_of(master, t)
        kinds.append(type(poll.order).__name__)
        assert poll.seq == (1 if isinstance(poll.order, Position) else 0)
        answer(master, t + 0.05)
        t += 0.1
    assert kinds == ["Position", "Velocity"] * 3


def test_one_pending_order_at_a_time_and_rejections_are_reported_with_their_reason():
    master = started_master()
    first = master.send_order(TARGET)
    master.send_order(ImageSettings(budget_bytes=300))
    poll = polls_of(master, 3.1)
    assert poll.order == TARGET
    events = answer(master, 3.2, ack=1, rejected=True, reason=2)
    assert [(e.order_id, e.reason, e.reason_text) for e in of(events, MasterRejected)] == [
        (first, 2, "refused by the autopilot")]
    assert not of(events, OrderAcknowledged)
    assert polls_of(master, 3.3).order == ImageSettings(budget_bytes=300)
    events = answer(master, 3.4, ack=0)
    assert of(events, OrderAcknowledged)


def test_stop_goes_in_every_poll_until_a_reply_to_a_stop_poll_confirms_it():
    master = started_master()
    stop_id = master.send_order(Stop())
    poll = polls_of(master, 3.1)
    assert isinstance(poll.order, Stop) and poll.seq == 0
    events = answer(master, 3.2, hold=True, autopilot=True, mode=Mode.DEPTH_HOLD)
    assert [(e.order_id, e.mode) for e in of(events, StopConfirmed)] == [(stop_id, Mode.DEPTH_HOLD)]
    assert not master.stopping and isinstance(polls_of(master, 3.3).order, Velocity)


def test_hold_in_a_reply_to_an_earlier_poll_confirms_nothing():
    master = started_master()
    polls_of(master, 3.0)  # a wish poll is on the air
    master.send_order(Stop())
    events = answer(master, 3.1, hold=True, autopilot=True, mode=Mode.POS_HOLD)
    assert not of(events, StopConfirmed) and master.stopping
    for t in (3.2, 3.4):
        assert isinstance(polls_of(master, t).order, Stop)
        events = answer(master, t + 0.05, hold=False, autopilot=True, mode=Mode.POS_HOLD)
        assert not of(events, StopConfirmed)  # HOLD missing
    polls_of(master, 3.6)
    assert of(answer(master, 3.65, hold=True, autopilot=True, mode=Mode.POS_HOLD), StopConfirmed)


def test_stop_without_an_autopilot_is_shown_not_carried_out_and_may_be_cancelled():
    master = started_master()
    stop_id = master.send_order(Stop())
    assert not master.cancel_stop()  # nothing says yet that it cannot be carried out
    polls_of(master, 3.1)
    events = answer(master, 3.2, hold=True, autopilot=False)
    assert [e.order_id for e in of(events, StopNotCarriedOut)] == [stop_id]
    polls_of(master, 3.3)
    assert not of(answer(master, 3.4, hold=True, autopilot=False), StopNotCarriedOut)  # once per spell
    assert master.cancel_stop()
    assert [e.order_id for e in of(master.take_events(), OrderCancelled)] == [stop_id]
    master.request_arm(False, 3.5)
    poll = polls_of(master, 3.5)
    assert isinstance(poll.order, Velocity) and poll.order.arm == Arm.DISARM


def test_stop_cancels_the_pending_order_whose_fate_the_replies_show_and_queued_ones_not_sent():
    master = started_master()
    pending = master.send_order(TARGET)
    queued = master.send_order(ImageSettings(budget_bytes=100))
    assert polls_of(master, 3.1).order == TARGET
    answer(master, 3.2)  # not flipped yet
    master.send_order(Stop())
    events = master.take_events()
    assert [(e.order_id, e.reason) for e in of(events, OrderNotSent)] == [(queued, "cancelled by STOP")]
    assert isinstance(polls_of(master, 3.3).order, Stop)
    events = answer(master, 3.4, ack=1, rejected=True, reason=1, hold=True, autopilot=True, mode=Mode.POS_HOLD)
    assert [(e.order_id, e.reason) for e in of(events, MasterRejected)] == [(pending, 1)]
    assert of(events, StopConfirmed) and not of(events, OrderCancelled)


def test_a_pending_order_never_taken_is_shown_cancelled_when_the_stop_is_confirmed():
    master = started_master()
    pending = master.send_order(TARGET)
    polls_of(master, 3.1)
    answer(master, 3.2)
    master.send_order(Stop())
    polls_of(master, 3.3)
    events = answer(master, 3.4, hold=True, autopilot=True, mode=Mode.POS_HOLD)
    assert [e.order_id for e in of(events, OrderCancelled)] == [pending]
    assert of(events, StopConfirmed)


def test_arm_request_goes_until_done_or_3_s_and_the_same_request_again_only_after_a_zero():
    master = started_master()
    master.request_arm(True, 3.0)
    t = 3.0
    while t < 6.5:
        poll = polls_of(master, t)
        if poll.order.arm == Arm.NONE:
            break
        answer(master, t + 0.05, autopilot=True, armed=False)
        t += 0.25
    assert t > 6.0 and of(master.take_events(), RequestExpired) == [RequestExpired("arm")]
    answer(master, t + 0.05, autopilot=True)  # the reply to the poll with ARM 0 ...
    # ... so the ROV's reference is 0 again and a new ARM is a change: it goes at once.
    master.request_arm(True, t + 0.1)
    assert polls_of(master, t + 0.1).order.arm == Arm.ARM
    events = answer(master, t + 0.15, autopilot=True, armed=True)
    assert polls_of(master, t + 0.2).order.arm == Arm.NONE  # done
    assert not of(events, RequestExpired)


def test_a_repeated_request_first_sends_the_field_0_until_a_reply_comes():
    master = started_master()
    master.request_mode(Mode.STABILIZE, 3.0)
    assert polls_of(master, 3.0).order.mode == Mode.STABILIZE
    answer(master, 3.05, autopilot=True, mode=Mode.MANUAL)  # the ROV saw STABILIZE: its reference
    master.request_mode(Mode.STABILIZE, 3.1)  # the pilot asks again
    assert polls_of(master, 3.1).order.mode == Mode.KEEP
    answer(master, 3.15, autopilot=True, mode=Mode.MANUAL)
    assert polls_of(master, 3.2).order.mode == Mode.STABILIZE


def test_a_request_right_after_a_stop_waits_for_the_rovs_new_reference():
    # The first VELOCITY the ROV takes after a STOP only sets its reference:
    # a MODE riding in it would be swallowed.  So it goes out as 0 first.
    master = started_master()
    master.send_order(Stop())
    assert isinstance(polls_of(master, 3.1).order, Stop)
    assert of(answer(master, 3.15, hold=True, autopilot=True, mode=Mode.POS_HOLD), StopConfirmed)
    master.request_mode(Mode.STABILIZE, 3.2)
    master.request_arm(False, 3.2)
    poll = polls_of(master, 3.2)
    assert isinstance(poll.order, Velocity) and poll.order.mode == Mode.KEEP
    assert poll.order.arm == Arm.DISARM          # a disarm acts whenever it arrives
    answer(master, 3.25, autopilot=True, mode=Mode.POS_HOLD)
    assert polls_of(master, 3.3).order.mode == Mode.STABILIZE
    assert not of(master.take_events(), RequestExpired)


def test_a_disarm_asked_while_a_stop_is_sent_waits_for_it_and_never_lapses_unsent():
    """§2 (decided): a STOP that the autopilot takes 5 s to confirm (its replies show the
    HOLD but not yet the braking mode); the pilot's DISARM asked just after it goes with the
    first VELOCITY after the confirmation, not lapsed behind the STOP's polls."""
    master = started_master()
    master.send_order(Stop())
    master.request_arm(False, 3.1)
    t = 3.1
    while t < 8.0:
        assert isinstance(polls_of(master, t).order, Stop)
        assert not of(answer(master, t + 0.05, hold=True, autopilot=True, armed=True, mode=Mode.MANUAL),
                      StopConfirmed)
        t += 0.25
    polls_of(master, t)
    assert of(answer(master, t + 0.05, hold=True, autopilot=True, armed=True, mode=Mode.POS_HOLD), StopConfirmed)
    poll = polls_of(master, t + 0.1)
    assert isinstance(poll.order, Velocity) and poll.order.arm == Arm.DISARM
    assert not of(master.take_events(), RequestExpired)
    answer(master, t + 0.15, hold=True, autopilot=True, armed=False, mode=Mode.POS_HOLD)
    assert polls_of(master, t + 0.2).order.arm == Arm.NONE  # done: the vehicle disarmed


def test_a_request_in_the_first_poll_after_a_failsafe_goes_again_after_a_0():
    """§2 (decided): the ROV's failsafe resets its ARM/MODE reference, so the first
    VELOCITY it takes after one only sets it.  The ARM that rode in it (the console
    was starved, the link silent past the failsafe, the pilot's ARM then in flight:
    tests/console/test_restarts.py's swallowed ARM) goes again after a 0, and the
    vehicle arms; it is never left repeating a value the ROV takes as no change."""
    master, slave = started_master(), ready_slave()
    slave.update_status(dataclasses.replace(READY, armed=False))
    for t in (0.0, 0.3):
        send(slave, Poll(order=Velocity()), t)  # the ROV's reference: ARM 0
    slave.tick(0.3 + slave.failsafe_s + 0.1)  # then silence: the ROV fails safe
    assert slave.failsafe
    master.request_arm(True, 3.0)
    armed_at = None
    t = 3.0
    while t < 6.0 and armed_at is None:
        poll = polls_of(master, t)
        reply, events = send(slave, poll, t + 0.02)
        if of(events, ArmRequested):
            armed_at = t
            slave.update_status(dataclasses.replace(READY, armed=True))
            reply, _ = send(slave, Poll(order=Velocity()), t + 0.03)  # (its status now armed)
        master.receive_bytes(encode_frame(reply.encode()), t + 0.05)
        t += 0.1
    assert armed_at is not None and armed_at >= 3.1, "the ARM in the first poll after the failsafe was swallowed"
    assert not of(master.take_events(), RequestExpired)


def test_a_request_waits_for_a_velocity_after_a_failsafe_answered_to_another_poll():
    master = started_master()
    master.send_order(Position(1, 2, 3, 0))
    t = 3.0
    while not isinstance(polls_of(master, t).order, Position):
        answer(master, t + 0.05, autopilot=True, mode=Mode.MANUAL)
        t += 0.1
    master.request_mode(Mode.STABILIZE, t)
    answer(master, t + 0.05, autopilot=True, mode=Mode.MANUAL, failsafe=True, hold=True)

    def next_velocity(t: float) -> Velocity:
        while not isinstance((poll := polls_of(master, t)).order, Velocity):
            answer(master, t + 0.05, autopilot=True, mode=Mode.MANUAL, hold=True)
            t += 0.1
        return poll.order

    # The ROV's reference is unset (the failsafe) and the POSITION set none: the request
    # goes as 0 in the next VELOCITY, then, once that is answered, as itself.
    assert next_velocity(t + 0.1).mode == Mode.KEEP
    answer(master, t + 0.15, autopilot=True, mode=Mode.MANUAL, hold=True)
    assert next_velocity(t + 0.2).mode == Mode.STABILIZE


def test_the_operator_len_cap_follows_the_last_polls_size():
    master = started_master(idle_size=0)
    polls_of(master, 3.0)
    assert master.decoder.max_len == 16 + 24
    too_long = reply_frame(img=0, offset=0, trunk=bytes(48))
    assert master.receive_bytes(too_long, 3.1) == []
    assert master.decoder.counters.oversize == 1


def test_first_over_a_partial_copy_discards_it():
    master = started_master(skip_first_image=False)
    polls_of(master, 3.0)
    answer(master, 3.05, img=0, offset=0, trunk=(100).to_bytes(2, "big") + b"a" * 22)
    poll = polls_of(master, 3.1)
    assert (poll.img, poll.offset) == (0, 24)
    events = answer(master, 3.15, img=0, offset=0, trunk=(50).to_bytes(2, "big") + b"b" * 22)
    assert of(events, ImageAbandoned)
    assert of(events, ImageProgress)[-1].prefix == b"b" * 22
    assert polls_of(master, 3.2).offset == 24


def test_the_operator_shows_the_second_image_after_start_not_the_first():
    master = Master(rng=random.Random(0), first_img=6, idle_size=3)
    polls_of(master, 0.0)
    events = answer(master, 0.05, img=6, offset=0, trunk=(3).to_bytes(2, "big") + b"old", last=True)
    assert not of(events, ImageComplete) and not of(events, ImageProgress)
    poll = polls_of(master, 0.1)
    assert (poll.img, poll.offset) == (7, 0)
    events = answer(master, 0.15, img=7, offset=0, trunk=(3).to_bytes(2, "big") + b"new", last=True)
    assert [e.data for e in of(events, ImageComplete)] == [b"new"]


# ---------------------------------------------------------------------------
# Both ends
# ---------------------------------------------------------------------------


def test_a_rov_restart_in_the_middle_of_an_image_never_splices_two_captures():
    captures = []

    def source(img, settings):
        data = bytes([len(captures) + 1]) * 1500
        captures.append(data)
        return data

    master = Master(rng=random.Random(3), first_img=0, skip_first_image=False, idle_size=1)
    slave = ready_slave(image_source=source)
    channel = Channel(LinkParams(), seed=0)
    done = []
    sim = SimLink(master, slave, channel, on_master_event=lambda e, now: done.append(e))
    while master.image_received < 600:
        sim.run_until(sim.now + 0.05)
    # The ROV restarts: the new process holds no image.
    sim.slave = ready_slave(image_source=source, now=sim.now)
    sim.run_until(sim.now + 30)
    complete = [e.data for e in done if isinstance(e, ImageComplete)]
    assert complete and all(data in captures for data in complete)  # never a mix of two
    assert complete[0] == captures[1]  # the image in progress came anew from the new ROV
    assert any(isinstance(e, ImageAbandoned) and "FIRST" in e.reason for e in done)


def test_end_to_end_orders_are_acknowledged_or_rejected_and_stop_confirmed():
    master = Master(rng=random.Random(1))
    slave = ready_slave(image_source=lambda img, s: bytes(200))
    answers = iter([(True, None), (False, 2)])
    events = []
    sim = SimLink(master, slave, Channel(LinkParams(), seed=1), on_master_event=lambda e, now: events.append(e),
                  autopilot=lambda e, now: next(answers))

    def brake(e, now):
        if isinstance(e, BrakeRequested):
            slave.update_status(dataclasses.replace(slave.status, mode=Mode.POS_HOLD))

    sim.on_slave_event = brake
    sim.run_until(1.0)
    ids = [master.send_order(TARGET), master.send_order(Position(5, 5, 5, 0)), master.send_order(ReservedOrder(9))]
    sim.run_until(10.0)
    stop = master.send_order(Stop())
    sim.run_until(15.0)
    assert [e.order_id for e in events if isinstance(e, OrderAcknowledged)] == [ids[0]]
    assert [(e.order_id, e.reason) for e in events if isinstance(e, MasterRejected)] == [(ids[1], 2), (ids[2], 0)]
    assert [e.order_id for e in events if isinstance(e, StopConfirmed)] == [stop]
    replies = [e.reply for e in events if isinstance(e, PoseReceived)]
    assert replies[-1].mode == Mode.POS_HOLD
    assert all(not r.sync for r in replies) and all(r.attitude_valid for r in replies)
    assert isinstance(Poll().order, NoOrder)


def test_a_second_stop_while_one_is_sent_joins_it():
    master = started_master()
    first, second = master.send_order(Stop()), None
    polls_of(master, 3.1)
    second = master.send_order(Stop())
    events = answer(master, 3.2, hold=True, autopilot=True, mode=Mode.POS_HOLD)
    assert [e.order_id for e in of(events, StopConfirmed)] == [first, second]
    assert not of(events, OrderCancelled)


def hold_kept_with_the_stick_held(master, slave, t0: float, seconds: float = 2.0) -> None:
    """Polls and replies for `seconds` from `t0`, the wish forward: the ROV never
    leaves its HOLD and never drives."""
    t = t0
    while t < t0 + seconds:
        poll = polls_of(master, t)
        reply, events = send(slave, poll, t + 0.02)
        assert slave.hold, f"HOLD left at {t:.2f} s with the stick held (poll {poll.order})"
        assert all(e.velocity.is_neutral for e in of(events, VelocityCommanded)), events
        master.receive_bytes(encode_frame(reply.encode()), t + 0.05)
        t += 0.1


def test_a_recentring_before_a_failsafe_never_releases_its_hold_with_the_stick_held():
    """§5 (decided): the pilot centred (its re-centring owed to a HOLD then shown), pushed
    the stick, and the link went silent before any reply came: the ROV failed safe and
    holds. The re-centring from before is not one for this HOLD: the VELOCITY polls after
    the link returns carry the held stick, and the ROV keeps holding until the pilot
    centres again (tests/console/test_cockpit.py's key held through a failsafe: the ROV
    drove off, when the page had become quick enough to press the key before a reply)."""
    master, slave = started_master(), ready_slave()
    master.set_pilot_in_force(True)
    centred(slave, 0.0)
    t = 3.0
    for _ in range(3):  # polls answered, the stick centred
        poll = polls_of(master, t)
        reply, _ = send(slave, poll, t + 0.02)
        master.receive_bytes(encode_frame(reply.encode()), t + 0.05)
        t += 0.1
    master.recentred()  # the pilot centres ...
    master.set_velocity(64, 0, 0, 0, t)  # ... and pushes again, no reply in between
    slave.tick(t + slave.failsafe_s + 0.1)  # the link silent: the ROV fails safe
    assert slave.failsafe and slave.hold
    hold_kept_with_the_stick_held(master, slave, t + slave.failsafe_s + 0.2)
    # Centred: the HOLD goes.
    master.set_velocity(0, 0, 0, 0, t + 10)
    master.recentred()
    for k in range(5):
        poll = polls_of(master, t + 10 + 0.1 * k)
        reply, _ = send(slave, poll, t + 10.02 + 0.1 * k)
        master.receive_bytes(encode_frame(reply.encode()), t + 10.05 + 0.1 * k)
    assert not slave.hold


def test_a_recentring_before_a_stop_never_releases_its_hold_with_the_stick_held():
    """The same for a STOP pressed with the stick pushed just after a centring: the STOP's
    HOLD stays until the pilot centres after it."""
    master, slave = started_master(), ready_slave()
    master.set_pilot_in_force(True)
    centred(slave, 0.0)
    master.recentred()
    master.set_velocity(64, 0, 0, 0, 3.0)
    master.send_order(Stop())
    hold_kept_with_the_stick_held(master, slave, 3.0)


def test_a_recentring_owed_to_a_stop_never_releases_a_failsafe_hold_that_came_after_it():
    """The pilot centred under a STOP's HOLD, the zero not yet sent, pushed the stick again,
    and the link went silent: the ROV failed safe. The first poll after the silence is
    made before any reply says so; it carries the held stick, not the zero owed to the
    STOP's HOLD, and the failsafe's HOLD stays until the pilot centres again."""
    master, slave = started_master(), ready_slave()
    master.set_pilot_in_force(True)
    centred(slave, 0.0)
    master.set_velocity(64, 0, 0, 0, 3.0)
    master.send_order(Stop())
    slave.update_status(dataclasses.replace(READY, mode=Mode.POS_HOLD))  # (the autopilot's brake)
    t = 3.0
    while (master.stopping or not slave.hold) and t < 6.0:  # the STOP's HOLD, confirmed
        poll = polls_of(master, t)
        reply, _ = send(slave, poll, t + 0.02)
        master.receive_bytes(encode_frame(reply.encode()), t + 0.05)
        t += 0.1
    assert not master.stopping and slave.hold, (master.stopping, slave.hold, poll)
    master.set_velocity(0, 0, 0, 0, t)
    master.recentred()  # centred under the HOLD ...
    master.set_velocity(64, 0, 0, 0, t)  # ... and pushed again before the zero went
    polls_of(master, t)  # a poll lost: no reply
    slave.tick(t + slave.failsafe_s + 0.1)  # the ROV fails safe
    assert slave.failsafe and slave.hold
    hold_kept_with_the_stick_held(master, slave, t + slave.failsafe_s + 0.2)
