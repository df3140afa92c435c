"""The predicted ghost integrates the wishes as they were sent, each from when it
reached the ROV, as the ROV applies them (issue 21 of the held stick): a stick
moved now changes nothing before its poll can have arrived, and under HOLD the
ignored stick predicts no motion.  A fake clock, the operator fed as its link
loop feeds it."""

from __future__ import annotations

import math

from rovlink.console.session.radio import Operator
from rovlink.link.radio.frame import encode_frame
from rovlink.link.radio.master import PollSent, PoseReceived
from rovlink.link.radio.messages import Mode, Poll, Reply, Stop, Velocity

from ..helpers import FakeClock


def _operator():
    clock = FakeClock()
    op = Operator(None, clock=clock)
    return op, clock


def _poll(op, clock, t, order) -> None:
    clock.t = t
    poll = Poll(seq=0, size=0, order=order, img=0, offset=8191)
    op.handle_events([PollSent(t, encode_frame(poll.encode()), poll)], t)


def _reply(op, clock, t, **kw) -> None:
    clock.t = t
    reply = Reply(armed=True, mode=Mode.DEPTH_HOLD, autopilot=True, position_valid=True, attitude_valid=True,
                  yaw_cdeg=-490, z_cm=300, **kw)
    op.handle_events([PoseReceived(reply, t, 0.3)], t)


def test_a_stick_moved_now_does_not_move_the_ghost_before_its_poll_can_arrive():
    op, clock = _operator()
    _poll(op, clock, 9.7, Velocity())
    _reply(op, clock, 10.0)
    _poll(op, clock, 10.0, Velocity())
    clock.t = 10.3
    before = op.predicted_pose(10.3)
    op.set_velocity(0.0, 0.0, 0.0, 1.0)  # full yaw, this instant
    moved = op.predicted_pose(10.3)
    assert (moved.x_m, moved.y_m, moved.yaw_deg) == (before.x_m, before.y_m, before.yaw_deg)
    assert abs(moved.yaw_deg - -4.9) < 1.0
    _poll(op, clock, 10.5, Velocity(vyaw=127))  # the wish leaves; it arrives ~0.13 s later
    clock.t = 11.0
    later = op.predicted_pose(11.0)
    turned = (later.yaw_deg - -4.9 + 180) % 360 - 180
    assert 0.0 < turned < 62 * 0.4  # at most the yaw rate over the time since it arrived


def test_under_hold_an_ignored_stick_predicts_no_motion_until_the_recentring_arrives():
    op, clock = _operator()
    _poll(op, clock, 9.7, Velocity(vx=100))
    _reply(op, clock, 10.0, hold=True)
    _poll(op, clock, 10.0, Velocity(vx=100))
    _poll(op, clock, 10.5, Velocity(vx=100))
    still = op.predicted_pose(11.5)
    assert math.hypot(still.x_m, still.y_m) < 0.01
    # The pilot re-centres, then pushes: the vehicle moves only from the push's arrival.
    _poll(op, clock, 11.0, Velocity())
    _poll(op, clock, 11.5, Velocity(vx=100))
    assert math.hypot(op.predicted_pose(11.5).x_m, 0) < 0.01
    assert op.predicted_pose(12.8).x_m > 0.1


def test_a_stop_sent_brakes_the_ghost_from_its_arrival():
    op, clock = _operator()
    _poll(op, clock, 9.7, Velocity(vx=127))
    _reply(op, clock, 10.0)
    _poll(op, clock, 10.0, Velocity(vx=127))
    free = op.predicted_pose(12.0)
    _poll(op, clock, 10.4, Stop())
    braked = op.predicted_pose(12.0)
    assert braked.x_m < free.x_m - 0.2


def test_against_the_truth_the_ghost_beats_the_received_pose_and_the_pilot_is_answered_fast():
    """The bench's session (simulated time): the real operator, slave and channel, the
    vehicle model as the truth, a pilot who steers and pauses while holding control."""
    from rovlink.console.bench.prediction import measure_prediction, prediction_targets

    result = measure_prediction(120.0, seed=3)
    assert result["samples"] > 500 and result["pauses"] >= 5
    targets = prediction_targets(result)
    assert targets["prediction_p95_below_received_at_every_age"]["met"], result["by_age"]
    assert targets["pose_age_not_steering_p95_le_1.5s"]["met"], result["pose_age_not_steering_s"]
    assert result["all"]["predicted_pos_m"][1] < result["all"]["received_pos_m"][1]
    # A couple of dozen pauses: the median is a behaviour, the p95 is the bench's to judge.
    assert result["first_wish_after_pause_s"][0] <= 0.5, result["first_wish_after_pause_s"]


def test_the_step_from_a_reply_without_a_position_to_the_first_real_one_is_no_speed():
    # At start the autopilot's estimate is not up: its replies say 0,0,0. The first real
    # pose 2 m down was read as metres per second (a 16 m ring, a ghost flying off).
    op, clock = _operator()
    clock.t = 10.0
    op.handle_events([PoseReceived(Reply(autopilot=True, position_valid=False), 10.0, 0.3)], 10.0)
    clock.t = 10.5
    op.handle_events([PoseReceived(Reply(autopilot=True, position_valid=True, attitude_valid=True, z_cm=200),
                                   10.5, 0.3)], 10.5)
    assert op.measured_velocity() == {"forward_mps": 0.0, "right_mps": 0.0, "down_mps": 0.0, "yaw_dps": 0.0}
    assert abs(op.predicted_pose(11.0).z_m - 2.0) < 0.05
