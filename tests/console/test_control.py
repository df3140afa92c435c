"""The one command layer: its permission table, its effects on the wish and
the recording, and what the console serves from it (GET /api/config, GET
/api/link).  An Operator without a link (its orders still reach the link
master; replies are handed to it as the link loop would) under a clock the
test moves, and the web app over FastAPI's TestClient."""

from __future__ import annotations

import json
import time

import pytest

from rovlink.console import control
from rovlink.console.control import PERMISSION, Caller, ControlDesk, NotHolder, Replaying
from rovlink.console.session.fates import Fate
from rovlink.console.session.radio import Operator
from rovlink.console.web.app import create_app
from rovlink.link.radio.frame import encode_frame
from rovlink.link.radio.master import PollSent, PoseReceived, ReplyLost, RequestExpired
from rovlink.link.radio.messages import Mode, Poll, Reply, Velocity

from ..helpers import FakeClock, local_test_client

HEADER = "X-Rovlink-Client"
KEY = "k" * 32

# One example of every order the console knows.
EXAMPLES = [control.Arm(True), control.SetMode("DEPTH_HOLD"), control.Drive(0.3), control.GoTo(1.0, 2.0, 3.0),
            control.PreviewTarget(1.0, 1.0, 2.0), control.ClearTarget(), control.SendTarget(),
            control.ChangeImage(budget_bytes=1500), control.NextImage(), control.CancelStop(), control.Stop(),
            control.FollowRoi((10, 10, 50, 50), keep=True, drawn_on=1), control.FrameObject(1)]


@pytest.fixture
def clock():
    return FakeClock(100.0)


@pytest.fixture
def operator(clock, tmp_path):
    op = Operator(None, clock=clock, record=tmp_path / "session.jsonl")
    yield op
    op.close()


def take_centred(desk, client_id):
    """Take control as a page does: it sends its input as it is then, here neutral
    (the page's own re-centring, after which its drive is in force)."""
    desk.take(client_id)
    desk.submit(control.Drive(), Caller(client_id))


def reply_at(operator, clock, **fields) -> None:
    """A reply arrives now, as the link loop hands it over."""
    operator.handle_events([PoseReceived(Reply(autopilot=True, position_valid=True, **fields), operator.now(), 0.1)],
                        operator.now())


def test_every_order_has_one_permission_and_stop_alone_is_open_to_all():
    assert set(PERMISSION) == {type(o) for o in EXAMPLES}
    assert [t.__name__ for t, who in PERMISSION.items() if who == control.ANYONE] == ["Stop"]


def test_the_permission_table_decides_for_every_caller(operator, clock):
    desk = ControlDesk(operator, clock=clock)
    pilot = desk.connect("pilot", scene_key=KEY)
    watcher = desk.connect("watcher", scene_key="w" * 32)
    take_centred(desk, pilot.id)
    callers = {"pilot": Caller(pilot.id), "pilot's scene": Caller(scene_key=KEY, via="scene"),
               "watcher": Caller(watcher.id), "watcher's scene": Caller(scene_key="w" * 32, via="scene"),
               "a scene opened alone": Caller(via="scene"), "nobody": Caller()}
    for order in EXAMPLES:
        for name, caller in callers.items():
            allowed = name.startswith("pilot") or isinstance(order, control.Stop)
            assert (desk.refusal(order, caller) is None) == allowed, (order, name)
    with pytest.raises(NotHolder, match="held by pilot"):
        desk.submit(control.Drive(0.5), callers["watcher"])
    assert operator.velocity_wish() == (0.0, 0.0, 0.0, 0.0)
    operator.replaying = True
    for order in EXAMPLES:
        with pytest.raises(Replaying):
            desk.submit(order, callers["pilot"])


