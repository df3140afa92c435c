"""The objects the ROV recognised, in the cockpit (issue 38, docs/PROTOCOL.md §11), on the
radio link: the whole running system (the simulated ROV recognising objects, version 2,
a tracker for FOLLOW) with the page and its embedded 3-D scene, driven as a pilot in
headless Chromium.  An object appears in the scene and in the page's list; its "Go to"
previews a path, Send flies it, and the vehicle stops at the stand-off facing it; "Frame
it" sets the next picture's ROI on it (the picture coded with an ROI that holds the
object's true box).  The scene's own selection orders only for the page that holds
control; an object out of view is said in one line, and no ROI goes."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from rovlink.console import control
from rovlink.console.session.world import STANDOFF_M
from rovlink.link.scene import SeenObject
from rovlink.rov.camera import SimulatedCamera
from rovlink.rov.seabed import Seabed

from ..helpers import needs_chromium
from .conftest import running_console, wait_for
from .pages import take_control


@pytest.fixture(scope="module")
def live():
    # 3 m over the seabed, amphorae ahead: objects in view from the start.
    # The ROV's failsafe at its real 3 s, not the tests' 1 s: a loaded machine's pause in the
    # link would otherwise brake the go-to this module flies.
    with running_console(scene=True, objects=True, tracker="klt", start_depth_m=5.0, failsafe_s=3.0) as console:
        yield console


def nearest_true(obj: dict):
    """The simulator's own object (its truth) the ROV's recognised `obj` is."""
    return min(Seabed.load().objects, key=lambda t: math.hypot(t.x_m - obj["north_m"], t.y_m - obj["east_m"]))


def true_box(pose: dict, obj: dict, size_px: tuple[int, int]):
    """Where the object truly lies in a picture of `size_px` taken from `pose` (rov/camera.py)."""
    camera = SimulatedCamera(*size_px, seabed=Seabed.load())
    at = SimpleNamespace(x_m=pose["x_m"], y_m=pose["y_m"], z_m=pose["z_m"], roll_rad=math.radians(pose["roll_deg"]),
                         pitch_rad=math.radians(pose["pitch_deg"]), yaw_rad=math.radians(pose["yaw_deg"]))
    return camera.object_box(at, nearest_true(obj)).clipped


def holds(roi, box) -> float:
    """The share of `box` inside `roi`."""
    x0, y0, x1, y1 = max(roi[0], box[0]), max(roi[1], box[1]), min(roi[2], box[2]), min(roi[3], box[3])
    return max(0.0, x1 - x0) * max(0.0, y1 - y0) / max(1e-9, (box[2] - box[0]) * (box[3] - box[1]))


def fate_text(page, oid: int) -> str:
    return page.text_content(f'#objects li[data-id="{oid}"] .object-frame-fate') or ""


def at_the_standoff(session, target, oid: int, *, within_m: float, beyond_m: float) -> None:
    """The vehicle where a go-to to object `oid` put it: within `within_m` of the target,
    at the stand-off from the object as last told (up to `beyond_m` past its half
    length), facing it within 15 degrees."""
    there = session.vehicle()
    obj = next(o for o in session.world_state()["objects"] if o["id"] == oid)
    assert math.hypot(there.x_m - target.x_m, there.y_m - target.y_m) < within_m, (there, target)
    off = math.hypot(obj["north_m"] - there.x_m, obj["east_m"] - there.y_m)
    assert STANDOFF_M - 0.3 < off < STANDOFF_M + obj["length_m"] / 2 + beyond_m, (off, obj)
    bearing = math.degrees(math.atan2(obj["east_m"] - there.y_m, obj["north_m"] - there.x_m))
    assert abs((there.yaw_deg - bearing + 180) % 360 - 180) < 15, (there.yaw_deg, bearing)


@pytest.mark.browser
@needs_chromium
def test_a_pilot_goes_to_an_object_and_frames_it(open_page, live):
    op, scene, desk = live.operator, live.scene, live.app.state.desk
    page = open_page(scene=True)  # (its own viewer of the scene orders)
    take_control(page)
    # An object appears in the page's list and in the scene, a box on the measured floor.
    page.wait_for_selector("#objects li .object-goto", timeout=90000)
    assert "seabed at" in page.text_content("#seabed-text")
    pose = op.vehicle()
    obj = min(op.world_state()["objects"], key=lambda o: math.hypot(o["north_m"] - pose.x_m, o["east_m"] - pose.y_m))
    oid = obj["id"]
    assert wait_for(lambda: oid in scene._object_nodes and scene._object_nodes[oid].visible, 10)
    assert scene.floor_z is not None

    # Its "Go to": the stand-off previewed, the path drawn, nothing sent.
    page.click(f'#objects li[data-id="{oid}"] .object-goto')
    page.wait_for_function("document.getElementById('goto-plan').dataset.previewed === '1'", timeout=30000)
    target = desk.target
    assert target is not None and target.order_id is None and len(target.points) >= 2
    assert wait_for(lambda: scene.preview_node.visible, 10), "no path in the scene"
    assert not [o for o in op.orders_state() if o["kind"] == "POSITION"]

    # Armed, Sent: it arrives at the stand-off, facing the object.
    page.click("#arm")
    page.wait_for_function("document.getElementById('arm-fate').dataset.state === 'followed'", timeout=30000)
    page.click("#goto-go")
    page.wait_for_function("document.getElementById('goto-fate').dataset.state === 'arrived'", timeout=120000)
    at_the_standoff(op, target, oid, within_m=0.5, beyond_m=0.6)

    # "Frame it": the next picture is coded with an ROI that holds the object.
    serial = op.image_state()["serial"]
    page.click(f'#objects li[data-id="{oid}"] .object-frame')
    page.wait_for_function(f"/framed/.test(document.querySelector('#objects li[data-id=\"{oid}\"] "
                           ".object-frame-fate').textContent)", timeout=30000)
    assert "ROI [" in fate_text(page, oid) and "not framed" not in fate_text(page, oid)
    asked = op.requested_settings
    assert asked.roi is not None

    def coded() -> dict | None:
        s = op.image_state()
        ok = s["serial"] > serial + 1 and s["complete"] and (s["settings"] or {}).get("roi") and s["capture"]
        return s if ok and s["capture"]["pose"] else None

    shown = wait_for(coded, 60)
    assert shown, op.image_state()
    roi = shown["settings"]["roi"]
    box = true_box(shown["capture"]["pose"], obj, (320, 240))
    assert box is not None and holds(roi, box) >= 0.8, (roi, box)
    # The fate beside the button follows the IMAGE order to the vehicle's word.
    page.wait_for_function(f"document.querySelector('#objects li[data-id=\"{oid}\"] .object-frame-fate')"
                           ".dataset.outcome === 'done'", timeout=30000)

    # The scene: the object selected there, in the panel of the page's own viewer, orders
    # through the desk as the page does (Go to previews; Frame it frames) ...
    client_id = page.evaluate("document.body.dataset.clientId")
    key = desk._clients[client_id].scene_key
    assert key is not None
    assert wait_for(lambda: any(scene.viewer_key(cid) == key for cid in list(scene.panels)), 60), "no scene viewer"
    viewer = next(cid for cid in list(scene.panels) if scene.viewer_key(cid) == key)
    assert scene.select_object(oid, viewer)
    panel = scene.panels[viewer]
    assert f"Object #{oid}" in panel.object_md.content
    desk.submit(control.ClearTarget(), control.Caller(client_id))
    assert panel.goto_object() and desk.target is not None and desk.target.order_id is None
    assert "previewed" in panel.object_fate_md.content
    assert panel.frame_object() is not None and "framed" in panel.object_fate_md.content


def test_the_scene_orders_for_the_holders_page_only_and_says_why_not_in_one_line(live):
    """A viewer whose page does not hold control selects an object and sees it, but its Go to
    and Frame it are refused, said under the buttons; an object out of view is never framed."""
    from rovlink.console.scene.panel import ControlPanel, PanelCallbacks

    op, scene, desk = live.operator, live.scene, live.app.state.desk
    assert wait_for(lambda: op.world_state()["objects"], 90), op.world_state()
    oid = op.world_state()["objects"][0]["id"]
    watcher = ControlPanel(scene.server.gui, op, PanelCallbacks(
        submit=lambda order: desk.submit(order, control.Caller(scene_key=None, via="scene"))), image_px=scene.image_px)
    script = desk.take(None, "script")
    try:
        watcher.select_object(next(o for o in op.world_state()["objects"] if o["id"] == oid))
        before = len(op.orders_state())
        assert watcher.frame_object() is None and "Not sent" in watcher.object_fate_md.content
        assert "only watch" in watcher.object_fate_md.content
        assert watcher.goto_object() is None and len(op.orders_state()) == before
        # The holder asks to frame one the camera cannot see from where the ROV is (told by
        # the link 40 m off): one line, beside the control and in the log; no ROI goes.
        pose = op.vehicle()
        op.world.object_seen(SeenObject(200, "pipe", 0.9, pose.x_m - 40.0, pose.y_m, 3.0, 0.3, 0.0, True), 9, op.now())
        try:
            with pytest.raises(control.OrderError) as refused:
                desk.submit(control.FrameObject(200), control.Caller(script.id))
        finally:
            op.world.object_removed(200, op.now())
        assert "not in view of the camera from where the ROV is" in str(refused.value), refused.value
        assert len(op.orders_state()) == before
        assert any("Frame it: object #200" in e["text"] and "not in view" in e["text"] for e in op.log_entries(20))
        with pytest.raises(control.OrderError):
            desk.submit(control.FrameObject(999), control.Caller(script.id))
    finally:
        desk.release(script.id)


@pytest.mark.browser
@needs_chromium
def test_with_no_rangefinder_the_page_and_the_scene_say_seabed_depth_unknown_and_draw_no_floor(open_page, live):
    """The vehicle's rangefinder stops reporting (as a real ArduSub without one, which sends
    no range the bridge may use): the ROV tells no altitude (§11's ALT 0), the page says
    "seabed depth unknown" with why, the scene hides its floor, the pictures laid on it and
    the objects, and its panel says so too.  It comes back with the rangefinder."""
    op, scene, sim = live.operator, live.scene, live.stack.sim
    page = open_page()
    page.wait_for_function("/seabed at/.test(document.getElementById('seabed-text').textContent)", timeout=90000)
    assert wait_for(lambda: scene.floor_z is not None and scene.floor_node.visible, 10)
    sim.has_rangefinder = False
    try:
        page.wait_for_function("document.getElementById('seabed-text').textContent === "
                               "'seabed depth unknown: the ROV reports no altitude (no rangefinder)'", timeout=30000)
        assert "stale" in page.get_attribute("#seabed-text", "class")
        # (The scene's loop hides the floor, then lays its objects again, then the pictures:
        # each is waited for, not caught between two steps.)
        def drawn() -> dict:
            return {"floor": scene.floor_z is not None or scene.floor_node.visible,
                    "objects": [oid for oid, node in scene._object_nodes.items() if node.visible],
                    "pictures": [n for n, (_floor, node) in scene._mosaic.items() if node.visible]}

        assert wait_for(lambda: not any(drawn().values()), 10), drawn()
        assert any("seabed depth unknown: the ROV reports no altitude" in e["text"] for e in op.log_entries(50))
        viewer = next(iter(scene.panels.values()), None)
        if viewer is not None:  # the page's embedded scene, when its viewer is connected
            assert wait_for(lambda: "seabed depth unknown" in viewer.world_md.content
                            and "no floor drawn" in viewer.world_md.content, 10), viewer.world_md.content
    finally:
        sim.has_rangefinder = True
    page.wait_for_function("/seabed at/.test(document.getElementById('seabed-text').textContent)", timeout=30000)
    assert wait_for(lambda: scene.floor_z is not None, 10)


@pytest.mark.browser
@needs_chromium
def test_an_object_record_out_of_range_on_the_wire_is_counted_and_ignored(open_page, live):
    """A record of a reserved class (§11.3) in a reply, authentic: the console takes the
    reply, ignores the record and counts it, says it once in the log; the page shows the
    count; the link and the world go on."""
    from rovlink.link.scene import OP_NEW, ObjectRecord

    op = live.operator
    page = open_page()
    page.wait_for_function("/seabed at/.test(document.getElementById('seabed-text').textContent)", timeout=90000)
    before = op.world_state()["records_ignored"]
    reports = op.link_state()["reports"]
    live.loop.call_soon_threadsafe(live.stack.node.scene.put, ObjectRecord(OP_NEW, 60, 6, 3, 80, 41, 18, 16, 50))
    assert wait_for(lambda: op.world_state()["records_ignored"] == before + 1, 30), op.world_state()
    page.wait_for_function("/bad object records ignored/.test(document.getElementById('seabed-text').textContent)",
                           timeout=30000)
    assert 60 not in {o["id"] for o in op.world_state()["objects"]}
    assert wait_for(lambda: op.link_state()["reports"] > reports + 3, 10)  # the replies still taken
    if before == 0:
        assert sum("object record out of range was ignored" in e["text"] for e in op.log_entries(200)) == 1
