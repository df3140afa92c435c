"""A position order's fate after the ROV took it (issue 25 of the pilot's page): it
arrives, or is aborted by a STOP, a newer order, the ROV's FAILSAFE, a disarm or
the vehicle leaving GUIDED, and says how far it has left meanwhile.  A fake
clock, the operator fed as its link loop feeds it."""

from __future__ import annotations

from rovlink.console.session.fates import Fate
from rovlink.console.session.radio import Operator
from rovlink.link.radio.master import PoseReceived
from rovlink.link.radio.messages import Mode, Reply

from ..helpers import FakeClock


def _session():
    clock = FakeClock()
    clock.t = 10.0
    op = Operator(None, clock=clock)
    return op, clock


def _reply(op, clock, dt=0.5, *, x=0.0, y=0.0, z=2.0, yaw=0.0, mode=Mode.GUIDED, **kw):
    clock.t += dt
    reply = Reply(armed=kw.pop("armed", True), mode=mode, autopilot=True, position_valid=True, attitude_valid=True,
                  x_cm=round(x * 100), y_cm=round(y * 100), z_cm=round(z * 100), yaw_cdeg=round(yaw * 100), **kw)
    op.handle_events([PoseReceived(reply, op.now(), 0.3)], op.now())


def _acknowledge(op, order_id):
    op._settled(op.orders.last_master_id(), Fate.ACKNOWLEDGED, op.now())
    assert op.orders.get(order_id)["state"] == "acknowledged"


def _state(op, order_id):
    """The fate and its reason."""
    info = op.orders.get(order_id)
    return Fate(info["state"]), info["reason"]


def test_a_goto_says_its_distance_left_and_arrives():
    op, clock = _session()
    _reply(op, clock, mode=Mode.POS_HOLD)
    order_id = op.send_position(4.0, 3.0, 2.0, 90.0)
    _reply(op, clock, mode=Mode.POS_HOLD)
    assert op.orders.get(order_id)["distance_left_m"] == 5.0  # told before it is even taken
    _acknowledge(op, order_id)
    _reply(op, clock, x=2.0, y=1.5, yaw=45.0)
    info = op.orders.get(order_id)
    assert info["state"] == "acknowledged" and info["distance_left_m"] == 2.5
    _reply(op, clock, x=3.9, y=2.9, yaw=60.0)  # there, but not yet turned
    assert _state(op, order_id) == (Fate.ACKNOWLEDGED, "")
    _reply(op, clock, x=3.9, y=2.9, yaw=88.0)
    info = op.orders.get(order_id)
    assert info["state"] == "arrived" and info["t_arrived"] == op.now() and info["distance_left_m"] == 0.1
    assert [o for o in op.orders_state() if o["id"] == order_id][0]["state"] == "arrived"


def test_a_goto_is_aborted_by_stop_a_newer_order_failsafe_disarm_or_leaving_guided():
    op, clock = _session()
    _reply(op, clock)

    def acknowledged_goto():
        order_id = op.send_position(10.0, 0.0, 2.0)
        _acknowledge(op, order_id)
        _reply(op, clock, x=1.0)
        return order_id

    first = acknowledged_goto()
    op.stop()
    assert _state(op, first) == (Fate.ABORTED, "STOP")

    second = acknowledged_goto()
    third = op.send_position(0.0, 10.0, 2.0)
    assert _state(op, second) == (Fate.ABORTED, f"replaced by position order #{third}")
    _acknowledge(op, third)
    _reply(op, clock, x=1.0, failsafe=True)
    assert _state(op, third) == (Fate.ABORTED, "the ROV went into FAILSAFE (it braked and holds)")

    fourth = acknowledged_goto()
    _reply(op, clock, x=1.5, armed=False)
    assert _state(op, fourth) == (Fate.ABORTED, "the vehicle is disarmed")

    fifth = acknowledged_goto()  # its replies show GUIDED
    _reply(op, clock, x=2.0, mode=Mode.POS_HOLD)
    assert _state(op, fifth) == (Fate.ABORTED, "the vehicle left GUIDED for POS_HOLD")
    # None of these is an alert: the pilot or the ROV's own failsafe (alerted on its own) ended it.
    assert not [e for e in op.log_entries() if e["level"] == "alert" and "POSITION" in e["text"]]


def test_a_relative_goto_goes_from_the_pose_it_was_given_at():
    op, clock = _session()
    _reply(op, clock, x=5.0, y=5.0, yaw=90.0)
    order_id = op.send_position(2.0, 0.0, 0.0, 0.0, relative=True, body=True)  # 2 m ahead, facing east
    _acknowledge(op, order_id)
    _reply(op, clock, x=5.0, y=7.0, yaw=90.0)
    assert _state(op, order_id) == (Fate.ARRIVED, "")


def test_without_a_picture_the_pilot_is_told_why():
    from rovlink.link.radio.master import ImageProgress

    op, clock = _session()
    clock.t += 1.0
    assert op.image_state()["waiting"] == "waiting for the ROV's first reply"
    clock.t += 9.0
    assert op.image_state()["waiting"] == "no picture: the link is lost"
    _reply(op, clock)
    said = [op.image_state()["waiting"]]
    assert said[-1].startswith("the ROV is preparing its first picture"), said
    op.protocol_master._image.data[:] = bytes(40)  # the master receives a first picture it will not show
    said.append(op.image_state()["waiting"])
    assert said[-1] == ("the ROV is sending a picture it took before this session (40 B so far): it may be old, "
                        "so it is not shown; the first fresh picture comes right after it")
    op.handle_events([ImageProgress(1, 60, 300, bytes(58))], op.now())
    said.append(op.image_state()["waiting"])
    assert said[-1].startswith("the first picture's first bytes are in: it shows as soon as"), said
    # Words for a pilot: what is happening and what comes next, no reference to a document.
    for text in said:
        assert "docs/" not in text and "§" not in text and "PROTOCOL" not in text and "unknown age" not in text, text
        assert "first" in text and ("comes" in text or "shows" in text), text
    op.set_image_settings(budget_bytes=0)
    assert op.image_state()["waiting"].startswith("pictures are off")
