"""A fate is never told false: an ARM the vehicle follows late is shown waiting,
then followed, never refused or FAILED, on the radio link (through the
ground-station gateway too) and on the acoustic link.

The defect this guards: a ground station sent ARM as soon as LOCAL_POSITION_NED
first came; the console gave the request up after 3 s and answered FAILED, and
the vehicle armed at 4.9 s."""

from __future__ import annotations

import time

import pytest
from pymavlink import mavutil

from rovlink.console.gcs import DeskCommands, GcsGateway
from rovlink.console.session.fates import Fate
from rovlink.link.transports.transport import free_udp_port

from .conftest import running_console

pytestmark = pytest.mark.slow
M = mavutil.mavlink
K = bytes(range(32))


def _shots(tmp_path):
    """Where the screenshots go: ROVLINK_SHOTS, to look at them, else the test's own folder."""
    import os
    from pathlib import Path

    return Path(os.environ.get("ROVLINK_SHOTS", str(tmp_path)))


def _order(operator, order_id: int) -> dict:
    return next(o for o in operator.orders_state() if o["id"] == order_id)


def test_an_arm_sent_at_the_first_telemetry_and_followed_late_is_accepted_never_failed():
    """The vehicle arms 6 s after it is asked (its ARM answered IN_PROGRESS
    meanwhile): the ground station sees IN_PROGRESS, a STATUSTEXT that it waits,
    then ACCEPTED and a STATUSTEXT that it was followed; the console's order goes
    requested, sent, waiting, followed, and no alert is raised."""
    port = free_udp_port()
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="ardupilotmega",
                                     source_system=255, source_component=190)
    with running_console(arm_delay_s=6.0) as live:
        gateway = GcsGateway([f"udpout:127.0.0.1:{port}"], live.operator,
                             DeskCommands(live.app.state.desk)).start()
        try:
            assert gcs.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=30) is not None
            gcs.mav.command_long_send(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
            acks, texts, armed_at = [], [], None
            asked = time.monotonic()
            while time.monotonic() - asked < 40 and not (acks and acks[-1] != M.MAV_RESULT_IN_PROGRESS
                                                         and any("followed" in t for t in texts)):
                m = gcs.recv_match(type=["COMMAND_ACK", "STATUSTEXT", "HEARTBEAT"], blocking=True, timeout=1)
                if m is None:
                    continue
                if m.get_type() == "COMMAND_ACK" and m.command == M.MAV_CMD_COMPONENT_ARM_DISARM:
                    acks.append(m.result)
                elif m.get_type() == "STATUSTEXT":
                    texts.append(m.text)
                elif m.get_type() == "HEARTBEAT" and m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED and armed_at is None:
                    armed_at = time.monotonic() - asked
            assert M.MAV_RESULT_FAILED not in acks, (acks, texts)
            assert acks[0] == M.MAV_RESULT_IN_PROGRESS and acks[-1] == M.MAV_RESULT_ACCEPTED, (acks, texts)
            assert armed_at is not None and armed_at > 5.0, armed_at  # it did arm late
            about_arm = [t for t in texts if t.startswith(("rovlink: ARM ", "rovlink: arm "))]
            assert any(t.startswith("rovlink: ARM followed,") for t in texts), texts
            assert all("followed" in t or "waiting" in t for t in about_arm), texts  # never refused nor failed
            arm = next(o for o in live.operator.orders_state() if o["kind"] == "ARM")
            assert arm["state"] == Fate.FOLLOWED and "t_waiting" in arm and "t_refused" not in arm, arm
            assert not [e for e in live.operator.log_entries(100) if e["level"] == "alert" and "ARM" in e["text"]]
        finally:
            gateway.stop()
            gcs.close()


def test_an_acoustic_arm_followed_late_is_taken_then_followed_never_rejected():
    """Over the acoustic link the ROV says "taken" at once and "done" when the
    vehicle armed, 20 s on; the console's order is never shown rejected or
    unknown, and is followed when the status shows it armed."""
    from rovlink.console.session.acoustic import AcousticSession
    from rovlink.link.acoustic.sim import AcousticSim, SimVehicle

    fates: list[str] = []
    session_box: dict = {}

    def on_event(event, now):
        session = session_box.get("s")
        if session is not None:
            with session._lock:
                session._handle([event], now)

    sim = AcousticSim(K, seed=5, vehicle=SimVehicle(armed=False, arm_delay_s=20.0), on_operator_event=on_event)
    session = AcousticSession(None, K, clock=lambda: sim.now)
    session.op = sim.operator
    session_box["s"] = session
    session.subscribe(lambda topic, payload: fates.append(payload["state"]) if topic == "order"
                      and payload.get("kind") == "ARM" else None)
    try:
        while not sim.operator.ready:
            sim.run_until(sim.now + 1.0)
            assert sim.now < 120, "no session"
        sim.run_until(sim.now + 5.0)  # a first status
        arm = session.arm(True)
        asked = sim.now
        while _order(session, arm)["state"] != Fate.FOLLOWED and sim.now - asked < 240:
            sim.run_until(sim.now + 1.0)
            session._mark_sending()
        final = _order(session, arm)
        assert final["state"] == Fate.FOLLOWED, (final, fates)
        assert sim.vehicle.armed and sim.now - asked >= 20.0
        assert not {Fate.REJECTED, Fate.REFUSED, Fate.UNKNOWN, Fate.CANCELLED} & {Fate(f) for f in fates}, fates
        assert Fate.ACKNOWLEDGED in fates, fates  # the ROV said it took it, before it was done
    finally:
        session.close()


@pytest.mark.browser
def test_the_page_shows_an_arm_the_vehicle_follows_late_waiting_then_armed(browser, tmp_path):
    """Beside Arm, at 1366x768: "arming…" with its age, "not yet" once the link stops
    repeating it, then "armed ✓" when the vehicle reports it armed, 12 s on; never refused,
    and no pop-up of an error."""
    with running_console(arm_delay_s=12.0) as live:
        context = browser.new_context(viewport={"width": 1366, "height": 768})
        errors: list[str] = []
        try:
            page = context.new_page()
            page.on("pageerror", lambda exc: errors.append(f"uncaught: {exc}"))
            page.goto(live.url + "/?scene=off")
            page.wait_for_function("document.body.dataset.clientId !== undefined")
            page.click("#take")
            page.wait_for_function("document.getElementById('control-text').textContent.includes('You have control')")
            page.click("#arm")
            page.wait_for_function("document.getElementById('arm-fate').dataset.state === 'waiting'", timeout=20000)
            waiting = page.text_content("#arm-fate")
            assert waiting.startswith("arming… (not yet, ") and waiting.endswith(" s)"), waiting
            assert "pending" in page.get_attribute("#arm-fate", "class")
            assert page.is_visible("#arm-fate")
            page.screenshot(path=str(_shots(tmp_path) / "arm-waiting.png"))
            page.wait_for_function("document.getElementById('arm-fate').dataset.state === 'followed'", timeout=30000)
            assert page.text_content("#arm-fate").startswith("armed ✓ "), page.text_content("#arm-fate")
            # (The top bar's ARMED may not last: with nobody driving, the simulated ArduSub disarms
            # 3 s after arming, as a real one does on "Lost manual control"; the fate is what is tested.)
            arm = next(o for o in live.operator.orders_state() if o["kind"] == "ARM")
            assert arm["state"] == "followed" and "t_waiting" in arm, arm
            shown = page.evaluate("Array.from(document.querySelectorAll('#orders li')).map(li => li.textContent)")
            arm_lines = [line for line in shown if " ARM" in line]
            assert arm_lines and "followed: " in arm_lines[0] and "after it was asked" in arm_lines[0], shown
            assert page.is_hidden("#error"), page.text_content("#error")  # nothing refused was popped up
        finally:
            context.close()
        assert not errors, errors
