"""The objects the ROV recognised, in the cockpit, on the acoustic link (issue 38, §11.2):
`rovlink sim` (3 m over the seabed) and `rovlink rov` as processes on two emulated
Modem-M64s (link/emulators/m64serial.py, four times the real pace), the console's
session, web app and 3-D scene in this process (as `rovlink console` wires them, its
link process included), recording.  As a pilot in headless Chromium: an object appears
in the list and in the scene; its "Go to" previews a path, Send flies it to the stand-off
facing it; "Frame it" asks a thumbnail whose ROI holds the object (FOLLOW from the ROV's
newest frame).  Then the recording, replayed, lays the same objects and thumbnails on the
same floor again."""

from __future__ import annotations

import asyncio
import contextlib
import math
import subprocess
import sys
import threading

import pytest

from rovlink.link.emulators.m64 import M64Params
from rovlink.link.transports.transport import free_udp_port

from ..helpers import CHROMIUM, CHROMIUM_ARGS, free_tcp_port, needs_chromium
from .acoustic_rig import end_processes, wait_for
from .conftest import _listening_socket, console_error
from .test_objects_page import at_the_standoff, holds, true_box

pytestmark = [pytest.mark.browser, pytest.mark.processes, pytest.mark.slow, needs_chromium]
ROVLINK = [sys.executable, "-m", "rovlink"]
FAST = M64Params(round_s=0.25, b_offset_s=0.125, latency_s=0.4, sync_s=1.0)


@contextlib.contextmanager
def acoustic_console(tmp, record):
    """The ROV side as processes, the console here; yields (base URL, session, scene)."""
    from rovlink.console.linkthread import LinkThread
    from rovlink.console.scene.app import ConsoleScene
    from rovlink.console.session.acoustic import AcousticSession
    from rovlink.console.web.app import create_app, serve
    from rovlink.link.acoustic.process import AcousticLinkProcess
    from rovlink.link.emulators.m64serial import M64SerialPair
    from rovlink.link.radio.auth import read_key_file

    key_path = tmp / "link.key"
    subprocess.run(ROVLINK + ["keygen", str(key_path)], check=True, capture_output=True, timeout=60)
    key = read_key_file(str(key_path))
    pair = M64SerialPair(str(tmp / "op-modem"), str(tmp / "rov-modem"), params=FAST, seed=5)
    pair.start()
    mav = free_udp_port()
    logs = [open(tmp / "sim.log", "w"), open(tmp / "rov.log", "w")]
    sim = subprocess.Popen(ROVLINK + ["sim", "--mavlink", f"udpin:127.0.0.1:{mav}", "--depth", "5"],
                           stdout=logs[0], stderr=subprocess.STDOUT)
    rov = subprocess.Popen(ROVLINK + ["rov", "--link", f"wlmodem://{tmp}/rov-modem?role=b&channel=4", "--key",
                                      str(key_path), "--mavlink", f"udpout:127.0.0.1:{mav}", "-v"],
                           stdout=logs[1], stderr=subprocess.STDOUT)
    link = LinkThread().start()
    process = AcousticLinkProcess(f"wlmodem://{tmp}/op-modem?role=a&channel=4", key)
    session = AcousticSession(None, key, record=record, link=process)
    link.spawn(session.run(), name="acoustic operator")
    scene = ConsoleScene(session, port=free_tcp_port()).start()
    app = create_app(session, viser_url=scene.url, scene=scene)
    sock = _listening_socket()
    loop, served = asyncio.new_event_loop(), {}

    def run() -> None:
        asyncio.set_event_loop(loop)
        served["task"] = loop.create_task(serve(app, sock=sock))
        with contextlib.suppress(asyncio.CancelledError):
            loop.run_until_complete(served["task"])

    thread = threading.Thread(target=run, name="acoustic web", daemon=True)
    base = f"http://127.0.0.1:{sock.getsockname()[1]}"
    thread.start()
    try:
        assert wait_for(lambda: session.vehicle() is not None, 120), "no status from the ROV over the modems"
        yield base, session, scene
    finally:
        loop.call_soon_threadsafe(served["task"].cancel)
        thread.join(15)
        scene.stop()
        link.stop_sync()
        process.close()
        session.close()
        end_processes(rov, sim)
        pair.close()
        for f in logs:
            f.close()


