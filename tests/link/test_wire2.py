"""Version 2's own bytes (docs/PROTOCOL.md §8.1): every version 1.1 poll and reply
survives the translation both ways, what is left out is exactly what the chained
reply says, structural faults are refused, and over a real (emulated) channel a
repeated wish keeps the vehicle driving while a changed one is always sent, also
after a lost reply.  The ROV's chain lives while polls are taken."""

from __future__ import annotations

import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rovlink.link.emulators.channel import Channel, LinkParams
from rovlink.link.radio.auth import OperatorChain, RovChain
from rovlink.link.radio.master import Master
from rovlink.link.radio.messages import NO_IMAGE_DATA, REPLY_STATUS_BYTE, Mode, NoOrder, Poll, ProtocolError, Reply, Velocity
from rovlink.link.radio.secure import SecureMaster, SecureSlave
from rovlink.link.radio.sim import SimLink
from rovlink.link.radio.slave import Slave, Status, VelocityCommanded
from rovlink.link.radio.wire2 import (
    NO_CONTINUATION,
    V2_CYCLE,
    continuation_of,
    encode_pose,
    poll_from_wire,
    poll_to_wire,
    pose_of,
    reply_from_wire,
    reply_to_wire,
    request_of,
    wish_of,
)

from .test_messages_properties import polls, replies

K = bytes(range(32))
requests = st.tuples(st.integers(0, 7), st.integers(0, NO_IMAGE_DATA))
poses = st.tuples(*([st.integers(-32768, 32767)] * 3 + [st.integers(-18000, 18000)] * 3))


@settings(max_examples=400)
@given(polls, requests)
def test_every_poll_survives_the_translation(poll, continuation):
    payload = poll.encode()
    wire = poll_to_wire(payload, continuation)
    assert poll_from_wire(wire, continuation) == payload
    # Left out: exactly a request equal to the continuation (never a reserved order's) ...
    left_out = len(payload) - len(wire)
    same = (poll.img, poll.offset) == continuation and poll.order.code <= 4
    no_arm_mode = isinstance(poll.order, Velocity) and not poll.order.arm and not poll.order.mode
    assert left_out == 2 * same + no_arm_mode


@settings(max_examples=300)
@given(replies(), poses, st.booleans())
def test_every_reply_survives_the_translation(reply, reference, first_poll):
    payload = reply.encode()
    # The request of the poll it answered: its own trunk's, or any when it has none.
    request = (reply.img, 0 if reply.first else reply.offset) if reply.has_trunk else (3, NO_IMAGE_DATA)
    wire = reply_to_wire(payload, None if first_poll else reference)
    back, pose = reply_from_wire(wire, request, None if first_poll else reference)
    # A REASON without REJECTED (meaningless, §5) does not cross: its bits are §11.1's annex.
    if not reply.rejected:
        payload = payload[:REPLY_STATUS_BYTE] + bytes((payload[REPLY_STATUS_BYTE] & 0xF9,)) + payload[REPLY_STATUS_BYTE + 1:]
    assert back == payload and pose == pose_of(payload)
    assert len(wire) <= len(payload) - (2 if reply.has_trunk else 0)


def test_the_pose_is_sent_as_differences_only_when_shorter():
    ref = (1000, -300, 450, 150, -220, 9000)
    small, delta = encode_pose((1010, -303, 452, 155, -227, 9120), ref)
    assert delta and small == bytes.fromhex("14 05 04 0a 0d f0 01")
    whole, delta = encode_pose((1250, -300, 450, 150, -220, -9000), (0, 0, 0, 0, 0, 9000))
    assert not delta and len(whole) == 12


@pytest.mark.parametrize("wire, why", [
    (bytes.fromhex("01 32 00"), "VELOCITY of 3 bytes"),
    (bytes.fromhex("00 00"), "NONE of 2 bytes"),
    (bytes.fromhex("02 00 00 00 00 00 00 00 00"), "POSITION without 9 bytes"),
    (bytes.fromhex("05 00"), "a reserved order without its request"),
    (b"", "empty"),
])
def test_a_poll_with_no_layout_is_a_structural_fault(wire, why):
    with pytest.raises(ProtocolError):
        poll_from_wire(wire, (0, 0))


