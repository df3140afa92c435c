"""The acoustic profile as a user runs it (issues 24 and 32): `rovlink rov` and
`rovlink console` as two processes, each on the real `wlmodem://` transport,
talking through two emulated Modem-M64s on real pseudo-terminals
(link/emulators/m64serial.py, four times the real modem's pace so the test takes a
minute, not four).  The pilot meets the same cockpit as on the radio link, in
headless Chromium at 1366x768: the 3-D scene embedded, the instruments, the
status with its age and when the next is due; no sticks (absent, not broken);
arm, a go-to previewed then sent and followed to "arrived"; a second page
refused an order (409) while the first holds control, and its STOP taken and
confirmed; a thumbnail refining, then verified.  A hostile radio between the
modems replays the go-to's packets after the STOP: the vehicle does not move.
The pilot's own ground station (pymavlink) sees the vehicle's mode, position
and a go-to's outcome, and stops it."""

from __future__ import annotations

import io
import subprocess
import sys
import time

import numpy as np
import pytest

from rovlink.console.bench.pilot import holds_control
from rovlink.link.emulators.m64 import M64Params
from rovlink.link.transports.transport import free_udp_port

from ..helpers import CHROMIUM, CHROMIUM_ARGS, free_tcp_port, needs_chromium
from .acoustic_rig import HostileRadio, end_processes, get, post, wait_for
from .pages import drag_roi

pytestmark = [pytest.mark.browser, pytest.mark.processes, pytest.mark.slow, needs_chromium]
ROVLINK = [sys.executable, "-m", "rovlink"]
FAST = M64Params(round_s=0.25, b_offset_s=0.125, latency_s=0.4, sync_s=1.0)


@pytest.fixture(scope="module")
def acoustic(tmp_path_factory):
    from rovlink.link.emulators.m64serial import M64SerialPair

    tmp = tmp_path_factory.mktemp("acoustic")
    key = tmp / "link.key"
    subprocess.run(ROVLINK + ["keygen", str(key)], check=True, capture_output=True, timeout=60)
    pair = M64SerialPair(str(tmp / "op-modem"), str(tmp / "rov-modem"), params=FAST, seed=3)
    radio = HostileRadio(pair.channel)
    pair.start()
    port, gcs_port = free_tcp_port(), free_udp_port()
    # Their output to files: `rov -v` says every packet, and a pipe nobody reads until the
    # end fills (64 kB) and stops the ROV at its next line, minutes into the module.
    rov_log, console_log = open(tmp / "rov.log", "w"), open(tmp / "console.log", "w")
    rov = subprocess.Popen(ROVLINK + ["rov", "--link", f"wlmodem://{tmp}/rov-modem?role=b&channel=4",
                                      "--key", str(key), "-v"],
                           stdout=rov_log, stderr=subprocess.STDOUT, text=True)
    console = subprocess.Popen(ROVLINK + ["console", "--link", f"wlmodem://{tmp}/op-modem?role=a&channel=4",
                                          "--key", str(key), "--port", str(port), "--viser-port", str(free_tcp_port()),
                                          "--no-record", "--gcs", f"udpout:127.0.0.1:{gcs_port}"],
                               stdout=console_log, stderr=subprocess.STDOUT, text=True, cwd=tmp)
    base = f"http://127.0.0.1:{port}"
    try:
        assert wait_for(lambda: get(base + "/api/pose")["received"], 120), "no status from the ROV over the modems"
        yield base, radio, rov, console, gcs_port, tmp / "rov.log"
    finally:
        end_processes(console)  # (first: its link process sends STOP as it ends, which the ROV takes)
        end_processes(rov)
        pair.close()
        rov_log.close()
        console_log.close()


def open_cockpit(browser, base: str, scene: bool = False):
    """The operator page at 1366x768, configured, its link up; its 3-D scene drawn only
    if `scene` (drawn without a graphics card, it takes a core from the rest of the suite)."""
    page = browser.new_page(viewport={"width": 1366, "height": 768})
    page.goto(base + ("/" if scene else "/?scene=off"))
    page.wait_for_function("document.body.dataset.configured === '1' && document.body.dataset.link === 'up'",
                           timeout=30000)
    return page


def order(base: str, kind: str) -> dict | None:
    """The newest order of `kind` the console lists."""
    mine = [o for o in get(base + "/api/orders") if o["kind"] == kind]
    return mine[-1] if mine else None


