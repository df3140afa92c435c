"""Version 2 around the master and the slave (link/radio/secure.py): a session
runs; what an attacker records, forges or replays never reaches either
machine; a ROV restart is seen by its BOOT.  Simulated time, real channel."""

from __future__ import annotations

import random

from rovlink.link.emulators.channel import Channel, LinkParams
from rovlink.link.radio.master import Master, OrderAcknowledged, PoseReceived
from rovlink.link.radio.messages import Mode, Position
from rovlink.link.radio.secure import InauthenticFrame, SecureMaster, SecureSlave, Synced
from rovlink.link.radio.sim import SimLink
from rovlink.link.radio.slave import OrderExecuted, Slave, Status, VelocityCommanded

K = bytes(range(32))


def _source(img, settings):
    return bytes((img * 7 + i) % 251 for i in range(1500))


def _session(duration_s=60.0, seed=1, ber=0.0, order_at=None):
    master = SecureMaster(Master(rng=random.Random(seed)), K)
    slave = SecureSlave(Slave(image_source=_source), K)
    # An armed vehicle with a position estimate: a POSITION can be carried out.
    slave.slave.update_status(Status(armed=True, mode=Mode.MANUAL, autopilot=True, position_valid=True,
                               attitude_valid=True))
    channel = Channel(LinkParams(bitrate_bps=1900, delay_s=0.085, ber=ber), seed=seed)
    master_events, slave_events, polls = [], [], []
    link = SimLink(master, slave, channel, on_master_event=lambda e, t: master_events.append(e),
                   on_slave_event=lambda e, t: slave_events.append(e))
    real_send = channel.send

    def recording_send(side, data, now):
        if side == "a":
            polls.append(bytes(data))
        return real_send(side, data, now)

    channel.send = recording_send
    if order_at is not None:
        link.at(order_at, lambda t: master.send_order(Position(150, -50, 300, 0)))
    link.run_until(duration_s)
    return master, slave, link, master_events, slave_events, polls


def test_an_authenticated_session_carries_images_and_orders():
    master, slave, _, mev, sev, _ = _session(90.0, order_at=8.0)  # after the 3 s start rule
    assert master.stats2.syncs == 1 and master.stats2.hellos_sent >= 1
    assert master.master.stats.images_completed >= 5
    assert sum(isinstance(e, OrderExecuted) for e in sev) == 1
    assert sum(isinstance(e, OrderAcknowledged) for e in mev) == 1
    assert not any(isinstance(e, InauthenticFrame) for e in mev + sev)


def test_a_recorded_session_replayed_to_the_rov_moves_nothing():
    _, _, _, _, _, polls = _session(60.0, order_at=8.0)
    # The same ROV after the session, and a new ROV process with the same key.
    _, slave, _, _, _, _ = _session(1.0)
    for victim in (slave, SecureSlave(Slave(image_source=_source), K)):
        events = []
        replies = 0
        taken_before = victim.chain.counters.polls_taken
        for i, frame in enumerate(polls):
            out = victim.receive_bytes(frame, 100.0 + i * 0.4)
            events.extend(out.events)
            replies += out.reply is not None
        acted = [e for e in events if isinstance(e, (OrderExecuted, VelocityCommanded))]
        assert acted == []
        # At most a SYNC for each recorded HELLO a new process has not seen: no poll is answered.
        assert victim.chain.counters.polls_taken == taken_before
        assert replies <= sum(1 for f in polls if f[2] & 0x40)


def test_forged_and_bit_flipped_replies_never_reach_the_master():
    master, slave, link, mev, _, _ = _session(10.0)
    poses_before = sum(isinstance(e, PoseReceived) for e in mev)
    reply = slave.chain.seal_reply(bytes(14), slave.chain.check_poll(b"\0" * 10, 10.0) or _fake_poll(), 10.0)
    flipped = bytearray(reply)
    flipped[5] ^= 0x10
    events = master.receive_bytes(bytes(flipped), 10.1) + master.receive_bytes(reply, 10.2)
    assert sum(isinstance(e, PoseReceived) for e in events) == 0
    assert master.stats2.inauthentic >= 1
    assert sum(isinstance(e, PoseReceived) for e in mev) == poses_before


def _fake_poll():
    from rovlink.link.radio.auth import PollIn

    return PollIn(b"\x00\x1f\xff", 0, b"\x11" * 32, b"\x22" * 32, False)


def test_a_rov_restart_is_seen_by_its_boot():
    master = SecureMaster(Master(rng=random.Random(3)), K)
    slave = SecureSlave(Slave(image_source=_source), K)
    channel = Channel(LinkParams(bitrate_bps=1900, delay_s=0.085), seed=3)
    events = []
    link = SimLink(master, slave, channel, on_master_event=lambda e, t: events.append(e))
    link.run_until(20.0)

    def restart(t):
        link.slave = SecureSlave(Slave(image_source=_source, now=t), K)

    link.at(20.0, restart)
    link.run_until(40.0)
    synced = [e for e in events if isinstance(e, Synced)]
    assert [s.restarted for s in synced] == [False, True]
    assert synced[0].boot != synced[1].boot
    assert master.stats2.hellos_sent >= 2


def test_the_replies_handed_to_the_master_are_reported_without_their_tags():
    master = SecureMaster(Master(rng=random.Random(4)), K)
    slave = SecureSlave(Slave(image_source=_source), K)
    seen = []
    master.on_reply = lambda payload, sync, now: seen.append((payload, sync))
    link = SimLink(master, slave, Channel(LinkParams(bitrate_bps=1900, delay_s=0.085), seed=4))
    link.run_until(15.0)
    assert seen[0][1] is True and len(seen[0][0]) == 14  # the SYNC's reply payload
    assert all(not sync for _, sync in seen[1:]) and len(seen) > 5
    from rovlink.link.radio.messages import Reply

    assert all(Reply.decode(payload) for payload, _ in seen[1:])  # plain 1.1 replies


def test_after_a_rov_restart_an_unanswered_order_is_of_unknown_fate_and_not_resent():
    from rovlink.link.radio.master import OrderFateUnknown

    master = SecureMaster(Master(rng=random.Random(5)), K)
    armed = Status(armed=True, mode=Mode.MANUAL, autopilot=True, position_valid=True, attitude_valid=True)
    slave = SecureSlave(Slave(image_source=_source), K)
    slave.slave.update_status(armed)
    channel = Channel(LinkParams(bitrate_bps=1900, delay_s=0.085), seed=5)
    events, executed = [], []
    # The autopilot never answers: the order stays in progress (ACK not flipped).
    link = SimLink(master, slave, channel, on_master_event=lambda e, t: events.append(e),
                   on_slave_event=lambda e, t: executed.append(e), autopilot=lambda e, t: None)
    link.run_until(8.0)
    order_id = master.send_order(Position(100, 0, 200, 0))
    link.run_until(10.0)

    def restart(t):
        new = SecureSlave(Slave(image_source=_source, now=t), K)
        new.slave.update_status(armed)
        link.slave = new

    link.at(10.0, restart)
    link.run_until(25.0)
    unknown = [e for e in events if isinstance(e, OrderFateUnknown)]
    assert [e.order_id for e in unknown] == [order_id]
    assert any(isinstance(e, Synced) and e.restarted for e in events)
    # The new ROV never saw the order: it was not sent again.
    from rovlink.link.radio.slave import OrderStarted

    started_after = [e for e in executed if isinstance(e, OrderStarted)]
    assert len(started_after) == 1  # the old ROV's, before the restart
