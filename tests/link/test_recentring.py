"""Only a pilot's own re-centring releases the ROV's HOLD (docs/PROTOCOL.md §5,
(decided); issue 21 of the held stick): nobody's neutral goes out as ORDER NONE
while the ROV holds, and a pilot's re-centring reaches the ROV even when the
sticks move again before the next poll.  The real master and slave in
simulated time."""

from __future__ import annotations

import dataclasses
import random

import pytest

from rovlink.link.emulators.channel import Channel, LinkParams
from rovlink.link.radio.master import Master
from rovlink.link.radio.messages import Mode, NoOrder, Poll, Stop, Velocity
from rovlink.link.radio.secure import SecureMaster, SecureSlave
from rovlink.link.radio.sim import SimLink
from rovlink.link.radio.slave import Slave, Status, VelocityCommanded

ARMED = Status(armed=True, mode=Mode.POS_HOLD, autopilot=True, position_valid=True, attitude_valid=True)


def _link(seed=1):
    master = Master(rng=random.Random(seed), images=False)
    slave = Slave()
    slave.update_status(ARMED)
    polls: list[tuple[float, object]] = []
    applied: list[tuple[float, Velocity]] = []

    def on_slave(event, t):
        if isinstance(event, VelocityCommanded):
            applied.append((t, event.velocity))

    link = SimLink(master, slave, Channel(LinkParams(bitrate_bps=1900, delay_s=0.085), seed=seed),
                   on_slave_event=on_slave)
    real = link.channel.send

    def watch(side, data, now):
        if side == "a":
            polls.append((now, Poll.decode(data[2:-2]).order))
        return real(side, data, now)

    link.channel.send = watch
    return master, slave, link, polls, applied


def test_a_console_that_starts_with_nobody_in_control_never_releases_the_start_hold():
    master, slave, link, polls, applied = _link()
    master.set_pilot_in_force(False)  # the desk: nobody holds control
    link.run_until(20.0)
    assert slave.hold  # the ROV's start HOLD stands
    assert polls and all(isinstance(o, NoOrder) for _, o in polls)
    assert not any(isinstance(o, Velocity) for _, o in polls)


def test_nobodys_neutral_is_a_velocity_when_the_rov_is_not_holding():
    """A pilot gone while driving: the vehicle must stop at once, not after the 1.5 s lapse."""
    master, slave, link, polls, applied = _link(2)
    link.run_until(2.0)
    master.recentred()
    link.run_until(4.0)  # the pilot's neutral released the start HOLD
    assert not slave.hold
    master.set_velocity(80, 0, 0, 0, 4.0)
    link.run_until(6.0)
    master.set_velocity(0, 0, 0, 0, 6.0)
    master.set_pilot_in_force(False)  # the holder's page closed
    link.run_until(8.0)
    after = [o for t, o in polls if t > 6.0]
    assert after and isinstance(after[0], Velocity) and after[0].is_neutral
    assert applied[-1][1].is_neutral


def test_a_recentring_between_polls_reaches_the_rov_and_releases_hold():
    """HOLD up; the pilot centres and pushes again before the next poll leaves: the
    next VELOCITY polls carry zero axes until one is answered, then the push."""
    master, slave, link, polls, applied = _link(3)
    master.set_velocity(60, 0, 0, 0, 0.0)
    link.run_until(3.0)
    assert slave.hold and all(v.is_neutral for _, v in applied)  # the held stick is ignored
    master.set_velocity(0, 0, 0, 0, 3.0)
    master.recentred()
    master.set_velocity(60, 0, 0, 0, 3.01)  # pushed again at once
    link.run_until(6.0)
    sent = [o for t, o in polls if t >= 3.0 and isinstance(o, Velocity)]
    assert sent[0].is_neutral  # the re-centring went out first
    assert not slave.hold
    assert any(v.vx == 60 for _, v in applied)  # and then the push drove


def test_a_console_neutral_after_stop_is_not_a_recentring():
    """STOP with the stick held: the console sets the wish neutral, but only the
    pilot's own re-centring (recentred) releases the HOLD the STOP set."""
    master, slave, link, polls, applied = _link(4)
    master.recentred()
    link.run_until(5.0)
    master.send_order(Stop())
    master.set_velocity(0, 0, 0, 0, 5.0)  # the desk's neutral at STOP ...
    master.set_pilot_in_force(False)  # ... and the holder's stick no longer counts
    link.run_until(10.0)
    assert slave.hold
    master.set_pilot_in_force(True)
    master.recentred()
    link.run_until(12.0)
    assert not slave.hold


@pytest.mark.parametrize("v2", [False, True])
@pytest.mark.parametrize("what", ["stop", "outage"])
def test_nobodys_neutral_never_releases_a_hold_set_while_the_pilot_was_centred(v2, what):
    """The pilot centred, then a STOP or a link outage past the failsafe sets HOLD and the
    pilot leaves. Version 2 repeats the chained reply's wish for a NONE poll (§8.1); a
    STOP's reply carries no wish and the failsafe ends the chain (a SYNC has none), so
    nobody's NONE stays a NONE there too, and the HOLD stands."""
    key = bytes(range(32))
    inner, slave = Master(rng=random.Random(5), images=False), Slave()
    slave.update_status(ARMED)
    master = SecureMaster(inner, key) if v2 else inner
    channel = Channel(LinkParams(bitrate_bps=1900, delay_s=0.085), seed=5)
    link = SimLink(master, SecureSlave(slave, key) if v2 else slave, channel)
    link.run_until(3.0)
    master.recentred()
    link.run_until(5.0)
    assert not slave.hold  # the pilot's centring released the start HOLD; the sticks stay centred
    if what == "stop":
        master.send_order(Stop())
        master.set_pilot_in_force(False)  # and the holder's page closes
    else:
        for side in "ab":
            channel.params[side] = dataclasses.replace(channel.params[side], loss=1.0)
        link.run_until(9.0)  # past the 3 s failsafe
        assert slave.hold and slave.failsafe
        master.set_pilot_in_force(False)
        for side in "ab":
            channel.params[side] = dataclasses.replace(channel.params[side], loss=0.0)
    link.run_until(25.0)
    assert slave.hold and not slave.failsafe  # the link is back, the HOLD stands