def test_the_acoustic_pilot_meets_the_one_cockpit_with_its_3d_scene(acoustic):
    from playwright.sync_api import sync_playwright

    base, radio, rov, console, _, _ = acoustic
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        page = open_cockpit(browser, base, scene=True)
        # The same page as the radio link's, with the 3-D scene embedded ...
        assert page.evaluate("document.body.dataset.profile") == "acoustic"
        scene = page.locator("#scene")
        assert scene.is_visible() and ":" in (scene.get_attribute("src") or "")
        assert "acoustic" in page.text_content("#link-version")
        # ... the status with its age and when the next one is due ...
        page.wait_for_function("/s old, next status in/.test(document.getElementById('odometry-age').textContent)",
                               timeout=30000)
        # ... and what the link cannot carry left out: no sticks, no "next picture".
        assert not page.locator("#keys").is_visible() and not page.locator("#key-hint").is_visible()
        assert not page.locator("#next-image").is_visible()

        page.click("#take")
        page.wait_for_function("document.getElementById('control-text').textContent.includes('You have control')")
        # Held keys send nothing on this link (the page does not stream a wish it cannot carry).
        page.keyboard.down("KeyW")
        time.sleep(1.0)
        page.keyboard.up("KeyW")
        assert get(base + "/api/state")["velocity_wish"] == {"vx": 0.0, "vy": 0.0, "vz": 0.0, "vyaw": 0.0}

        # Arm: its fate comes back beside the button.
        page.click("#arm")
        page.wait_for_function("document.getElementById('arm-fate').dataset.state === 'followed'", timeout=60000)

        # A go-to, previewed before it is sent: the scene shows the target and its path, nothing moves.
        start = get(base + "/api/pose")["received"]
        for field, value in (("x", start["x_m"] + 2.0), ("y", start["y_m"]), ("z", start["z_m"]), ("yaw", 0)):
            page.fill(f"#goto-{field}", f"{value:.1f}")
        page.click("#goto-preview")
        page.wait_for_function("!document.getElementById('goto-plan').hidden", timeout=10000)
        assert order(base, "POSITION") is None  # previewed, not sent
        time.sleep(2.0)
        assert abs(get(base + "/api/pose")["received"]["x_m"] - start["x_m"]) < 0.3
        page.click("#goto-go")
        page.wait_for_function("document.getElementById('goto-fate').dataset.state === 'arrived'", timeout=90000)
        flown = get(base + "/api/pose")["received"]
        assert abs(flown["x_m"] - (start["x_m"] + 2.0)) < 0.6, flown
        first_goto = radio.goto_frame()  # what a hostile radio recorded of it

        # A second page: refused an order while the first holds control; its STOP is taken.
        second = browser.new_page(viewport={"width": 1366, "height": 768})
        second.goto(base + "/?scene=off")
        second.wait_for_function("document.body.dataset.clientId !== undefined", timeout=30000)
        status = second.evaluate("""async () => (await fetch('/api/orders/arm', {method: 'POST',
            headers: {'Content-Type': 'application/json', 'X-Rovlink-Client': document.body.dataset.clientId},
            body: JSON.stringify({armed: false})})).status""")
        assert status == 409
        second.click("#stop")
        assert wait_for(lambda: (order(base, "STOP") or {}).get("state") == "acknowledged", 60), \
            (get(base + "/api/orders"), second.evaluate("[page.ws && page.ws.readyState, page.clientId,"
                                                        " document.getElementById('error').textContent]"))
        held = get(base + "/api/pose")
        assert held["hold"] and held["armed"]  # the arm was not undone by the second page
        # Both pages show the STOP's fate.
        for pg in (page, second):
            pg.wait_for_function("document.getElementById('orders').textContent.includes('STOP')", timeout=10000)

        # A thumbnail refines, then is verified; the picture decodes.
        page.fill("#budget", "120")
        page.click("#apply-image")
        page.wait_for_function("document.getElementById('image-decoded').textContent.includes('verified')"
                               " && !document.getElementById('image-decoded').textContent.includes('UNVERIFIED')",
                               timeout=300000)  # (about 20 data packets, a STATUS between; slower under load)
        png = get(base + "/api/image/latest.png")
        from PIL import Image

        picture = np.asarray(Image.open(io.BytesIO(png)))
        assert picture.shape[:2] == (60, 80) and picture.std() > 1.0  # a picture, not a blank
        browser.close()

    # Back where it started, by a go-to of the API's (the same path as the page's) ...
    me = post(base + "/api/control/take", {"name": "script"})["client_id"]
    post(base + "/api/orders/position", {"x_m": start["x_m"], "y_m": start["y_m"], "z_m": start["z_m"]},
         headers={"X-Rovlink-Client": me})
    assert wait_for(lambda: (order(base, "POSITION") or {}).get("state") == "arrived"
                    and len([o for o in get(base + "/api/orders") if o["kind"] == "POSITION"]) == 2, 90)
    # ... then a hostile radio replays the first go-to's packets: refused, the vehicle stays.
    assert len(first_goto) == 2
    time.sleep(3.0)  # settled on the target
    before = get(base + "/api/state")
    radio.replay(first_goto)
    time.sleep(8.0)
    after = get(base + "/api/state")
    # Taken, it would fly 2 m north again: it stays where it was (the autopilot's last centimetres aside).
    x_after, x_before = after["pose"]["received"]["x_m"], before["pose"]["received"]["x_m"]
    assert abs(x_after - start["x_m"]) < 0.6 and x_after < x_before + 0.3
    assert not after["pose"]["going"]
    assert [o["state"] for o in after["orders"]] == [o["state"] for o in before["orders"]]
    assert after["link"]["state"] == "up"
    assert rov.poll() is None and console.poll() is None
    post(base + "/api/control/release", {}, headers={"X-Rovlink-Client": me})  # the next pilot may take it