@pytest.mark.parametrize("wire, asked, reference", [
    (bytes.fromhex("01 b1 00 00 00 00 00"), (0, 0), (0,) * 6),  # five differences
    (bytes.fromhex("01 b1 ff ff ff 01 00 00 00 00"), (0, 0), (0,) * 6),  # a difference of 4 bytes
    (bytes.fromhex("01 b1 00 00 00 00 00 00"), (0, 0), None),  # differences, no reference
    (bytes.fromhex("01 b1 02 00 00 00 00 00"), (0, 0), (32767, 0, 0, 0, 0, 0)),  # out of int16
    (bytes.fromhex("01 b0") + bytes(12) + b"x", (0, NO_IMAGE_DATA), None),  # a trunk nobody asked for
    (bytes.fromhex("01 b0") + bytes(12) + b"x", (0, 0), None),  # offset 0 without FIRST
    (bytes.fromhex("01 b0") + bytes(11), (0, 0), None),  # a whole pose cut short
])
def test_a_reply_with_no_layout_is_a_structural_fault(wire, asked, reference):
    with pytest.raises(ProtocolError):
        reply_from_wire(wire, asked, reference)


def test_a_none_poll_chained_to_a_velocitys_reply_is_that_velocity_again():
    velocity = Poll(order=Velocity(50, 0, -20, 10), img=2, offset=40).encode()
    wish = wish_of(velocity)
    assert wish == Velocity(50, 0, -20, 10).encode_body()
    again = poll_from_wire(poll_to_wire(Poll(order=NoOrder(), img=2, offset=140).encode(), (2, 140)), (2, 140), wish)
    assert Poll.decode(again) == Poll(order=Velocity(50, 0, -20, 10), img=2, offset=140)
    # No wish from an ARM or MODE request, an invalid axis, or any other order.
    assert wish_of(Poll(order=Velocity(50, 0, 0, 0, 1, 0)).encode()) is None
    assert wish_of(Poll(order=Velocity(0, 0, 0, 0, 0, Mode.MANUAL)).encode()) is None
    assert wish_of(velocity[:3] + bytes.fromhex("00 80 00 00 00")) is None
    assert wish_of(Poll(order=NoOrder()).encode()) is None


def test_the_continuation_is_after_the_trunk_or_the_request_again():
    poll = Poll(order=NoOrder(), img=5, offset=100).encode()
    with_trunk = Reply(img=5, offset=100, trunk=b"abc").encode()
    assert continuation_of(with_trunk, poll) == (5, 103)
    assert continuation_of(Reply().encode(), poll) == (5, 100)
    assert continuation_of(Reply(sync=True).encode(), None) == NO_CONTINUATION
    assert request_of(poll) == (5, 100)


# -- the ROV's chain lives while polls are taken --------------------------------


def _chain(now=0.0):
    op, rov = OperatorChain(K, count=0), RovChain(K, failsafe_s=3.0)
    hello = op.seal_hello(bytes.fromhex("40 1f ff"), now)
    sync = rov.seal_sync(bytes.fromhex("01" + "00" * 12 + "81"), rov.check_poll(hello[2:], now), now)
    op.open_reply(sync[2:], now)
    return op, rov


def _exchange(op, rov, t, answered=True):
    poll = op.seal_poll(bytes.fromhex("00"), t)
    taken = rov.check_poll(poll[2:], t)
    if taken is None:
        return False
    rov.take(taken, t)
    reply = rov.seal_reply(bytes.fromhex("01 b0") + bytes(12), taken, t)
    if answered:
        op.open_reply(reply[2:], t)
    return True


def test_a_poll_on_a_reply_older_than_the_failsafe_time_is_taken_while_polls_are():
    op, rov = _chain()
    assert _exchange(op, rov, 0.5)
    # Replies lost for 4 s (more than the failsafe time), polls arriving: the chain lives.
    for t in (1.0, 2.0, 3.0, 4.0):
        assert _exchange(op, rov, t, answered=False)
    assert _exchange(op, rov, 4.4)


def test_no_poll_for_the_failsafe_time_ends_the_chain():
    op, rov = _chain()
    assert _exchange(op, rov, 0.5)
    assert not _exchange(op, rov, 3.6)  # nothing taken since 0.5 s: the failsafe engaged


