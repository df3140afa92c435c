"""FOLLOW on the console (issue 34, docs/PROTOCOL.md §10): over REST and in headless
Chromium against the whole running system, whose simulated ROV has a tracker.  An ROI
dragged on a picture and set to follow; the vehicle turned with the keys; the ROI each
picture was coded with (drawn solid) moves with what it framed; the page says when
the track is lost."""

from __future__ import annotations

import pytest

from rovlink.link.radio.messages import FollowSettings

from ..helpers import free_tcp_port, get_json, needs_chromium
from .conftest import running_console, wait_for
from .pages import drag_roi, take_control, wish

FIRST_IMAGE_MS = 90000


def post(url: str, body: dict, headers: dict | None = None) -> tuple[int, dict]:
    import json
    import urllib.error
    import urllib.request

    request = urllib.request.Request(url, json.dumps(body).encode(), method="POST",
                                     headers={"Content-Type": "application/json", **(headers or {})})
    try:
        with urllib.request.urlopen(request, timeout=10) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


@pytest.fixture(scope="module")
def live():
    # 3 m over the seabed, amphorae ahead on the right: something to follow.
    with running_console(tracker="klt", start_depth_m=5.0) as console:
        yield console


def test_follow_over_rest_codes_each_picture_with_the_tracked_roi_and_its_track(live):
    assert wait_for(lambda: live.operator.image_state()["serial"] >= 2, 90), "no picture"
    img = live.operator.image_state()["img"]
    status, taken = post(live.url + "/api/control/take", {"name": "script"})
    assert status == 200, taken
    headers = {"X-Rovlink-Client": taken["client_id"]}
    status, sent = post(live.url + "/api/image/follow", {"roi": [160, 96, 272, 180], "img": img, "keep": False},
                        headers)
    assert status == 200 and sent["kind"] == "IMAGE", sent
    assert isinstance(live.operator.requested_settings, FollowSettings)
    assert live.operator.requested_settings.drawn_on == img and not live.operator.requested_settings.keep
    assert wait_for(lambda: (get_json(live.url + "/api/image").get("track") or {}).get("state") == "holds", 60), \
        get_json(live.url + "/api/image")
    state = get_json(live.url + "/api/image")
    assert state["track"] == {"state": "holds", "keep": False, "lost_for_s": 0.0}
    roi = state["settings"]["roi"]  # the ROI the ROV coded the picture with (its DEBT header's)
    assert roi is not None and roi[0] < roi[2] <= 320 and roi[1] < roi[3] <= 240
    # The pictures kept say it too, once complete.
    assert wait_for(lambda: any((e.get("track") or {}).get("state") == "holds" and e["settings"]["roi"]
                                for e in get_json(live.url + "/api/images")), 60)
    # No ROI: refused before anything goes.
    status, refused = post(live.url + "/api/image/follow", {"roi": [0, 0, 0, 0], "img": 0}, headers)
    assert status == 422 and "ROI" in refused["message"], refused
    post(live.url + "/api/control/release", {}, headers)


def test_the_scene_draws_the_ray_from_the_capture_through_the_coded_roi_to_the_seabed(live):
    import numpy as np

    from rovlink.console import control
    from rovlink.console.scene import frames
    from rovlink.console.scene.app import CAMERA_IN_BODY_FLU, ConsoleScene
    from rovlink.console.scene.follow import followed_ray
    from rovlink.console.scene.panel import ControlPanel, PanelCallbacks

    desk = live.app.state.desk
    scene = ConsoleScene(live.operator, port=free_tcp_port())
    scene.use_desk(desk)
    scene.start()
    holder = desk.take(None, "test script")
    try:
        assert wait_for(lambda: live.operator.image_state()["img"] is not None, 60)
        # The scene's panel: an ROI dragged on the scene's picture (an IMAGE order), then Follow ROI.
        panel = ControlPanel(scene.server.gui, live.operator, PanelCallbacks(
            submit=lambda order: desk.submit(order, control.Caller(holder.id))), image_px=scene.image_px)
        desk.submit(control.ChangeImage(roi=(160, 96, 272, 180), shift=6), control.Caller(holder.id))
        shown = live.operator.image_state()["img"]
        assert panel.follow_roi() is not None
        followed = live.operator.requested_settings
        assert isinstance(followed, FollowSettings) and followed.roi == (160, 96, 272, 180) and followed.keep
        assert followed.drawn_on == shown
        assert wait_for(lambda: (live.operator.image_state().get("track") or {}).get("state") == "holds", 60)
        assert wait_for(lambda: scene.follow_node.visible, 10), "no ray drawn"
        # The seabed as a ROV with a rangefinder tells it (this stack's link, version 1.1, carries no
        # altitude, §11): the ray then ends on that floor, the one the ROV measured.
        z = live.operator.vehicle().z_m
        live.operator.world.altitude(scene.seabed.depth_m - z, live.operator.now(), z)
        assert wait_for(lambda: scene.floor_z is not None, 10), "no floor drawn"

        def drawn_as_state() -> bool:
            image = live.operator.image_state()
            want = followed_ray(image["capture"]["pose"], image["settings"]["roi"], hfov_deg=scene.hfov_deg,
                                tilt_deg=scene.tilt_deg, size_px=scene.image_px, camera_in_body_flu=CAMERA_IN_BODY_FLU,
                                floor_z=scene.floor_z)
            return np.allclose(np.asarray(scene.follow_node.points)[0], want, atol=1e-3)

        assert wait_for(drawn_as_state, 10)
        hit = np.asarray(scene.follow_node.points)[0][1]
        assert hit[2] == pytest.approx(scene.floor_z, abs=1e-3)  # it ends on the measured seabed
        assert frames.world_to_ned(hit)[0] > live.operator.image_state()["capture"]["pose"]["x_m"]  # ahead (north)
        # A plain IMAGE order ends the following: the ray goes once the pictures say no track.
        panel.refresh()
        assert "track holds" in panel.image_md.content or "track lost" in panel.image_md.content
        desk.submit(control.ChangeImage(roi=None), control.Caller(holder.id))
        assert wait_for(lambda: not scene.follow_node.visible, 60)
    finally:
        desk.release(holder.id)
        scene.stop()