def test_a_ground_station_sees_the_acoustic_vehicle_and_its_go_to_and_stops_it(acoustic):
    """QGroundControl's part, with pymavlink: the HEARTBEAT says the mode and arming
    the last status said, LOCAL_POSITION_NED its position; a go-to (a position
    target) is answered with its outcome; MANUAL_CONTROL moves nothing (no sticks at
    64 bit/s); DO_PAUSE_CONTINUE is the STOP, ACCEPTED once the ROV confirms it."""
    from pymavlink import mavutil

    from rovlink.link.radio.messages import Mode
    from rovlink.rov.ardusub import PROTOCOL_TO_SUB

    m = mavutil.mavlink
    base, _, _, _, gcs_port, _ = acoustic
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", dialect="ardupilotmega", source_system=255)
    try:
        hb = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=30)
        assert hb is not None and hb.type == m.MAV_TYPE_SUBMARINE
        pose = get(base + "/api/pose")
        assert bool(hb.base_mode & m.MAV_MODE_FLAG_SAFETY_ARMED) == pose["armed"]
        assert hb.custom_mode == int(PROTOCOL_TO_SUB[Mode[pose["mode"]]])
        local = gcs.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=30)
        assert local is not None
        assert abs(local.x - pose["received"]["x_m"]) < 0.3 and abs(local.z - pose["received"]["z_m"]) < 0.3

        if not pose["armed"]:  # (a pilot before may have left it disarmed) armed from the ground station
            gcs.mav.command_long_send(1, 1, m.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
            assert wait_for(lambda: get(base + "/api/pose")["armed"], 60), get(base + "/api/orders")
            pose = get(base + "/api/pose")
        # A go-to from the ground station: its outcome comes back as STATUSTEXT.
        target_x = pose["received"]["x_m"] + 1.5
        gcs.mav.set_position_target_local_ned_send(0, 1, 1, m.MAV_FRAME_LOCAL_NED, 0b0000111111111000, target_x,
                                                   pose["received"]["y_m"], pose["received"]["z_m"],
                                                   0, 0, 0, 0, 0, 0, 0, 0)
        texts = []
        end = time.monotonic() + 120
        while time.monotonic() < end and not any("arrived" in t for t in texts):
            msg = gcs.recv_match(type="STATUSTEXT", blocking=True, timeout=2)
            if msg is not None:
                texts.append(msg.text)
        assert any("go-to" in t and "arrived" in t for t in texts), texts
        hb = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=10)
        assert hb.custom_mode == int(PROTOCOL_TO_SUB[Mode.GUIDED])

        before = get(base + "/api/pose")["received"]
        for _ in range(20):
            gcs.mav.manual_control_send(1, 1000, 0, 500, 0, 0)
            time.sleep(0.1)
        gcs.mav.command_long_send(1, 1, m.MAV_CMD_DO_PAUSE_CONTINUE, 0, 0, 0, 0, 0, 0, 0, 0)
        results = []
        end = time.monotonic() + 60
        while time.monotonic() < end and m.MAV_RESULT_ACCEPTED not in results:
            ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=2)
            if ack is not None and ack.command == m.MAV_CMD_DO_PAUSE_CONTINUE:
                results.append(ack.result)
        assert results[0] == m.MAV_RESULT_IN_PROGRESS and results[-1] == m.MAV_RESULT_ACCEPTED, results
        assert order(base, "STOP")["state"] == "acknowledged"
        after = get(base + "/api/pose")["received"]
        assert abs(after["x_m"] - before["x_m"]) < 0.6  # the stick stream moved nothing
    finally:
        gcs.close()