def test_a_value_older_than_twice_the_failsafe_time_is_never_matched():
    op, rov = _chain()
    assert _exchange(op, rov, 0.5)
    for t in (1.0, 2.0, 3.0, 4.0, 5.0, 6.0):
        assert _exchange(op, rov, t, answered=False)
    assert not _exchange(op, rov, 6.6)  # chained to the reply of 0.5 s


def test_a_held_back_poll_is_refused_once_the_failsafe_engaged():
    op, rov = _chain()
    assert _exchange(op, rov, 0.5)
    held = op.seal_poll(bytes.fromhex("00"), 1.0)  # held back by an attacker ...
    assert rov.check_poll(held[2:], 4.0) is None  # ... past the failsafe (no poll taken since 0.5 s)


# -- over the channel ---------------------------------------------------------------


def _link(seed=3, **params):
    master = SecureMaster(Master(rng=random.Random(seed)), K)
    slave = SecureSlave(Slave(image_source=lambda img, s: bytes(range(200)) * 10), K)
    slave.slave.update_status(Status(armed=True, mode=Mode.MANUAL, autopilot=True, position_valid=True,
                                     attitude_valid=True))
    channel = Channel(LinkParams(bitrate_bps=1900, delay_s=0.085, **params), seed=seed)
    commanded: list = []
    sim = SimLink(master, slave, channel, on_slave_event=lambda e, t: commanded.append((t, e.velocity))
                  if isinstance(e, VelocityCommanded) else None)
    return master, slave, channel, sim, commanded


