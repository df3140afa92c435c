"""Version 2 keeps its promise (docs/PROTOCOL.md §2, §8; issue 16): every reply and
every SYNC is paired with the frame it answers, never with "the poll the
master awaits".  A hostile radio in simulated time (the real master, slave
and channel): STOP polls dropped while HELLO and SYNC pass, replies held back
past the master's resend, a frame-size cap; and the smaller rules one by one."""

from __future__ import annotations

import dataclasses
import random

import pytest

from rovlink.link.emulators.channel import Channel, LinkParams
from rovlink.link.radio.master import (
    Master,
    OrderAcknowledged,
    OrderCancelled,
    OrderRejected,
    PoseReceived,
    StopConfirmed,
)
from rovlink.link.radio.messages import Mode, Position, Reply, Stop
from rovlink.link.radio.secure import LateReply, SecureMaster, SecureSlave, Synced
from rovlink.link.radio.sim import SimLink
from rovlink.link.radio.slave import (
    BrakeRequested,
    FailsafeEntered,
    OrderAbandoned,
    OrderExecuted,
    Slave,
    Status,
)
from rovlink.link.radio.slave import OrderDeclined as SlaveRejected

K = bytes(range(32))
ARMED = Status(armed=True, mode=Mode.MANUAL, autopilot=True, position_valid=True, attitude_valid=True)
STOP_ORDER = 4


def _source(img, settings):
    return bytes((img * 7 + i) % 251 for i in range(1500))


def _order_of(frame: bytes) -> int | None:
    """The ORDER a version 2 poll frame carries (frames are not encrypted); None for a HELLO or a reply."""
    if len(frame) > 2 and not frame[2] & 0x40:
        return frame[2] & 0x0F
    return None


class Hostile:
    """Between the channel and the machines: drops polls carrying STOP in a window,
    holds chosen replies back; HELLOs, SYNCs and every other frame pass."""

    def __init__(self, link: SimLink, *, drop_stop: tuple[float, float] | None = None,
                 hold_reply=None) -> None:
        self.link = link
        self.drop_stop = drop_stop
        self.hold_reply = hold_reply  # (reply frame, now) -> seconds to hold it, or 0
        self.stop_polls_passed: list[float] = []  # when a poll carrying STOP went on the air
        self.frames: list[tuple[str, float, bytes]] = []
        channel = link.channel
        self._send = channel.send
        channel.send = self.send

    def send(self, side: str, data: bytes, now: float) -> bool:
        data = bytes(data)
        self.frames.append((side, now, data))
        if side == "a" and _order_of(data) == STOP_ORDER:
            if self.drop_stop and self.drop_stop[0] <= now < self.drop_stop[1]:
                return True  # lost on the way: the ROV never hears it
            self.stop_polls_passed.append(now)
        if side == "b" and self.hold_reply is not None:
            hold = self.hold_reply(data, now)
            if hold:
                self.link.at(now + hold, lambda t, d=data: self._send("b", d, t))
                return True
        return self._send(side, data, now)


def _braking_rov(slave: Slave):
    """The simulated autopilot: a brake (STOP, failsafe, start) puts it in POS_HOLD."""

    def on_event(event, now):
        if isinstance(event, (BrakeRequested, FailsafeEntered)):
            slave.update_status(dataclasses.replace(slave.status, mode=Mode.POS_HOLD))

    return on_event


def _link(seed: int = 1, *, mtu: int = 259, autopilot="at once"):
    master = SecureMaster(Master(rng=random.Random(seed), max_frame=mtu), K)
    slave = SecureSlave(Slave(image_source=_source, max_frame=mtu), K)
    slave.slave.update_status(ARMED)
    master_events: list[tuple[float, object]] = []
    slave_events: list[tuple[float, object]] = []
    on_rov = _braking_rov(slave.slave)

    def slave_event(e, t):
        slave_events.append((t, e))
        on_rov(e, t)

    kwargs = {} if autopilot == "at once" else {"autopilot": autopilot}
    link = SimLink(master, slave, Channel(LinkParams(bitrate_bps=1900, delay_s=0.085), seed=seed),
                   on_master_event=lambda e, t: master_events.append((t, e)), on_slave_event=slave_event,
                   **kwargs)
    return master, slave, link, master_events, slave_events


