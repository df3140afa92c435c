"""The request/ack/resend tracker, the telemetry's freshness and the GUIDED driver,
driven with a fake clock (no sockets, no threads)."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from rovlink.link.radio.messages import Reason
from rovlink.rov.ardusub import PROTOCOL_TO_SUB, SubMode, protocol_mode, sub_mode
from rovlink.rov.commands import CommandTracker, GotoTicket, Ticket
from rovlink.rov.goto import GotoDriver, GotoOrder
from rovlink.rov.telemetry import AutopilotSnapshot, Telemetry

SET_MODE = mavlink.MAV_CMD_DO_SET_MODE
ARM = mavlink.MAV_CMD_COMPONENT_ARM_DISARM
OK, FAILED, IN_PROGRESS = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_FAILED, mavlink.MAV_RESULT_IN_PROGRESS


# --- the tracker ---------------------------------------------------------------


def test_a_request_is_sent_at_once_then_every_half_second_until_acknowledged():
    tracker = CommandTracker()
    ticket = Ticket("mode")
    tracker.mode(ticket, SubMode.POSHOLD, now=10.0)
    sent = [t for t in (10.0, 10.2, 10.5, 10.7, 11.0) if tracker.due(t)]
    assert sent == [10.0, 10.5, 11.0]
    (request,) = tracker.requests
    assert request.command == SET_MODE and request.params[:2] == (1.0, float(SubMode.POSHOLD))
    assert tracker.on_ack(SET_MODE, OK, 11.1) is request
    assert ticket.status == Ticket.ACCEPTED and not tracker.requests
    assert tracker.due(11.6) == []


def test_an_answer_to_a_resend_of_a_request_that_is_over_is_not_taken_as_a_newer_ones():
    """MAVLink's ACK names only the command.  A POSHOLD sent twice (its first answer late,
    a loaded machine) is refused twice; the brake's ALT_HOLD, sent after the first
    refusal, must not be failed by the second (a newcomer's run saw exactly that)."""
    tracker = CommandTracker()
    poshold, alt_hold = Ticket("mode POSHOLD"), Ticket("mode ALT_HOLD")
    tracker.mode(poshold, SubMode.POSHOLD, now=0.0)
    assert tracker.due(0.0) and tracker.due(0.5)  # sent, then sent again
    tracker.on_ack(SET_MODE, FAILED, 0.6, "POSHOLD requires position")
    assert poshold.status == Ticket.FAILED
    tracker.mode(alt_hold, SubMode.ALT_HOLD, now=0.6)
    assert tracker.due(0.6)
    assert tracker.on_ack(SET_MODE, FAILED, 0.65, "POSHOLD requires position") is None  # the resend's
    assert alt_hold.status == Ticket.PENDING
    assert tracker.on_ack(SET_MODE, OK, 0.7) is not None
    assert alt_hold.status == Ticket.ACCEPTED


def test_a_refusal_fails_the_request_as_reason_2_with_the_autopilots_words():
    tracker = CommandTracker()
    ticket = Ticket("mode")
    tracker.mode(ticket, SubMode.GUIDED, now=0.0)
    tracker.due(0.0)
    tracker.on_ack(SET_MODE, FAILED, 0.05, "GUIDED requires position")
    assert ticket.status == Ticket.FAILED and ticket.reject_reason == Reason.REFUSED
    assert "GUIDED requires position" in ticket.reason


def test_no_answer_within_2_s_is_reason_2_and_no_autopilot_is_reason_1():
    tracker = CommandTracker()
    silent, other = Ticket("arm"), Ticket("mode")
    tracker.arm(silent, True, now=0.0)
    tracker.mode(other, SubMode.MANUAL, now=0.0)
    tracker.due(0.0)
    assert tracker.expire(1.99, reachable=True) == []
    assert silent.status == Ticket.PENDING
    # Both past the deadline while the autopilot is there: it did not answer.
    tracker.expire(2.0, reachable=True)
    assert silent.reject_reason == Reason.REFUSED and other.reject_reason == Reason.REFUSED
    later = Ticket("arm")
    tracker.arm(later, False, now=5.0)
    tracker.expire(7.0, reachable=False)
    assert later.status == Ticket.FAILED and later.reject_reason == Reason.IMPOSSIBLE


def test_in_progress_stops_the_resends_and_a_later_answer_still_counts():
    tracker = CommandTracker()
    ticket = Ticket("arm")
    tracker.arm(ticket, True, now=0.0)
    tracker.due(0.0)
    tracker.on_ack(ARM, IN_PROGRESS, 0.1)
    assert tracker.due(1.0) == [] and ticket.status == Ticket.PENDING
    tracker.on_ack(ARM, OK, 1.2)
    assert ticket.status == Ticket.ACCEPTED


def test_an_arm_in_progress_is_the_autopilots_to_finish_not_refused_at_2_s():
    """A vehicle that answers ARM "in progress" and arms seconds later is accepted
    then, by its heartbeat; it is failed only after 30 s without finishing."""
    tracker = CommandTracker()
    late, never = Ticket("arm"), Ticket("mode")
    tracker.arm(late, True, now=0.0)
    tracker.mode(never, int(SubMode.ALT_HOLD), now=0.0)
    tracker.due(0.0)
    tracker.on_ack(ARM, IN_PROGRESS, 0.1)
    tracker.on_ack(SET_MODE, IN_PROGRESS, 0.1)
    assert tracker.expire(2.0, reachable=True) == [] and late.status == never.status == Ticket.PENDING
    tracker.on_state(True, None)  # the heartbeat shows it armed, 4.9 s on
    assert late.status == Ticket.ACCEPTED
    assert tracker.expire(29.9, reachable=True) == [] and never.status == Ticket.PENDING
    tracker.expire(30.0, reachable=True)
    assert never.status == Ticket.FAILED and "did not finish within 30 s" in never.reason


def test_the_heartbeat_accepts_a_request_whose_ack_was_lost_but_only_once_sent():
    tracker = CommandTracker()
    ticket = Ticket("arm")
    tracker.arm(ticket, True, now=0.0)
    tracker.on_state(armed=True, custom_mode=19)  # not sent yet: not our doing
    assert ticket.status == Ticket.PENDING
    tracker.due(0.0)
    tracker.on_state(armed=True, custom_mode=19)
    assert ticket.status == Ticket.ACCEPTED


def test_a_newer_request_of_the_same_kind_cancels_the_older():
    tracker = CommandTracker()
    first, second, arm = Ticket("mode"), Ticket("mode"), Ticket("arm")
    tracker.mode(first, SubMode.GUIDED, 0.0)
    tracker.arm(arm, True, 0.0)
    tracker.mode(second, SubMode.ALT_HOLD, 0.1)
    assert first.status == Ticket.CANCELLED and arm.status == Ticket.PENDING
    assert [r.ticket for r in tracker.requests] == [arm, second]


def test_an_ack_for_a_command_never_sent_resolves_nothing():
    tracker = CommandTracker()
    ticket = Ticket("mode")
    tracker.mode(ticket, SubMode.GUIDED, 0.0)
    assert tracker.on_ack(SET_MODE, OK, 0.01) is None  # a stale answer to someone else
    assert ticket.status == Ticket.PENDING


# --- modes ---------------------------------------------------------------------


def test_the_protocol_modes_map_onto_ardusubs_by_name():
    assert [PROTOCOL_TO_SUB[n].name for n in range(1, 7)] == [
        "MANUAL", "STABILIZE", "ALT_HOLD", "POSHOLD", "GUIDED", "SURFACE",
    ]
    assert sub_mode("POS_HOLD") == sub_mode("poshold") == SubMode.POSHOLD
    assert protocol_mode(SubMode.ACRO) == 7 and protocol_mode(None) == 0
    with pytest.raises(ValueError):
        sub_mode(0)


# --- telemetry -------------------------------------------------------------------


def _snap(telemetry: Telemetry, now: float) -> AutopilotSnapshot:
    return telemetry.snapshot(now, connected=True, failsafe=False)


def test_attitude_and_position_are_valid_for_one_second():
    t = Telemetry()
    t.on_heartbeat(1, False, 19, 0.0)
    assert not _snap(t, 0.0).attitude_valid and _snap(t, 0.0).attitude_age_s is None
    t.on_attitude(0.1, 0.2, 0.3, 0.0, 0.1)
    t.on_position(1.0, 2.0, 3.0, 0, 0, 0, 0.1)
    snap = _snap(t, 1.05)
    assert snap.attitude_valid and snap.position_valid and snap.attitude_age_s == pytest.approx(0.95)
    snap = _snap(t, 1.1)
    assert not snap.attitude_valid and not snap.position_valid
    assert snap.yaw_rad == 0.3  # the value stays, shown as stale


def test_after_an_autopilot_loss_old_attitude_is_never_valid_again():
    t = Telemetry()
    t.on_heartbeat(1, True, 19, 0.0)
    t.on_attitude(0.0, 0.0, 1.0, 0.0, 2.9)
    assert _snap(t, 2.95).attitude_valid
    assert not _snap(t, 3.05).autopilot_alive and not _snap(t, 3.05).attitude_valid
    # The autopilot is back (a restart): its first heartbeat does not revive the old attitude.
    assert t.on_heartbeat(1, False, 19, 3.2) is True
    snap = _snap(t, 3.2)
    assert snap.autopilot_alive and not snap.attitude_valid and not snap.position_valid
    t.on_attitude(0.0, 0.0, -2.0, 0.0, 3.3)
    assert _snap(t, 3.3).attitude_valid and _snap(t, 3.3).yaw_rad == -2.0


def test_a_closed_connection_loses_the_autopilot_at_once():
    t = Telemetry()
    t.on_heartbeat(1, True, 19, 0.0)
    t.on_attitude(0.0, 0.0, 1.0, 0.0, 0.0)
    t.lost()
    snap = _snap(t, 0.1)
    assert not snap.autopilot_alive and not snap.attitude_valid and not snap.armed and snap.mode == 0


def test_the_mode_follows_an_accepted_mode_change_before_the_next_heartbeat():
    t = Telemetry()
    t.on_heartbeat(1, False, SubMode.MANUAL, 0.0)
    t.on_mode_accepted(SubMode.ALT_HOLD, 0.3)
    assert _snap(t, 0.3).mode == 3
    t.on_heartbeat(1, False, SubMode.ALT_HOLD, 1.0)
    assert _snap(t, 1.0).mode == 3


# --- the GUIDED driver ---------------------------------------------------------------


def _ready(**changes) -> AutopilotSnapshot:
    base = dict(autopilot_alive=True, armed=True, position_valid=True, custom_mode=int(SubMode.MANUAL),
                x_m=1.0, y_m=2.0, z_m=3.0, yaw_rad=math.pi / 2)
    base.update(changes)
    return AutopilotSnapshot(**base)


@pytest.mark.parametrize(
    "snap, words",
    [
        (_ready(armed=False), "disarmed"),
        (_ready(position_valid=False), "position"),
        (_ready(autopilot_alive=False), "autopilot"),
    ],
)
def test_a_goto_that_cannot_work_is_refused_at_once_as_reason_1(snap, words):
    tracker = CommandTracker()
    driver = GotoDriver(tracker)
    ticket = GotoTicket()
    driver.start(ticket, GotoOrder(1.0, 0.0, 3.0), snap, 0.0)
    assert ticket.status == Ticket.FAILED and ticket.reject_reason == Reason.IMPOSSIBLE and words in ticket.reason
    assert tracker.requests == [] and driver.active is None


def test_a_goto_asks_for_guided_then_sends_the_resolved_target_every_second():
    tracker = CommandTracker()
    driver = GotoDriver(tracker)
    ticket = GotoTicket()
    driver.start(ticket, GotoOrder(1.0, 0.0, 0.5, 0.0, relative=True, body=True), _ready(), 0.0)
    assert ticket.target == pytest.approx((1.0, 3.0, 3.5, math.pi / 2))  # facing east: forward is east
    (request,) = tracker.due(0.0)
    assert request.params[1] == SubMode.GUIDED
    assert driver.step(_ready(), 0.1) is None  # not GUIDED yet: no target
    tracker.on_ack(SET_MODE, OK, 0.1)
    guided = _ready(custom_mode=int(SubMode.GUIDED))
    assert driver.step(guided, 0.1) == ticket.target and ticket.status == Ticket.ACCEPTED
    assert driver.step(guided, 0.6) is None
    assert driver.step(guided, 1.1) == ticket.target
    # The autopilot leaves GUIDED by itself: the order is over.
    assert driver.step(_ready(custom_mode=int(SubMode.MANUAL)), 1.5) is None and driver.active is None


def test_guided_refused_fails_the_goto_as_reason_2():
    tracker = CommandTracker()
    driver = GotoDriver(tracker)
    ticket = GotoTicket()
    driver.start(ticket, GotoOrder(1.0, 0.0, 3.0), _ready(), 0.0)
    tracker.due(0.0)
    tracker.on_ack(SET_MODE, FAILED, 0.05, "GUIDED requires position")
    driver.step(_ready(), 0.05)
    assert ticket.status == Ticket.FAILED and ticket.reject_reason == Reason.REFUSED
    assert "GUIDED requires position" in ticket.reason


def test_a_guided_accepted_after_the_2_s_makes_the_driver_ask_for_a_brake():
    tracker = CommandTracker()
    driver = GotoDriver(tracker)
    ticket = GotoTicket()
    driver.start(ticket, GotoOrder(1.0, 0.0, 3.0), _ready(), 0.0)
    tracker.due(0.0)
    tracker.expire(2.0, reachable=True)
    driver.step(_ready(), 2.0)
    assert ticket.status == Ticket.FAILED and ticket.reject_reason == Reason.REFUSED
    assert not driver.brake_wanted
    driver.step(_ready(custom_mode=int(SubMode.GUIDED)), 2.5)  # the late answer: nobody flies it
    assert driver.brake_wanted


def test_a_newer_goto_after_a_failed_one_is_not_braked_by_the_late_answer():
    tracker = CommandTracker()
    driver = GotoDriver(tracker)
    driver.start(GotoTicket(), GotoOrder(1.0, 0.0, 3.0), _ready(), 0.0)
    tracker.due(0.0)
    tracker.expire(2.0, reachable=True)
    driver.step(_ready(), 2.0)
    newer = GotoTicket()
    driver.start(newer, GotoOrder(2.0, 0.0, 3.0), _ready(), 2.2)
    driver.step(_ready(custom_mode=int(SubMode.GUIDED)), 2.5)
    assert not driver.brake_wanted and newer.status == Ticket.ACCEPTED