def test_wishes_go_neutral_after_stop_a_change_of_holder_a_lost_holder_and_nobody(operator, clock):
    desk = ControlDesk(operator, clock=clock, lease_s=5.0)
    a, b = desk.connect("a"), desk.connect("b")
    take_centred(desk, a.id)
    desk.submit(control.Drive(0.5, 0.2), Caller(a.id))
    desk.submit(control.Stop(), Caller(b.id))  # anyone may stop
    assert operator.velocity_wish() == (0.0, 0.0, 0.0, 0.0)
    desk.submit(control.Drive(0.5), Caller(a.id))  # a's stick still forward after the STOP: no drive
    assert operator.velocity_wish() == (0.0, 0.0, 0.0, 0.0)
    assert desk.status(a.id)["centre_to_drive"]

    desk.submit(control.Drive(), Caller(a.id))  # centred
    desk.submit(control.Drive(0.5), Caller(a.id))
    take_centred(desk, b.id)  # a change of holder
    assert operator.velocity_wish() == (0.0, 0.0, 0.0, 0.0)

    desk.submit(control.Drive(vyaw=0.4), Caller(b.id))
    desk.disconnect(b.id)  # the holder's page is gone
    assert operator.velocity_wish() == (0.0, 0.0, 0.0, 0.0)

    # A wish set behind the desk's back with nobody in control: the next tick ends it.
    operator.set_velocity(0.3, 0.0, 0.0, 0.0)
    desk.tick()
    assert operator.velocity_wish() == (0.0, 0.0, 0.0, 0.0)

    # Every change is in the recording, the neutral ones too (Fig. 5).
    operator.close()
    wishes = [r["v"] for r in map(json.loads, open(operator.recorder.path)) if r["k"] == "wish"]
    assert wishes == [[64, 25, 0, 0], [0, 0, 0, 0], [64, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 51], [0, 0, 0, 0],
                      [38, 0, 0, 0], [0, 0, 0, 0]]


def test_a_key_press_drives_only_for_the_dead_mans_time(operator, clock):
    desk = ControlDesk(operator, clock=clock, deadman_s=1.0)
    pilot = desk.connect("pilot", scene_key=KEY)
    take_centred(desk, pilot.id)
    desk.submit(control.Drive(0.5, streamed=True), Caller(scene_key=KEY, via="scene"))
    clock.t += 0.5
    desk.tick()
    assert operator.velocity_wish()[0] == 0.5
    clock.t += 0.6
    desk.tick()
    assert operator.velocity_wish() == (0.0, 0.0, 0.0, 0.0)


def test_unattended_armed_vehicle_warns_and_disarms_when_configured(operator, clock):
    desk = ControlDesk(operator, clock=clock, unattended_warn_s=60.0, disarm_unattended_s=120.0)
    pilot = desk.connect("pilot")
    take_centred(desk, pilot.id)
    reply_at(operator, clock, armed=True, mode=Mode.MANUAL)
    desk.disconnect(pilot.id)
    assert desk.status()["unattended_s"] == 0.0 and not desk.status()["unattended_warning"]
    clock.t += 61.0
    reply_at(operator, clock, armed=True, mode=Mode.MANUAL)
    desk.tick()
    assert desk.status()["unattended_warning"]
    assert not any(o["kind"] == "DISARM" for o in operator.orders_state())
    clock.t += 60.0
    desk.tick()
    assert [o["kind"] for o in operator.orders_state()] == ["DISARM"]


def test_arm_and_mode_requests_show_their_fate(operator, clock):
    armed = operator.arm(True)
    mode = operator.set_mode("DEPTH_HOLD")
    clock.t += 1.0
    reply_at(operator, clock, armed=True, mode=Mode.MANUAL)  # armed, but the mode did not change
    fates = {o["id"]: o for o in operator.orders_state()}
    assert fates[armed]["state"] == Fate.FOLLOWED and fates[mode]["state"] == Fate.REQUESTED
    # The link stops repeating the request (§2's 3 s): the mode waits, still watched, never refused.
    operator.handle_events([RequestExpired("mode")], operator.now())
    clock.t += 30.0
    reply_at(operator, clock, armed=True, mode=Mode.MANUAL)
    waiting = {o["id"]: o for o in operator.orders_state()}[mode]
    assert waiting["state"] == Fate.WAITING and waiting["outcome"] == "pending", waiting
    assert not any(e["level"] == "alert" for e in operator.log_entries(50)), operator.log_entries(50)
    # The vehicle follows late: the order says so, and the log.
    clock.t += 2.0
    reply_at(operator, clock, armed=True, mode=Mode.DEPTH_HOLD)
    followed = {o["id"]: o for o in operator.orders_state()}[mode]
    assert followed["state"] == Fate.FOLLOWED and followed["outcome"] == "done"
    assert followed["reason"] == "33.0 s after it was asked"
    assert any("followed after all" in e["text"] for e in operator.log_entries(50))
    operator.close()
    recorded = [(r["state"], r["reason"]) for r in map(json.loads, open(operator.recorder.path)) if r["k"] == "order_state"]
    assert recorded == [("followed", ""), ("waiting", "the link repeated it for its 3 s"),
                        ("followed", "33.0 s after it was asked")]