SHOWN = """() => {
  const box = document.getElementById('roi-box');
  const track = document.getElementById('track-text');
  return [document.getElementById('image').dataset.key || '', box.hidden ? null : parseFloat(box.style.left),
          track.dataset.state || '', track.textContent];
}"""


@pytest.mark.browser
@needs_chromium
def test_a_followed_roi_moves_with_its_object_as_the_vehicle_turns_and_the_page_says_the_track_is_lost(
        open_page, live):
    page = open_page()
    take_control(page)
    page.click("#arm")
    page.wait_for_function("document.getElementById('armed').textContent === 'ARMED'", timeout=30000)
    page.wait_for_selector("#image[data-decoded-bytes]", state="visible", timeout=FIRST_IMAGE_MS)
    # An ROI round the amphorae, dragged on the arriving picture, set to follow.
    drag_roi(page, "#image", (0.5, 0.4), (0.85, 0.75))
    assert page.is_visible("#roi-follow") and page.is_checked("#roi-keep")
    page.click("#roi-follow")
    assert wait_for(lambda: isinstance(live.operator.requested_settings, FollowSettings), 5), "no FOLLOW order"
    page.wait_for_function("document.getElementById('track-text').dataset.state === 'holds'", timeout=60000)
    assert "track holds" in page.text_content("#track-text")

    # Turning right in taps of E: what the ROI framed slides left, picture after picture, then out.
    def shown():
        key, left, state, text = page.evaluate(SHOWN)
        return int(key.split(":")[0] or 0), left, state, text

    # (The track's state comes with the telemetry, the picture it was coded for a moment
    # later, once loaded: its ROI is drawn then.)
    assert wait_for(lambda: shown()[1] is not None, 30), shown()
    lefts, last = [shown()[1]], shown()
    # A tap turns the vehicle for as long as the console holds the wish, and on a loaded
    # machine the page's letting go reaches it later: a tap of 400 ms then turned twice
    # as far (80 -> 38 px, then out). So each tap is held for what moves the ROI about
    # 20 px, judged from the tap before: the object stays in view for a few pictures
    # however busy the machine.
    hold_ms = 400.0
    for _ in range(20):
        page.keyboard.down("KeyE")
        try:
            assert wait_for(lambda: wish(live)["vyaw"] > 0, 5), "E sent no yaw"
            page.wait_for_timeout(hold_ms)
        finally:
            page.keyboard.up("KeyE")
        assert wait_for(lambda: wish(live)["vyaw"] == 0, 3), "letting go of E did not stop the turn"
        serial = shown()[0]
        # Two pictures later: one captured after the turn, drawn with the ROI it was coded with.
        assert wait_for(lambda serial=serial: shown()[0] >= serial + 2, 60), "no new picture"
        last = shown()
        if last[2] != "holds":
            break
        moved = lefts[-1] - last[1]
        lefts.append(last[1])
        if moved > 0:
            hold_ms = min(400.0, hold_ms * 20.0 / moved)
    _, left_lost, state, text = last
    assert state == "lost" and "track LOST" in text and "last ROI kept" in text, last
    assert left_lost is not None  # kept: the last ROI is still drawn
    assert len(lefts) >= 3, lefts
    assert all(b <= a + 2 for a, b in zip(lefts, lefts[1:])) and lefts[-1] < lefts[0] - 20, lefts  # it went left
    assert wait_for(lambda: wish(live)["vyaw"] == 0, 3)
    page.keyboard.press("Space")