def test_a_stop_is_never_confirmed_by_a_sync_while_its_polls_are_dropped():
    master, slave, link, mev, sev = _link(1)
    hostile = Hostile(link, drop_stop=(8.0, 14.0))
    link.run_until(8.0)
    stop_id = master.send_order(Stop())
    link.run_until(24.0)
    # The ROV failed safe meanwhile (no valid poll for 3 s): it holds in POS_HOLD, and the
    # SYNCs that answered the operator's HELLOs said so: HOLD, AUTOPILOT, POS_HOLD.
    assert any(isinstance(e, FailsafeEntered) for _, e in sev)
    syncs = [t for t, e in mev if isinstance(e, Synced) and 8.0 < t < 14.0]
    assert syncs, "HELLO and SYNC passed while the STOP polls were dropped"
    confirmed = [t for t, e in mev if isinstance(e, StopConfirmed) and e.order_id == stop_id]
    assert len(confirmed) == 1
    first_stop_through = min(t for t in hostile.stop_polls_passed if t >= 8.0)
    assert first_stop_through >= 14.0
    assert confirmed[0] > first_stop_through  # confirmed only by the reply to a STOP poll that got through


def test_a_reply_held_back_past_the_resend_confirms_nothing():
    """Steering (short polls), STOP pressed; the reply to the poll before it is held
    back 0.3 s, so it arrives after the master's deadline for that poll, when the STOP
    poll has left: it is late, not the STOP's answer, though it shows HOLD, AUTOPILOT
    and POS_HOLD.  (Judged by the largest poll timeout, 0.648 s, it was taken.)"""
    master, slave, link, mev, sev = _link(2)
    link.run_until(6.0)
    master.set_velocity(60, 0, 0, 0, 6.0)
    slave.slave.update_status(dataclasses.replace(slave.slave.status, mode=Mode.POS_HOLD))
    slave.slave.hold = True  # as after a STOP or failsafe the pilot has not re-centred from
    held: list[float] = []

    def hold_one(frame, now):
        if not held and now > 8.0:
            held.append(now)
            link.at(now, lambda t: master.send_order(Stop()))
            return 0.3
        return 0

    hostile = Hostile(link, drop_stop=(0.0, 60.0), hold_reply=hold_one)
    link.run_until(14.0)
    assert held
    late = [t for t, e in mev if isinstance(e, LateReply)]
    assert late and late[0] < held[0] + 1.0
    assert not any(isinstance(e, StopConfirmed) for _, e in mev), "no STOP poll reached the ROV"
    assert not hostile.stop_polls_passed
    assert master.stopping


def test_every_late_reply_is_never_shown_as_the_present():
    """Replies held back by up to two poll timeouts: every PoseReceived the master shows
    answers the last frame it sent, so its round trip is below that frame's timeout."""
    master, slave, link, mev, _ = _link(3)
    rng = random.Random(3)
    Hostile(link, hold_reply=lambda frame, now: rng.choice((0, 0, 0, 0.3, 0.55, 0.8)) if now > 5 else 0)
    link.run_until(120.0)
    late = sum(isinstance(e, LateReply) for _, e in mev)
    poses = [e for _, e in mev if isinstance(e, PoseReceived)]
    assert late > 10 and len(poses) > 30
    m = master.master
    longest = max(m.timeout_for(4 + 12 + 5, m.reply_frame_bytes(3) + 4), master.hello_timeout())
    assert all(p.round_trip_s is not None and p.round_trip_s <= longest + 1e-9 for p in poses)


