"""SI to the wire and back, in link/ alone (issue 32): the console hands metres,
degrees and stick fractions to link.units and reads link.report's SI; neither a
reply's centimetres nor a STATUS's decimetres reach it."""

from __future__ import annotations

import pytest

from rovlink.link import acoustic as ac
from rovlink.link.radio.messages import Reply
from rovlink.link.report import report_from_reply, report_from_status
from rovlink.link.units import acoustic_goto, position_order, velocity_ints, wish_fractions


def test_wishes_become_velocity_integers_and_back():
    assert velocity_ints((1.0, -1.0, 0.5, 0.0)) == (127, -127, 64, 0)
    assert wish_fractions((127, -127, 0, 64)) == pytest.approx((1.0, -1.0, 0.0, 64 / 127))
    with pytest.raises(ValueError, match="vyaw"):
        velocity_ints((0.0, 0.0, 0.0, 1.5))


def test_position_orders_carry_centimetres_and_a_wrapped_yaw():
    p = position_order(1.234, -2.0, 3.0, 270.0, relative=False, body=False)
    assert (p.x_cm, p.y_cm, p.z_cm, p.yaw_cdeg) == (123, -200, 300, -9000)
    with pytest.raises(ValueError):
        position_order(400.0, 0.0, 0.0, 0.0, relative=False, body=False)  # past the int16 centimetres


def test_acoustic_go_tos_carry_decimetres_and_say_what_is_out_of_range():
    g = acoustic_goto(12.34, -5.0, 7.0, 190.0, relative=False, body=False)
    assert (g.x_dm, g.y_dm, g.z_dm, g.yaw_cdeg, g.yaw_set) == (123, -50, 70, -17000, True)
    assert not acoustic_goto(1.0, 0.0, 1.0, None, relative=True, body=True).yaw_set
    with pytest.raises(ValueError, match="x_m must be within"):
        acoustic_goto(5000.0, 0.0, 1.0, 0.0, relative=False, body=False)
    with pytest.raises(ValueError, match="BODY without RELATIVE"):
        acoustic_goto(1.0, 0.0, 1.0, 0.0, relative=False, body=True)


def test_a_status_reads_in_si_with_a_heading_and_no_tilt():
    s = ac.StatusBody(x_dm=15, y_dm=-7, z_dm=32, heading_cdeg=27000, armed=True, attitude_valid=True, position_valid=True,
                  autopilot=True, going=True, mode=5, battery_dv=158)
    r = report_from_status(s, sampled_at=10.0, arrived_at=13.0)
    assert (r.x_m, r.y_m, r.z_m, r.yaw_deg) == pytest.approx((1.5, -0.7, 3.2, -90.0))
    assert r.attitude_valid and not r.tilt_valid and r.going and r.battery_v == pytest.approx(15.8)
    assert (r.sampled_at, r.arrived_at, r.mode) == (10.0, 13.0, 5)


def test_a_reply_is_dated_by_its_own_frame_but_never_before_its_poll():
    reply = Reply(x_cm=150, yaw_cdeg=-4500, position_valid=True, trunk=b"x" * 96, img=1, offset=0, last=False)
    slow = report_from_reply(reply, arrived_at=100.0, frame_bytes=120, bitrate_bps=1900.0, delay_s=0.085)
    assert slow.sampled_at == pytest.approx(100.0 - 8 * 120 / 1900 - 0.085)
    assert (slow.x_m, slow.yaw_deg) == (1.5, -45.0)
    # The same reply over a link far faster than the bitrate it was told (loopback UDP):
    # its poll left 20 ms before it came, so the ROV sampled within those 20 ms.
    fast = report_from_reply(reply, arrived_at=100.0, frame_bytes=120, bitrate_bps=1900.0, delay_s=0.085,
                             round_trip_s=0.02)
    assert 99.98 <= fast.sampled_at <= 100.0