def test_a_newer_request_cancels_the_one_that_waits(operator, clock):
    first = operator.set_mode("DEPTH_HOLD")
    operator.handle_events([RequestExpired("mode")], operator.now())
    second = operator.set_mode("POS_HOLD")
    fates = {o["id"]: o for o in operator.orders_state()}
    assert (fates[first]["state"], fates[first]["reason"]) == (Fate.CANCELLED, "superseded by a newer request")
    clock.t += 1.0
    reply_at(operator, clock, mode=Mode.DEPTH_HOLD)  # the first one's mode: no longer watched
    fates = {o["id"]: o for o in operator.orders_state()}
    assert fates[first]["state"] == Fate.CANCELLED and fates[second]["state"] == Fate.REQUESTED


def test_link_state_comes_from_replies(operator, clock):
    app = create_app(operator, rov_failsafe_s=3.4)  # lost after 3 s, in FAILSAFE after 3.4 s
    with local_test_client(app) as http:
        reply_at(operator, clock)
        link = http.get("/api/link").json()
        assert link["state"] == "up" and link["since_reply_s"] == pytest.approx(0.0)
        # Three polls of the four in the window unanswered: degraded, and said why.
        operator.handle_events([ReplyLost(operator.now(), operator.now())] * 3, operator.now())
        clock.t += 1.0
        link = http.get("/api/link").json()
        assert link["state"] == "degraded" and link["since_reply_s"] == pytest.approx(1.0)
        assert link["degraded_short"] == "75% lost" and link["degraded_reason"].startswith("3 of 4 replies lost")
        clock.t += 2.0
        link = http.get("/api/link").json()
        assert link["state"] == "lost" and not link["failsafe_inferred"] and not link["link_up"]
        clock.t += 0.5
        link = http.get("/api/link").json()
        assert link["failsafe_inferred"] and len(link["failsafe_inferred_since"]) == 8  # HH:MM:SS
        pose = http.get("/api/pose").json()
        assert pose["stale"] and pose["uncertainty_m"] == pytest.approx(3.5, abs=0.3)
        assert link["failsafe_inferred_at"] == pytest.approx(time.time() - 0.1, abs=2.0)
        clock.t += 8.0  # the losses out of the degraded window (console/session/health.py)
        reply_at(operator, clock)  # the link is back
        link = http.get("/api/link").json()
        assert link["state"] == "up" and link["since_reply_s"] == pytest.approx(0.0) and link["link_up"]
        assert not link["failsafe_inferred"] and not http.get("/api/pose").json()["stale"]
        operator.replaying = True
        assert http.get("/api/link").json()["state"] == "replay"


def test_link_lost_is_raised_by_the_link_driver_not_by_reading_and_cleared_when_back(operator, clock):
    def alerts():
        return [e for e in operator.log_entries() if e["level"] == "alert"]

    reply_at(operator, clock)
    operator._turn(operator.now())
    clock.t += 4.0
    for _ in range(3):
        operator.link_state()  # reading says "lost" and logs nothing
    assert operator.link_state()["state"] == "lost" and not alerts()
    operator._turn(operator.now())  # the link loop's next turn
    operator._turn(operator.now())
    lost = alerts()
    assert [e["cause"] for e in lost] == ["link"] and "LINK LOST" in lost[0]["text"] and lost[0]["cleared_wall"] is None
    clock.t += 1.0
    reply_at(operator, clock, failsafe=True)  # back; the ROV had failed safe meanwhile
    link_alert, failsafe_alert = alerts()
    assert link_alert["cleared_wall"] == pytest.approx(operator.wall(operator.now()))
    assert failsafe_alert["cause"] == "failsafe" and failsafe_alert["cleared_wall"] is None
    assert any(e["text"].startswith("link back") for e in operator.log_entries())
    clock.t += 0.5
    reply_at(operator, clock, failsafe=False)  # polls reach it again: out of FAILSAFE
    assert alerts()[1]["cleared_wall"] == pytest.approx(operator.wall(operator.now()))
    assert operator.log_entries()[-1]["text"].startswith("ROV out of FAILSAFE")


def test_the_prediction_stops_at_the_rovs_failsafe_time(operator, clock):
    reply_at(operator, clock, armed=True, mode=Mode.MANUAL)
    operator.set_velocity(1.0, 0.0, 0.0, 0.0)
    # The wish goes out (the prediction runs the wishes as they were sent).
    poll = Poll(seq=0, size=0, order=Velocity(127, 0, 0, 0), img=0, offset=8191)
    operator.handle_events([PollSent(operator.now(), encode_frame(poll.encode()), poll)], operator.now())
    clock.t += 2.0
    early = operator.predicted_pose()
    clock.t += 2.0
    late = operator.predicted_pose()
    clock.t += 30.0
    assert late.x_m > early.x_m > 0.0
    assert operator.predicted_pose() == late


