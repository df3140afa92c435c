"""The acoustic profile as a user runs it (issue 24): `rovlink rov` and `rovlink
console` as two processes, each on the real `wlmodem://` transport, talking
through two emulated Modem-M64s on real pseudo-terminals (link/m64serial.py,
four times the real modem's pace so the test takes a minute, not four).  The
pilot uses the acoustic page in headless Chromium: the status with its age and
the next status due, arm, a go-to previewed then sent and flown by the
simulated vehicle, STOP confirmed, a thumbnail refining then verified and
decoded.  A hostile radio between the modems replays the go-to's packets
after the STOP: the vehicle does not move."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest

from rovlink.link.m64 import M64Params
from rovlink.link.transport import free_udp_port

from ..helpers import CHROMIUM, CHROMIUM_ARGS, free_tcp_port, needs_chromium
from .acoustic_rig import HostileRadio, end_processes, get, post, wait_for

pytestmark = [pytest.mark.browser, pytest.mark.processes, pytest.mark.slow, needs_chromium]
ROVLINK = [sys.executable, "-m", "rovlink"]
FAST = M64Params(round_s=0.25, b_offset_s=0.125, latency_s=0.4, sync_s=1.0)


@pytest.fixture(scope="module")
def acoustic(tmp_path_factory):
    from rovlink.link.m64serial import M64SerialPair

    tmp = tmp_path_factory.mktemp("acoustic")
    key = tmp / "link.key"
    subprocess.run(ROVLINK + ["keygen", str(key)], check=True, capture_output=True, timeout=60)
    pair = M64SerialPair(str(tmp / "op-modem"), str(tmp / "rov-modem"), params=FAST, seed=3)
    radio = HostileRadio(pair.channel)
    pair.start()
    port, gcs_port = free_tcp_port(), free_udp_port()
    rov = subprocess.Popen(ROVLINK + ["rov", "--link", f"wlmodem://{tmp}/rov-modem?role=b&channel=4",
                                      "--key", str(key), "-v"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    console = subprocess.Popen(ROVLINK + ["console", "--link", f"wlmodem://{tmp}/op-modem?role=a&channel=4",
                                          "--key", str(key), "--port", str(port), "--viser-port", str(free_tcp_port()),
                                          "--no-record", "--gcs", f"udpout:127.0.0.1:{gcs_port}"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp)
    base = f"http://127.0.0.1:{port}"
    try:
        assert wait_for(lambda: get(base + "/api/state")["status"], 120), "no status from the ROV over the modems"
        yield base, radio, rov, console, gcs_port
    finally:
        end_processes(console, rov)
        pair.close()


def test_a_pilot_supervises_the_rov_through_the_acoustic_page(acoustic):
    from playwright.sync_api import sync_playwright

    base, radio, rov, console, _ = acoustic
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1366, "height": 768})
        page.goto(base + "/")
        # The link up, the status with its age, when the next is due, and the ROV's failsafe stated.
        page.wait_for_function("document.getElementById('link').textContent.includes('up')", timeout=30000)
        page.wait_for_function("document.getElementById('status-age').textContent.includes('s old')")
        assert "next status" in page.text_content("#next")
        page.wait_for_function("document.getElementById('failsafe').textContent.includes('60 s')", timeout=30000)
        assert "holds position" in page.text_content("#failsafe")

        # Arm: its fate comes back.
        page.click("button[data-order=arm]")
        page.wait_for_selector("#orders tr[data-state=done]", timeout=60000)
        page.wait_for_function("[...document.querySelectorAll('#status th')].some(th => th.nextSibling"
                               " && th.nextSibling.textContent === 'ARMED')", timeout=30000)

        # A go-to, previewed before it is sent: the page draws the target, nothing moves.
        start = get(base + "/api/state")["status"]
        page.fill("#gx", str(start["x_m"] + 2.0))
        page.fill("#gy", str(start["y_m"]))
        page.fill("#gz", str(start["depth_m"]))
        page.wait_for_function("document.getElementById('goto-preview').textContent.includes('m away')")
        assert "2.0 m away" in page.text_content("#goto-preview")
        time.sleep(2.0)
        assert abs(get(base + "/api/state")["status"]["x_m"] - start["x_m"]) < 0.3  # previewed, not sent
        page.click("#send-goto")
        page.wait_for_function("[...document.querySelectorAll('#orders tr')].some(r => r.textContent.includes('go to')"
                               " && r.dataset.state === 'done')", timeout=90000)
        flown = get(base + "/api/state")["status"]
        assert abs(flown["x_m"] - (start["x_m"] + 2.0)) < 0.5, flown
        first_goto = radio.goto_frame()  # what a hostile radio recorded of it

        # STOP: sent first, confirmed by the ROV.
        page.click("#stop")
        page.wait_for_function("document.getElementById('stop-fate').dataset.state === 'confirmed'", timeout=60000)
        held = get(base + "/api/state")["status"]
        assert held["hold"] and held["mode"] in ("POS_HOLD", "DEPTH_HOLD")

        # A thumbnail refines, then is verified; the picture decodes.
        page.click("#send-thumb")
        page.wait_for_function("document.getElementById('thumb-state').dataset.verified === 'true'", timeout=120000)
        png = get(base + "/api/thumbnail.png")
        assert png[:8] == b"\x89PNG\r\n\x1a\n"
        import io

        from PIL import Image

        picture = np.asarray(Image.open(io.BytesIO(png)))
        assert picture.shape[:2] == (240, 320) and picture.std() > 1.0  # a picture, not a blank
        browser.close()

    # Back where it started, by a go-to of the API's (the same path as the page's) ...
    post(base + "/api/goto", {"x_m": start["x_m"], "y_m": start["y_m"], "z_m": start["depth_m"]})
    assert wait_for(lambda: [o for o in get(base + "/api/state")["orders"]
                             if o["text"].startswith("go to") and o["state"] == "done"][1:], 90)
    # ... then a hostile radio replays the first go-to's packets: refused, the vehicle stays.
    assert len(first_goto) == 2
    time.sleep(3.0)  # settled on the target
    before = get(base + "/api/state")
    radio.replay(first_goto)
    time.sleep(8.0)
    after = get(base + "/api/state")
    # Taken, it would fly 2 m north again: it stays where it was (the autopilot's last centimetres aside).
    assert abs(after["status"]["x_m"] - start["x_m"]) < 0.6 and after["status"]["x_m"] < before["status"]["x_m"] + 0.3
    assert not after["status"]["going"]
    assert [o["state"] for o in after["orders"]] == [o["state"] for o in before["orders"]]
    assert after["link"]["state"] == "up"
    assert rov.poll() is None and console.poll() is None


def test_a_ground_station_sees_the_status_and_stops_the_rov_over_the_acoustic_link(acoustic):
    """QGroundControl's part, with pymavlink: the HEARTBEAT says what the last status
    said, MANUAL_CONTROL moves nothing (no sticks at 64 bit/s), and DO_PAUSE_CONTINUE
    is the STOP, answered ACCEPTED once the ROV confirms it."""
    from pymavlink import mavutil

    base, _, _, _, gcs_port = acoustic
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", dialect="ardupilotmega", source_system=255)
    try:
        hb = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=30)
        assert hb is not None and hb.type == mavutil.mavlink.MAV_TYPE_SUBMARINE
        armed = bool(hb.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        assert armed == get(base + "/api/state")["status"]["armed"]
        before = get(base + "/api/state")["status"]
        for _ in range(20):
            gcs.mav.manual_control_send(1, 1000, 0, 500, 0, 0)
            time.sleep(0.1)
        gcs.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_DO_PAUSE_CONTINUE, 0, 0, 0, 0, 0, 0, 0, 0)
        results = []
        end = time.monotonic() + 60
        while time.monotonic() < end and mavutil.mavlink.MAV_RESULT_ACCEPTED not in results:
            ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=2)
            if ack is not None and ack.command == mavutil.mavlink.MAV_CMD_DO_PAUSE_CONTINUE:
                results.append(ack.result)
        assert results[0] == mavutil.mavlink.MAV_RESULT_IN_PROGRESS and results[-1] == mavutil.mavlink.MAV_RESULT_ACCEPTED
        after = get(base + "/api/state")
        assert after["stop"]["state"] == "confirmed"
        assert abs(after["status"]["x_m"] - before["x_m"]) < 0.6  # the stick stream moved nothing
    finally:
        gcs.close()