def test_a_position_pending_when_stop_is_pressed_is_never_told_not_taken_when_the_rov_took_it():
    """A POSITION in flight, the autopilot answering slowly, then STOP with its polls
    dropped for 4 s: the pilot is told what the ROV did with the POSITION."""
    answers = []

    def slow_autopilot(event, now):
        answers.append((event.token, now))
        return None

    master, slave, link, mev, sev = _link(4, autopilot=slow_autopilot)
    hostile = Hostile(link)
    link.run_until(8.0)
    position_id = master.send_order(Position(150, -50, 300, 0))

    def answer(t):
        for token, _ in answers:
            sev.extend((t, e) for e in slave.slave.order_outcome(token, True, None, t))

    def stop(t):
        hostile.drop_stop = (t, t + 6.0)
        master.send_order(Stop())

    link.run_until(12.0)
    assert answers, "the POSITION reached the ROV"
    started = answers[0][1]
    link.at(started + 0.05, stop)  # before its reply is back
    link.at(started + 1.9, answer)  # within the ROV's 2 s wait
    link.run_until(40.0)
    took = [e for _, e in sev if isinstance(e, OrderExecuted)]
    refused = [e for _, e in sev if isinstance(e, (SlaveRejected, OrderAbandoned))]
    fate = [e for _, e in mev if getattr(e, "order_id", None) == position_id
            and isinstance(e, (OrderAcknowledged, OrderRejected, OrderCancelled))]
    assert len(fate) == 1
    if took:
        assert isinstance(fate[0], OrderAcknowledged)
    elif refused:
        assert isinstance(fate[0], OrderRejected)
    else:
        assert isinstance(fate[0], OrderCancelled)


def test_with_a_64_byte_cap_on_both_ends_every_frame_fits_and_pictures_complete():
    master, slave, link, mev, _ = _link(5, mtu=64)
    hostile = Hostile(link)
    link.run_until(90.0)
    sizes = [len(f) for _, _, f in hostile.frames]
    assert max(sizes) <= 64
    assert max(len(f) for side, _, f in hostile.frames if side == "b") == 64  # the trunk fills the cap
    assert master.master.stats.images_completed >= 3


def test_a_hello_goes_out_only_when_no_poll_awaits_its_reply():
    master, slave, link, mev, _ = _link(6)
    Hostile(link, drop_stop=(5.0, 40.0))  # STOP polls lost: silence, then HELLOs
    hellos, polls = [], []
    real_next = master.next_poll

    def watching_next_poll(now):
        awaiting = master.master.awaiting_reply and now < master.master.deadline()
        frame = real_next(now)
        if frame is not None:
            (hellos if frame[2] & 0x40 else polls).append(now)
            assert not awaiting, f"a frame went out at {now:.3f} while a poll awaited its reply"
        return frame

    object.__setattr__(master, "next_poll", watching_next_poll)
    link.run_until(5.0)
    master.send_order(Stop())
    link.run_until(20.0)
    assert len(hellos) >= 3 and len(polls) > 10


def test_a_new_boot_keeps_arm_and_mode_requests_back_until_a_velocity_reply():
    """A mode asked for the moment a restarted ROV's SYNC comes must not ride in the
    first VELOCITY the new ROV takes (that one only sets its reference, §2)."""
    from rovlink.link.radio.messages import Poll
    from rovlink.link.radio.slave import ModeRequested

    master, slave, link, mev, sev = _link(7)
    link.run_until(8.0)
    seen_modes: list[int] = []

    def restart(t):
        new = SecureSlave(Slave(image_source=_source, now=t), K)
        new.slave.update_status(ARMED)
        link.slave = new
        real = new.slave.receive

        def watching(payload, now):
            poll = Poll.decode(payload)
            if hasattr(poll.order, "mode"):
                seen_modes.append(int(poll.order.mode))
            return real(payload, now)

        new.slave.receive = watching

    link.at(8.0, restart)
    t = 8.0
    while not any(isinstance(e, Synced) and e.restarted for _, e in mev):
        t += 0.05
        link.run_until(t)
    master.request_mode(Mode.DEPTH_HOLD, t)
    link.run_until(t + 8.0)
    assert seen_modes[0] == 0  # the reference-setting VELOCITY carries no request
    assert Mode.DEPTH_HOLD in seen_modes  # then the request goes out, and is acted on
    assert any(isinstance(e, ModeRequested) and e.mode == Mode.DEPTH_HOLD for _, e in sev)