def test_config_serves_one_mode_list_one_key_map_and_the_limits(operator):
    with local_test_client(create_app(operator, disarm_unattended_s=90.0)) as http:
        config = http.get("/api/config").json()
        assert config["modes"] == [m.name for m in Mode if 1 <= m <= 6]
        assert config["keys"]["W"] == ["vx", 1] and config["keys"]["S"] == ["vx", -1] and len(config["keys"]) == 8
        assert config["stop_key"] == "Space" and config["limits"]["velocity"] == [-1.0, 1.0]
        assert config["unattended_warn_s"] == 60.0 and config["disarm_unattended_s"] == 90.0
        assert config["rov_failsafe_s"] == 3.0 and config["lost_after_s"] == 3.0
        # The schema's mode list is the same one.
        schema = http.get("/openapi.json").json()["components"]["schemas"]["ModeOrder"]["properties"]["mode"]
        assert schema["enum"] == config["modes"]


def test_rest_orders_go_through_the_table(operator):
    with local_test_client(create_app(operator)) as http:
        pilot = {HEADER: http.post("/api/control/take", json={"name": "pilot"}).json()["client_id"]}
        other = {HEADER: http.post("/api/control/take", json={"name": "other"}).json()["client_id"]}
        # "other" holds now; the pilot may only stop.
        routes = [("/api/orders/velocity", {"vx": 0.2}), ("/api/orders/position", {"x_m": 1, "y_m": 1, "z_m": 2}),
                  ("/api/orders/position/preview", {"x_m": 1, "y_m": 1, "z_m": 2}),
                  ("/api/orders/arm", {"armed": True}), ("/api/orders/mode", {"mode": "MANUAL"}),
                  ("/api/image/settings", {"budget_bytes": 1000}), ("/api/image/next", {})]
        # (/api/orders/stop/cancel: 409 for the pilot, 422 for the holder while no STOP needs cancelling.)
        assert http.post("/api/orders/stop/cancel", headers=pilot).status_code == 409
        assert http.post("/api/orders/stop/cancel", headers=other).status_code == 422
        for path, body in routes:
            assert http.post(path, json=body, headers=pilot).status_code == 409, path
            assert http.post(path, json=body, headers=other).status_code in (200, 204), path
        assert http.post("/api/orders/stop", headers=pilot).status_code == 200
        # Go to says it switches to GUIDED.
        sent = http.post("/api/orders/position", json={"x_m": 1, "y_m": 1, "z_m": 2}, headers=other).json()
        assert sent["mode"] == "GUIDED"
        assert [o for o in operator.orders_state() if o["id"] == sent["id"]][0]["mode"] == "GUIDED"


def test_the_recording_holds_stop_as_a_neutral_wish_and_each_orders_outcome(operator, clock):
    from rovlink.console.recording import series

    operator.set_velocity(0.3, 0.0, 0.0, 0.0)
    clock.t += 1.0
    stop = operator.stop()
    operator._settled(operator.orders.last_master_id(), Fate.ACKNOWLEDGED, operator.now())
    operator.close()
    s = series(operator.recorder.path)
    # Fig. 5: the commanded surge drops to 0 at STOP (it used to stay at 0.3).
    assert [(round(t, 3), v[0]) for t, v in s.commanded] == [(0.0, 0.0), (0.0, pytest.approx(0.3, abs=0.01)),
                                                            (1.0, 0.0)]
    records = [json.loads(line) for line in open(operator.recorder.path)]
    assert {"k": "order_state", "id": stop, "kind": "STOP", "state": "acknowledged"}.items() <= \
        [r for r in records if r["k"] == "order_state"][-1].items()


def test_protocol_2_alerts_after_more_than_3_inauthentic_frames_in_10_s(operator, clock):
    from rovlink.link.radio.secure import InauthenticFrame, LateReply

    for _ in range(4):
        operator.handle_events([InauthenticFrame("reply"), LateReply(False)], operator.now())
        clock.t += 1.0
    link = operator.link_state()
    assert link["inauthentic_frames"] == 4 and link["late_replies"] == 4 and link["auth_alert"]
    assert any("ALERT" in line.text and line.level == "alert" for line in operator.history.log)
    clock.t += 20.0
    assert not operator.link_state()["auth_alert"]