def test_an_acoustic_pilot_goes_to_an_object_frames_it_and_the_replay_lays_it_again(tmp_path):
    from playwright.sync_api import sync_playwright

    from rovlink.console.replaycontrol import replay
    from rovlink.console.session.acoustic import AcousticSession

    record = tmp_path / "session.jsonl"
    with acoustic_console(tmp_path, record) as (base, session, scene), sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        errors: list[str] = []
        page = browser.new_page(viewport={"width": 1366, "height": 768})
        page.on("pageerror", lambda exc: errors.append(f"uncaught: {exc}"))
        page.on("console", lambda m: errors.append(text) if (text := console_error(m)) else None)
        page.goto(base + "/?scene=off")  # (the scene's objects are read from the scene itself)
        page.wait_for_function("document.body.dataset.configured === '1' && document.body.dataset.link === 'up'",
                               timeout=60000)
        page.click("#take")
        page.wait_for_function("document.getElementById('control-text').textContent.includes('You have control')")
        # An object appears in the list and in the scene, on the floor the ROV measured.
        page.wait_for_selector("#objects li .object-goto", timeout=120000)
        assert "seabed at" in page.text_content("#seabed-text")
        pose = session.vehicle()
        obj = min(session.world_state()["objects"],
                  key=lambda o: math.hypot(o["north_m"] - pose.x_m, o["east_m"] - pose.y_m))
        oid = obj["id"]
        assert wait_for(lambda: oid in scene._object_nodes and scene._object_nodes[oid].visible, 10)
        # Go to: previewed (the path in the scene, nothing sent), then sent; it arrives at the stand-off.
        page.click(f'#objects li[data-id="{oid}"] .object-goto')
        page.wait_for_function("document.getElementById('goto-plan').dataset.previewed === '1'", timeout=30000)
        desk = scene.desk
        target = desk.target
        assert target is not None and target.order_id is None and len(target.points) >= 2
        assert wait_for(lambda: scene.preview_node.visible, 10)
        page.click("#arm")
        page.wait_for_function("document.getElementById('arm-fate').dataset.state === 'followed'", timeout=90000)
        page.click("#goto-go")
        page.wait_for_function("document.getElementById('goto-fate').dataset.state === 'arrived'", timeout=150000)
        at_the_standoff(session, target, oid, within_m=0.6, beyond_m=0.7)
        # Frame it: a thumbnail asked with its ROI on the object, following from the ROV's newest frame.
        serial = session.image_state()["serial"]
        page.click(f'#objects li[data-id="{oid}"] .object-frame')
        page.wait_for_function(f"/framed/.test(document.querySelector('#objects li[data-id=\"{oid}\"] "
                               ".object-frame-fate').textContent)", timeout=30000)
        asked = [o for o in session.orders_state() if o["kind"] == "IMAGE"][-1]
        assert asked.get("follow") is True and asked.get("drawn_on") == 0, asked

        def coded():
            s = session.image_state()
            ok = s["serial"] > serial and s["complete"] and (s["settings"] or {}).get("roi") and s["capture"]
            return s if ok and s["capture"]["pose"] else None

        shown = wait_for(coded, 240)
        assert shown, session.image_state()
        box = true_box(shown["capture"]["pose"], obj, (80, 60))
        assert box is not None and holds(shown["settings"]["roi"], box) >= 0.7, (shown["settings"], box)
        live_world = session.world_state()
        laid = wait_for(lambda: dict(scene._mosaic), 15)  # the scene's thread lays it within its 0.5 s turn
        browser.close()
        assert not errors, errors
    assert laid, "no thumbnail laid on the measured floor"

    # The recording, replayed: the same objects, the same floor, the thumbnails laid again.
    from rovlink.console.scene.app import ConsoleScene

    replayed = AcousticSession(None, None)
    again_scene = ConsoleScene(replayed, port=free_tcp_port())
    asyncio.run(replay(replayed, record, speed=64.0))
    again = replayed.world_state()
    assert again["seabed_depth_m"] is not None
    assert abs(again["seabed_depth_m"] - live_world["seabed_depth_m"]) < 0.15
    assert {o["id"] for o in live_world["objects"]} <= {o["id"] for o in again["objects"]}
    again_scene.start()
    try:
        assert wait_for(lambda: again_scene.floor_z is not None and again_scene._mosaic, 15), \
            "the replay laid no thumbnail"
        assert {o["id"] for o in live_world["objects"]} <= set(again_scene._object_nodes)
    finally:
        again_scene.stop()