def test_an_angle_out_of_range_shows_the_attitude_unknown_and_the_rest_is_used():
    good = Reply(ack=1, armed=True, mode=Mode.POS_HOLD, hold=True, x_cm=120, yaw_cdeg=9000, autopilot=True,
                 failsafe=True, position_valid=True, attitude_valid=True, rejected=True, reason=1)
    payload = bytearray(good.encode())
    payload[11:13] = (27000).to_bytes(2, "big", signed=True)  # yaw 270°: a ROV reporting 0..360
    got = Reply.decode(bytes(payload))
    assert not got.attitude_valid and got.yaw_cdeg == 0
    assert (got.ack, got.hold, got.failsafe, got.rejected, got.reason, got.x_cm, got.mode) == (
        1, True, True, True, 1, 120, Mode.POS_HOLD)


def test_the_master_says_what_it_sent_hellos_polls_and_their_orders():
    """PollSent (issue 17 of the console's house): the frame as it left (sealed), the
    poll it carried, the ids of the orders in it; nobody decodes the bytes again."""
    from rovlink.link.radio.master import PollSent

    master, slave, link, mev, sev = _link(8)
    sent_frames: list[bytes] = []
    real = link.channel.send
    link.channel.send = lambda side, data, now: (sent_frames.append(bytes(data)) if side == "a" else None,
                                                  real(side, data, now))[1]
    link.run_until(8.0)
    position_id = master.send_order(Position(100, 0, 200, 0))
    link.run_until(12.0)
    stop_id = master.send_order(Stop())
    link.run_until(16.0)
    told = [e for _, e in mev if isinstance(e, PollSent)]
    assert [e.frame for e in told] == sent_frames  # every frame that left, as it left
    assert told[0].hello and told[0].poll is None
    assert any(isinstance(e.poll.order, Position) and e.order_ids == (position_id,) for e in told if e.poll)
    assert any(isinstance(e.poll.order, Stop) and e.order_ids == (stop_id,) for e in told if e.poll)
    assert all(e.order_ids == () for e in told if e.poll and not isinstance(e.poll.order, (Position, Stop)))


# -- a structural fault is never chained to (§1, issue 33) ---------------------


def _by_hand():
    """A SecureMaster and a SecureSlave passing frames by hand, a cycle each half second."""
    master = SecureMaster(Master(rng=random.Random(1)), K)
    slave = SecureSlave(Slave(image_source=_source), K)
    slave.slave.update_status(ARMED)
    return master, slave


def _cycle(master, slave, t, tamper=None, deliver=True, rov_events=None):
    """One poll and its reply; `tamper` rewrites the reply's version 2 payload before
    the ROV seals it (an authentic reply with a fault); the master's events (the
    slave's go to `rov_events`)."""
    poll = master.next_poll(t)
    assert poll is not None
    real = slave.chain.seal_reply
    if tamper is not None:
        slave.chain.seal_reply = lambda payload, taken, now, info=None: real(tamper(payload), taken, now, info=info)
    try:
        out = slave.receive_bytes(poll, t + 0.1)
    finally:
        slave.chain.seal_reply = real
    if rov_events is not None:
        rov_events.extend(out.events)
    return master.receive_bytes(out.reply, t + 0.2) if deliver else []


def _pose_end(payload: bytes) -> int:
    """Where a version 2 reply's pose ends (its trunk starts)."""
    if not payload[1] & 0x01:
        return 14
    i = 2
    for _ in range(6):
        while payload[i] & 0x80:
            i += 1
        i += 1
    return i


def _no_trunk(bit):
    return lambda p: bytes((p[0] | bit,)) + p[1:_pose_end(p)]


def _differences(diffs: str):
    return lambda p: bytes((p[0], p[1] | 0x01)) + bytes.fromhex(diffs) + p[_pose_end(p):]