def test_frames_failing_their_tag_while_replies_come_are_counted_not_alerted(operator, clock):
    """Version 2 has no CRC (§8.1): a reply hit by noise fails its tag like a forged one.
    While replies keep coming that is a noisy link (counted, shown), not an alert."""
    from rovlink.link.radio.master import PoseReceived
    from rovlink.link.radio.messages import Reply
    from rovlink.link.radio.secure import InauthenticFrame

    for _ in range(8):
        operator.handle_events([PoseReceived(Reply(autopilot=True), operator.now(), 0.4), InauthenticFrame("reply")],
                               operator.now())
        clock.t += 1.0
    link = operator.link_state()
    assert link["inauthentic_frames"] == 8 and not link["auth_alert"]
    assert not any("ALERT" in line.text for line in operator.history.log)


def test_the_shared_target_says_sent_whoever_sent_it(operator, clock):
    desk = ControlDesk(operator, clock=clock)
    pilot = desk.connect("pilot", scene_key=KEY)
    take_centred(desk, pilot.id)
    seen = []
    operator.subscribe(lambda topic, payload: seen.append(payload) if topic == "target" else None)
    # Previewed in the scene, sent from the page (REST): the scene's card follows the desk's target.
    desk.submit(control.PreviewTarget(1.0, 2.0, 3.0, 90.0), Caller(scene_key=KEY, via="scene"))
    assert seen[-1]["sent"] is False and len(seen[-1]["points"]) > 1
    order_id = desk.submit(control.GoTo(1.0, 2.0, 3.0, 90.0), Caller(pilot.id))
    assert seen[-1]["sent"] is True and seen[-1]["order_id"] == order_id and len(seen[-1]["points"]) > 1
    # STOP, from anywhere, ends the target for every surface.
    desk.submit(control.Stop(), Caller(scene_key="w" * 32, via="scene"))
    assert seen[-1] is None and desk.target_state() is None
    with pytest.raises(control.OrderError, match="no target"):
        desk.submit(control.SendTarget(), Caller(pilot.id))


def test_a_page_that_takes_control_with_a_held_stick_drives_only_once_it_is_centred(operator, clock):
    desk = ControlDesk(operator, clock=clock)
    assert operator.master.pilot_in_force is False  # nobody holds control: nobody's neutral
    pilot = desk.connect("pilot")
    desk.take(pilot.id)
    assert desk.status(pilot.id)["centre_to_drive"] and not operator.master.pilot_in_force
    desk.submit(control.Drive(0.6, streamed=True), Caller(pilot.id))  # held since before it took control
    assert operator.velocity_wish() == (0.0, 0.0, 0.0, 0.0)
    assert sum("centre the sticks to drive" in e["text"] for e in operator.log_entries()) == 1
    desk.submit(control.Drive(0.6, streamed=True), Caller(pilot.id))
    assert operator.velocity_wish() == (0.0, 0.0, 0.0, 0.0)
    desk.submit(control.Drive(streamed=True), Caller(pilot.id))  # centred: its own input, neutral
    assert not desk.status(pilot.id)["centre_to_drive"] and operator.master.pilot_in_force
    desk.submit(control.Drive(0.6, streamed=True), Caller(pilot.id))
    assert operator.velocity_wish() == (0.6, 0.0, 0.0, 0.0)
    # STOP (anyone's): the stick still forward is not a drive until it is centred again.
    desk.submit(control.Stop(), Caller(desk.connect("watcher").id))
    desk.submit(control.Drive(0.6, streamed=True), Caller(pilot.id))
    assert operator.velocity_wish() == (0.0, 0.0, 0.0, 0.0) and desk.status(pilot.id)["centre_to_drive"]
    desk.submit(control.Drive(streamed=True), Caller(pilot.id))
    desk.submit(control.Drive(0.6, streamed=True), Caller(pilot.id))
    assert operator.velocity_wish() == (0.6, 0.0, 0.0, 0.0)
    # Released: nobody's input again.
    desk.release(pilot.id)
    assert not operator.master.pilot_in_force