SHOWN = """() => {
  const box = document.getElementById('roi-box');
  const track = document.getElementById('track-text');
  const key = document.getElementById('image').dataset.key || '';
  return [parseInt(key.split(':')[0] || '0', 10), box.hidden ? null : parseFloat(box.style.left),
          track.dataset.state || '', track.textContent];
}"""
VERIFIED = ("document.getElementById('image-decoded').textContent.includes('verified')"
            " && !document.getElementById('image-decoded').textContent.includes('UNVERIFIED')")


def test_the_acoustic_pilot_follows_an_roi_from_thumbnail_to_thumbnail(acoustic):
    """Issue 34 over the acoustic link (§9.3, §10), as the pilot meets it: an ROI dragged
    on a thumbnail, Follow; the vehicle turned right by a go-to; "Ask again, following":
    the ROI the next thumbnail was coded with has moved left with what it framed; turned
    away, the next thumbnail says the track is LOST."""
    from playwright.sync_api import sync_playwright

    base, rov_log = acoustic[0], acoustic[5]

    def rov_says(word: str) -> list[str]:
        return [line.strip() for line in open(rov_log, encoding="utf-8", errors="replace") if word in line][-5:]

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        page = open_cockpit(browser, base)
        page.click("#take")
        page.wait_for_function("document.getElementById('control-text').textContent.includes('You have control')")
        if not get(base + "/api/pose")["armed"]:
            page.click("#arm")
            page.wait_for_function("document.getElementById('armed').textContent === 'ARMED'", timeout=60000)
        page.fill("#budget", "100")
        before = max([o["id"] for o in get(base + "/api/orders")], default=0)
        page.click("#apply-image")
        # This thumbnail, not one an earlier test asked for that is still coming in.
        asked = wait_for(lambda: next(((o["oid"],) for o in get(base + "/api/orders")
                                       if o["kind"] == "IMAGE" and o["id"] > before), None), 30)
        assert asked is not None, get(base + "/api/orders")[-3:]
        page.wait_for_function(f"document.getElementById('image').dataset.img === '{asked[0]}' && {VERIFIED}",
                               timeout=300000)
        first = page.evaluate(SHOWN)[0]
        drawn_on = int(page.evaluate("document.getElementById('image').dataset.img"))  # the thumbnail's OID

        # An ROI round the amphorae, dragged on the thumbnail, set to follow.
        drag_roi(page, "#image", (0.5, 0.4), (0.85, 0.75))
        assert page.is_visible("#roi-follow") and page.is_checked("#roi-keep")
        page.click("#roi-follow")
        page.wait_for_function(f"({SHOWN})()[0] > {first} && ({SHOWN})()[1] !== null && {VERIFIED}", timeout=240000)
        serial, left0, state, text = page.evaluate(SHOWN)
        assert state == "holds" and "track holds" in text, (text, get(base + "/api/image"), rov_says("FOLLOW"))
        assert page.is_visible("#follow-again")
        sent = [o for o in get(base + "/api/orders") if o["kind"] == "IMAGE"][-1]
        assert sent.get("follow") is True and sent.get("drawn_on") == drawn_on, sent

        def turn(by_deg: float) -> None:
            holds_control(page, base)  # (if not: what its socket and the console's log said)
            pose = get(base + "/api/pose")["received"]
            for field, value in (("x", pose["x_m"]), ("y", pose["y_m"]), ("z", pose["z_m"]),
                                 ("yaw", pose["yaw_deg"] + by_deg)):
                page.fill(f"#goto-{field}", f"{value:.1f}")
            page.click("#goto-go")
            page.wait_for_function("document.getElementById('goto-fate').dataset.state === 'arrived'",
                                   timeout=120000)

        # Turned right: what the ROI framed slides left in the next thumbnail.
        turn(20.0)
        page.click("#follow-again")
        page.wait_for_function(f"({SHOWN})()[0] > {serial} && ({SHOWN})()[1] !== null && {VERIFIED}",
                               timeout=300000)
        serial, left1, state, text = page.evaluate(SHOWN)
        assert state == "holds", (text, rov_says("FOLLOW"))
        assert left1 < left0 - 5, (left0, left1)
        # Turned away: the next thumbnail says the track is lost, the last ROI kept.
        turn(120.0)
        page.click("#follow-again")
        page.wait_for_function(f"({SHOWN})()[0] > {serial} && {VERIFIED}", timeout=300000)
        _, _, state, text = page.evaluate(SHOWN)
        assert state == "lost" and "track LOST" in text and "last ROI kept" in text, text
        browser.close()