FAULTS = {
    # (the reply rewritten, which poll it answers: "first" asks from offset 0, "after a loss"
    # for no image data, "steering" is of SIZE 0)
    "FIRST without a trunk": (_no_trunk(0x80), "first"),
    "LAST without a trunk": (_no_trunk(0x40), "first"),
    "a trunk at offset 0 without FIRST": (lambda p: bytes((p[0] & 0x7F,)) + p[1:], "first"),
    "a trunk answering OFFSET 8191": (lambda p: p + b"x", "after a loss"),
    "a pose difference over 3 bytes": (_differences("80 80 80 01 00 00 00 00 00"), "first"),
    "a pose difference not in its shortest form": (_differences("80 00 00 00 00 00 00"), "first"),
    "a value out of 16 bits after adding": (_differences("80 80 04 00 00 00 00 00"), "first"),
    "a reply over its SIZE class": (lambda p: p + bytes(100), "steering"),
}


@pytest.mark.parametrize("fault", FAULTS)
def test_a_reply_with_a_structural_fault_is_counted_ignored_and_never_chained_to(fault):
    tamper, which = FAULTS[fault]
    master, slave = _by_hand()
    _cycle(master, slave, 0.0)  # HELLO and SYNC
    t = 0.5
    if which == "after a loss":
        _cycle(master, slave, t, deliver=False)  # a reply lost: the next poll asks for no image data
        t += 2.0
    if which == "steering":
        master.set_velocity(40, 0, 0, 0, t)
    chained_to, continuation, reference = master.chain.chain_to, master._continuation, master._reference
    errors, replies = master.master.stats.protocol_errors, master.master.stats.replies
    events = _cycle(master, slave, t, tamper)
    assert not any(isinstance(e, PoseReceived) for e in events)
    assert master.master.stats.replies == replies
    # Counted: a protocol error, or (too long for its poll's SIZE) never a start of a frame.
    assert master.master.stats.protocol_errors == errors + (fault != "a reply over its SIZE class")
    assert (master.chain.chain_to, master._continuation, master._reference) == (chained_to, continuation, reference)
    # The next poll is made on the reply before, and the link goes on.
    events = _cycle(master, slave, t + 2.0)
    assert any(isinstance(e, PoseReceived) for e in events)


def test_a_departed_pilots_wish_is_never_repeated_for_nobody_after_a_lost_reply():
    """§5 (decided, version 2): nobody's neutral never goes as a NONE that repeats the
    wish of the reply it is chained to: the vehicle a departed pilot was driving stops,
    and stays stopped while replies are lost."""
    from rovlink.link.radio.messages import Velocity
    from rovlink.link.radio.slave import VelocityCommanded

    master, slave = _by_hand()
    _cycle(master, slave, 0.0)  # HELLO and SYNC: the ROV holds (its start)
    master.set_pilot_in_force(True)
    master.set_velocity(0, 0, 0, 0, 0.5)
    master.recentred()
    t = 0.5
    for _ in range(3):  # the pilot re-centres, then drives
        _cycle(master, slave, t)
        master.set_velocity(60, 0, 0, 0, t)
        t += 0.5
    for _ in range(3):
        _cycle(master, slave, t)
        t += 0.5
    assert not master.master.last_reply.hold
    master.set_pilot_in_force(False)  # the pilot leaves: the console sets nobody's neutral
    master.set_velocity(0, 0, 0, 0, t)
    rov: list = []
    _cycle(master, slave, t, deliver=False, rov_events=rov)  # four zero axes reach the ROV; their reply is lost
    for k in range(4):  # each poll made on the reply to the last wish of the pilot, its reply lost too
        _cycle(master, slave, t + 0.8 * (k + 1), deliver=False, rov_events=rov)
    assert not any(isinstance(e, FailsafeEntered) for e in rov)
    commanded = [e.velocity for e in rov if isinstance(e, VelocityCommanded)]
    assert len(commanded) == 5 and all(v == Velocity() for v in commanded)


def test_a_trunk_past_the_objects_last_byte_is_found_before_the_chain_moves():
    from rovlink.link.radio.messages import Poll, ProtocolError
    from rovlink.link.radio.secure import parse_reply

    poll11 = Poll(img=1, offset=8189).encode()
    wire = bytes.fromhex("01 b0") + bytes(12)
    assert parse_reply(wire + b"ab", poll11, None)[1] == (1, 8191)  # bytes 8189 and 8190: the last
    with pytest.raises(ProtocolError):
        parse_reply(wire + b"abc", poll11, None)  # a third byte would be past 8190