def test_a_script_drives_at_once_and_a_ground_station_only_once_centred(operator, clock):
    desk = ControlDesk(operator, clock=clock)
    script = desk.take(None, "script")
    assert not desk.status(script.id)["centre_to_drive"] and operator.master.pilot_in_force
    desk.submit(control.Drive(0.4), Caller(script.id))
    assert operator.velocity_wish() == (0.4, 0.0, 0.0, 0.0)
    gcs = desk.take(None, "ground station", streams_input=True)
    desk.submit(control.Drive(0.6, streamed=True), Caller(gcs.id, via="gcs"))
    assert operator.velocity_wish() == (0.0, 0.0, 0.0, 0.0)
    assert desk.status()["centre_to_drive"] and desk.status()["holder"] == "ground station"


def test_a_page_whose_connection_failed_is_given_control_back_when_it_reconnects_in_time(operator, clock):
    """Control dies with its page's socket; a socket that failed (1006, 1011: not one the
    page closed) belongs to a page that may reconnect, and the same page (its key, one
    per page load) is given control back within `resume_s`, with its sticks to centre
    again. Meanwhile nobody drives; another page that takes control keeps it; the
    page that closed its socket itself, or that comes back too late, is not given it."""
    desk = ControlDesk(operator, clock=clock, resume_s=10.0)
    page = desk.connect("pilot", scene_key=KEY)
    take_centred(desk, page.id)
    desk.submit(control.Drive(0.5), Caller(page.id))
    desk.disconnect(page.id, "the connection failed, code 1011", failed=True)
    assert not desk.status()["held"] and operator.velocity_wish() == (0.0, 0.0, 0.0, 0.0)
    clock.t += 3.0
    other = desk.connect("another page", scene_key="x" * 32)  # not the same page: a watcher
    assert not desk.status(other.id)["held"]
    again = desk.connect("pilot", scene_key=KEY)
    status = desk.status(again.id)
    assert status["you"] and status["centre_to_drive"], status
    desk.submit(control.Drive(0.5), Caller(again.id))  # the stick held through the gap: no drive
    assert operator.velocity_wish() == (0.0, 0.0, 0.0, 0.0)
    texts = [e["text"] for e in operator.state()["log"]]
    assert any("given back if the page reconnects within 10 s" in t for t in texts), texts
    assert any(t == "control given back to pilot: its page reconnected" for t in texts), texts

    # Taken by another page meanwhile: it keeps it.
    desk.disconnect(again.id, "the connection broke, code 1006", failed=True)
    take_centred(desk, other.id)
    third = desk.connect("pilot", scene_key=KEY)
    assert desk.status(other.id)["you"] and not desk.status(third.id)["you"]

    # Closed by the page (1001): nothing to give back.
    desk.disconnect(other.id, "the page went away, code 1001")
    take_centred(desk, third.id)
    desk.disconnect(third.id, "the page went away, code 1001", failed=False)
    assert not desk.status(desk.connect("pilot", scene_key=KEY).id)["held"]

    # Too late: not given back, and the log says so.
    late = desk.connect("pilot", scene_key=KEY)
    take_centred(desk, late.id)
    desk.disconnect(late.id, "the connection broke, code 1006", failed=True)
    clock.t += 10.5
    desk.tick()
    assert not desk.status(desk.connect("pilot", scene_key=KEY).id)["held"]
    assert "control not given back: pilot did not reconnect within 10 s" in [e["text"] for e in operator.state()["log"]]


def test_a_ground_station_takes_control_only_when_nobody_holds_it_even_when_forgotten(operator, clock):
    """The gateway's orders take control when it is free, decided under the desk's lock,
    and are DENIED while a page holds it; a gateway idle long enough for the desk to forget
    its client id takes control again with a new one, rather than failing."""
    from pymavlink.dialects.v20 import ardupilotmega as m

    from rovlink.console.gcs import CommandRefused, DeskCommands

    desk = ControlDesk(operator, clock=clock, lease_s=5.0)
    gcs = DeskCommands(desk)
    gcs.mode("MANUAL")
    assert desk.status()["holder"] == "ground station"
    page = desk.connect("pilot")
    take_centred(desk, page.id)  # taken from the ground station
    with pytest.raises(CommandRefused) as refused:
        gcs.mode("MANUAL")
    assert refused.value.result == m.MAV_RESULT_DENIED and "held by pilot" in refused.value.reason
    with pytest.raises(NotHolder):
        desk.take(None, "ground station", unless_held=True)
    assert desk.status(page.id)["you"]
    desk.release(page.id)
    clock.t += 6.0
    desk.tick()  # the idle gateway's client is forgotten
    gcs.mode("MANUAL")  # free: taken, with a new client
    assert desk.status()["holder"] == "ground station"