def test_an_unchanged_wish_goes_as_none_and_the_vehicle_keeps_it():
    master, slave, channel, sim, commanded = _link()
    sent: list = []
    real_send = channel.send
    channel.send = lambda side, data, now: (sent.append((side, bytes(data))), real_send(side, data, now))[1]
    sim.run_until(4.0)
    master.set_velocity(0, 0, 0, 0, sim.now)  # the pilot re-centres (HOLD at start), then drives
    sim.run_until(6.0)
    master.set_velocity(60, 0, 0, 0, sim.now)
    sim.run_until(36.0)
    polls = [d for side, d in sent if side == "a" and not d[2] & 0x40]
    none_polls = [p for p in polls if p[2] & 0x0F == 0 and len(p) == 8]
    assert len(none_polls) > len(polls) / 3  # the wish rode in a NONE poll every other cycle or so
    # The vehicle kept the wish throughout: no lapse, and every poll it took was that VELOCITY.
    assert slave.slave.stats.velocity_lapses == 0
    driving = [v for t, v in commanded if t > 7.0]
    assert len(driving) > 50 and all((v.vx, v.vy, v.vz, v.vyaw) == (60, 0, 0, 0) for v in driving)
    # And each reply filled its cycle: a poll and its reply within SIZE 0's 72 bytes.
    replies = [d for side, d in sent[len(sent) // 2:] if side == "b"]
    assert max(len(r) for r in replies) + 8 <= V2_CYCLE[0]


def test_a_wish_changed_back_after_a_lost_reply_reaches_the_vehicle():
    """The ROV took wish B but its reply was lost; the pilot goes back to A, which
    the last reply the operator holds answered.  The poll is chained to that reply,
    so a NONE there would be A again at the ROV: the vehicle drives A either way."""
    master, slave, channel, sim, commanded = _link()
    sim.run_until(4.0)
    master.set_velocity(0, 0, 0, 0, sim.now)
    sim.run_until(6.0)
    master.set_velocity(40, 0, 0, 0, sim.now)  # A
    sim.run_until(10.0)
    real_deliver = channel.deliver
    state = {"dropped": False}

    def deliver(now):
        out = real_deliver(now)
        if not state["dropped"] and slave.slave.velocity.vx == -40:
            kept = [d for d in out if d.to != "a"]  # the reply to B's poll is lost
            state["dropped"] = len(kept) < len(out)
            return kept
        return out

    channel.deliver = deliver
    master.set_velocity(-40, 0, 0, 0, sim.now)  # B
    sim.run_until(sim.now + 1.2)
    assert state["dropped"]
    master.set_velocity(40, 0, 0, 0, sim.now)  # A again
    sim.run_until(sim.now + 1.5)
    assert slave.slave.velocity.vx == 40


def test_after_a_lost_reply_the_next_poll_asks_no_image_data():
    master, slave, channel, sim, _ = _link(seed=5, loss=0.1)
    asked: list = []
    real_next = master.master.next_poll

    def next_poll(now):
        lost_before = master.master.stats.replies_lost
        frame = real_next(now)
        if frame is not None:
            asked.append((lost_before, master.master._awaiting[1].offset))
        return frame

    master.master.next_poll = next_poll
    sim.run_until(120.0)
    after_loss = [offset for (lost, offset), (lost_prev, _) in zip(asked[1:], asked) if lost > lost_prev]
    assert after_loss and all(offset == NO_IMAGE_DATA for offset in after_loss)
    assert master.master.stats.images_completed > 0


def test_after_a_lost_reply_the_next_poll_waits_with_the_shortest_margin():
    """§8.1: the poll after a lost reply asks for no image data and waits for its
    answer with §5's shortest margin (50 ms), so that a run of lost polls leaves
    the ROV without one for less time; once a reply comes, the usual margin.
    Version 1.1's master keeps its margin (only version 2 asks for this)."""
    from rovlink.link.radio.master import OUTAGE_MARGIN_S

    def timeouts(master, inner):
        seen: list = []
        real_next = master.next_poll

        def next_poll(now):
            frame = real_next(now)  # counts the last poll's reply lost when its deadline passed
            if frame is not None and inner._awaiting is not None and inner._awaiting[0] == now:  # a poll, no HELLO
                sent_at, poll, reply = inner._awaiting
                waited = master.deadline() - sent_at
                usual = inner.timeout_for(inner.sizes.poll(poll), reply)
                seen.append((inner.stats.replies_lost, waited, usual))
            return frame

        master.next_poll = next_poll
        return seen

    master, slave, channel, sim, _ = _link(seed=5, loss=0.1)
    seen = timeouts(master, master.master)
    sim.run_until(120.0)
    pairs = list(zip(seen, seen[1:]))
    after_loss = [(w, u) for (lost_prev, _, _), (lost, w, u) in pairs if lost > lost_prev]
    after_reply = [(w, u) for (lost_prev, _, _), (lost, w, u) in pairs if lost == lost_prev]
    assert after_loss and after_reply
    margin = master.master.margin_s
    assert all(w == pytest.approx(u - margin + OUTAGE_MARGIN_S) for w, u in after_loss)
    assert all(w == pytest.approx(u) for w, u in after_reply)

    # Version 1.1: the same channel, the usual margin after a loss too.
    v11 = Master(rng=random.Random(5))
    seen11 = timeouts(v11, v11)
    sim11 = SimLink(v11, Slave(image_source=lambda img, s: bytes(range(200)) * 10),
                    Channel(LinkParams(bitrate_bps=1900, delay_s=0.085, loss=0.1), seed=5))
    sim11.run_until(120.0)
    assert v11.stats.replies_lost > 0
    assert all(w == pytest.approx(u) for _, w, u in seen11)


def test_a_rov_and_operator_keep_the_same_reference_pose_while_it_moves():
    """Bit errors lose replies; the differences are always taken from the reply the
    poll was chained to, so every pose shown is one the ROV had, never a drifted sum."""
    master, slave, channel, sim, _ = _link(seed=7, ber=2e-4)
    rng = random.Random(1)
    had: set = set()

    def move(now):
        s = slave.slave.status
        status = Status(armed=True, mode=Mode.MANUAL, autopilot=True, position_valid=True, attitude_valid=True,
                        x_cm=s.x_cm + rng.randint(-60, 60), y_cm=s.y_cm + rng.randint(-60, 60),
                        z_cm=max(0, s.z_cm + rng.randint(-9, 9)), roll_cdeg=rng.randint(-300, 300),
                        pitch_cdeg=rng.randint(-300, 300),
                        yaw_cdeg=(s.yaw_cdeg + rng.randint(-2000, 2000) + 18000) % 36000 - 18000)
        slave.slave.update_status(status)
        had.add((status.x_cm, status.y_cm, status.z_cm, status.roll_cdeg, status.pitch_cdeg, status.yaw_cdeg))
        sim.at(now + 0.1, move)

    shown: list = []
    sim.on_master_event = lambda e, t: shown.append(e.reply) if hasattr(e, "reply") else None
    sim.at(0.0, move)
    sim.run_until(120.0)
    assert master.master.stats.replies_lost > 5  # the noise did lose replies
    moved = [r for r in shown if not r.sync and r.x_cm]
    assert len(moved) > 100
    assert all((r.x_cm, r.y_cm, r.z_cm, r.roll_cdeg, r.pitch_cdeg, r.yaw_cdeg) in had for r in moved)
    assert master.master.stats.protocol_errors == 0


# -- the text read one way (issue 33) ---------------------------------------------


def test_a_field_sent_that_could_have_been_left_out_is_taken_as_sent():
    poll = Poll(order=Velocity(50, 0, -20, 10), img=2, offset=140).encode()
    short = poll_to_wire(poll, (2, 140))
    assert len(short) == 5  # byte 0 and the four axes
    for wire in (poll, poll[:3] + poll[4:], bytes((poll[0],)) + poll[3:]):  # request, ARM/MODE byte, both
        assert poll_from_wire(wire, (2, 140)) == poll
    # A whole pose where six differences would be shorter: taken as it is.
    reply = Reply(x_cm=10, y_cm=-3).encode()
    back, pose = reply_from_wire(reply_to_wire(reply, None), (0, NO_IMAGE_DATA), (0,) * 6)
    assert back == reply and pose == (10, -3, 0, 0, 0, 0)


def test_a_hello_does_not_advance_count():
    op, rov = _chain()
    first = op.seal_poll(bytes.fromhex("00"), 0.1)
    op.seal_hello(bytes.fromhex("40 1f ff"), 0.2)
    second = op.seal_poll(bytes.fromhex("00"), 0.3)
    assert (first[-5] + 1) % 256 == second[-5]  # COUNT, before the 4-byte TAG


def test_a_poll_for_no_image_data_waits_for_a_reply_without_a_trunk():
    master = SecureMaster(Master(rng=random.Random(1), images=False), K)
    slave = SecureSlave(Slave(), K)
    out = slave.receive_bytes(master.next_poll(0.0), 0.0)
    master.receive_bytes(out.reply, 0.1)
    frame = master.next_poll(1.0)
    assert Poll.decode(master._sent[max(master._sent)][0]).offset == NO_IMAGE_DATA
    m = master.master
    # §5 (decided): the largest reply such a poll allows has no trunk: 20 bytes with the whole
    # pose, and §11.1's annex (ALT and one object record, 10 bytes): 30.
    assert m.deadline() == 1.0 + m.timeout_for(m.sizes.poll(Poll.decode(master._sent[max(master._sent)][0])), 30)
    assert len(frame) <= 19


def test_hellos_come_after_twice_the_failsafe_time_less_two_timeouts_of_the_largest_poll():
    master = SecureMaster(Master(rng=random.Random(1)), K)
    slave = SecureSlave(Slave(), K)
    out = slave.receive_bytes(master.next_poll(0.0), 0.0)
    master.receive_bytes(out.reply, 0.1)  # heard at 0.1 s
    m = master.master
    for size, silent in ((0, 4.66), (3, 3.04)):  # the defaults: 3 s, 1.9 kbit/s, 85 ms, margin 0.15 s
        master._last_size = size
        largest = m.timeout_for(19, m.reply_frame_bytes(size))  # a POSITION with its request, its SIZE's reply
        assert abs((6.0 - 2 * largest) - silent) < 0.01
        assert not master._silent_too_long(0.1 + silent - 0.02) and master._silent_too_long(0.1 + silent + 0.02)


def test_size_0_caps_a_steering_cycle_at_72_bytes():
    """§8.1 (issue 40): SIZE 0's cycle is 72 bytes, poll frame and reply frame.  After the
    vectors' VELOCITY poll of 12 bytes a reply with a pose of seven bytes of differences
    carries 45 bytes of picture (72 - 12 - start, LEN, byte 0, status, pose, tag); after
    a NONE poll of 8 bytes the reply frame may be 64 bytes."""
    from rovlink.link.radio.auth import TAG_BYTES
    from rovlink.link.radio.wire2 import reply_frame_cap, trunk_room

    velocity_poll = bytes.fromhex("550a013200ec0a018fe21f06")
    none_poll = bytes.fromhex("55060002db2babe3")
    assert trunk_room(0, 257, 7, TAG_BYTES, len(velocity_poll)) == 45
    assert reply_frame_cap(0, 257, len(none_poll)) == 64
    assert reply_frame_cap(0, 40, len(none_poll)) == 40  # a link's maximum frame caps it too
