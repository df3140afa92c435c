"""The scene's views: a camera that follows the vehicle, a top view, a free
one and "centre on vehicle"; the picture's screen where it never hides the
vehicle; the uncertainty ring; the camera at the picture's capture pose.

Geometry first (no server), then the whole system: a real Stack (simulated
ArduSub, ROV node, emulated channel), the viser scene, and one headless
Chromium that opens the scene and whose camera, as the browser reports it to
viser, is checked against where the vehicle is.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest
from viser import transforms as tf

from rovlink import debt
from rovlink.console import control
from rovlink.console.scene import chase, frames
from rovlink.console.scene.app import CAMERA_IN_BODY_FLU, UNCERTAINTY_SHOWN_AFTER_S, ConsoleScene
from rovlink.console.scene.roi import roi_from_world
from rovlink.console.session.radio import MAX_SPEED_MPS, Pose
from rovlink.console.stack import Stack, StackConfig

from ..helpers import CHROMIUM, CHROMIUM_ARGS
from .test_scene import LoopThread, free_port, screen_point, wait_for

# A box around the vehicle (the mesh is 0.46 x 0.58 x 0.25 m): all of it must be seen.
MIN_SIZE = 0.02  # of the image's height: 16 pixels in an 800 pixel high view
VEHICLE_BOX = np.array([[sx * 0.3, sy * 0.3, sz * 0.15] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])


@dataclasses.dataclass(frozen=True)
class Camera:
    """A camera as viser describes it: R_world_camera (OpenCV axes: x right,
    y down, z forward), vertical fov, width / height."""
    position: np.ndarray
    wxyz: np.ndarray
    fov: float
    aspect: float
    look_at: np.ndarray | None = None

    @classmethod
    def looking(cls, eye, look_at, up, fov: float, aspect: float) -> "Camera":
        z = np.asarray(look_at, float) - eye
        z /= np.linalg.norm(z)
        x = np.cross(z, up)
        x /= np.linalg.norm(x)
        return cls(np.asarray(eye, float), tf.SO3.from_matrix(np.column_stack([x, np.cross(z, x), z])).wxyz,
                   fov, aspect, np.asarray(look_at, float))

    def image_points(self, points) -> np.ndarray:
        """Normalised image coordinates (x / tan(hfov/2), y / tan(vfov/2)) and depth."""
        r = tf.SO3(np.asarray(self.wxyz)).as_matrix()
        c = (np.asarray(points, float) - self.position) @ r
        t = math.tan(self.fov / 2)
        return np.column_stack([c[:, 0] / c[:, 2] / (t * self.aspect), c[:, 1] / c[:, 2] / t, c[:, 2]])

    def sees(self, points, min_size: float = MIN_SIZE) -> bool:
        """All points inside the view frustum (in front, within the image),
        and together at least `min_size` of the image's height tall or wide:
        a vehicle 50 m down the view is inside it, and a few pixels."""
        p = self.image_points(points)
        if not (np.all(p[:, 2] > 0.05) and np.all(np.abs(p[:, :2]) < 1.0)):
            return False
        return max(np.ptp(p[:, 0]) * self.aspect, np.ptp(p[:, 1])) / 2 >= min_size


def vehicle_corners(position) -> np.ndarray:
    return np.asarray(position, float) + VEHICLE_BOX


def screen_corners(centre, wxyz, width_m: float = chase.SCREEN_WIDTH_M, height_m: float = 3.0) -> np.ndarray:
    r = tf.SO3(np.asarray(wxyz)).as_matrix()
    return np.array([centre + r @ (sx * width_m / 2, sy * height_m / 2, 0.0) for sx in (-1, 1) for sy in (-1, 1)])


def overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Do the image bounding boxes of two projected point sets overlap?"""
    return not (a[:, 0].max() < b[:, 0].min() or b[:, 0].max() < a[:, 0].min()
                or a[:, 1].max() < b[:, 1].min() or b[:, 1].max() < a[:, 1].min())


# ----------------------------------------------------------------------
# Geometry (no server)
# ----------------------------------------------------------------------


@pytest.mark.parametrize("mode", [chase.FOLLOW, chase.TOP])
def test_chase_views_see_the_vehicle_and_the_screen_never_hides_it(mode):
    lo, hi = chase.DISTANCE_LIMITS_M[mode]
    for fov_deg in (50.0, 75.0):
        for distance in (None, lo, (lo + hi) / 2, hi):
            for yaw in (0.0, 37.0, 90.0, 200.0, -120.0):
                p = np.array([3.0, -7.0, -2.5])
                eye, look_at, up = chase.chase_view(p, yaw, mode, distance)
                camera = Camera.looking(eye, look_at, up, math.radians(fov_deg), 1.5)
                # Seen, and well seen unless the pilot zoomed out.
                assert camera.sees(vehicle_corners(p), MIN_SIZE if distance is None else 0.0), \
                    (mode, fov_deg, distance, yaw)
                centre, wxyz = chase.screen_pose(p, yaw)
                screen = camera.image_points(screen_corners(centre, wxyz))
                assert np.all(screen[:, 2] > 0), (mode, distance, yaw)  # in front of the camera
                assert not overlap(camera.image_points(vehicle_corners(p)), screen), (mode, fov_deg, distance, yaw)
                # The picture's side faces the camera (it is seen, not its back).
                normal = tf.SO3(np.asarray(wxyz)).as_matrix()[:, 2]
                assert normal @ (eye - centre) < 0
                if mode == chase.FOLLOW:
                    # Behind the vehicle and above it.
                    heading = chase.heading_vector(yaw)
                    assert (p - eye) @ heading > 0 and eye[2] > p[2]
                else:
                    # Above, looking down, north up on the screen.
                    r = tf.SO3(camera.wxyz).as_matrix()
                    assert r[2, 2] < -0.99 and -r[1, 1] > 0.05 and abs(r[0, 1]) < 1e-9


def test_a_moved_screen_still_maps_a_drag_to_the_roi():
    # The screen placed for a vehicle far away, turned: the ROI comes from its pose.
    centre, wxyz = chase.screen_pose(np.array([20.0, -14.0, -3.0]), 131.0)
    size_m, size_px = (chase.SCREEN_WIDTH_M, 3.0), (320, 240)
    r = tf.SO3(np.asarray(wxyz)).as_matrix()

    def on_screen(u, v):
        x, y = frames.pixel_to_image_plane(np.array([u, v]), size_m, size_px)
        return centre + r @ np.array([x, y, 0.0])

    roi = roi_from_world(on_screen(40.3, 30.2), on_screen(199.6, 149.9), position=centre, wxyz=wxyz,
                         size_m=size_m, size_px=size_px)
    assert roi == (40, 30, 200, 150)


def test_a_view_keeps_the_pilots_zoom_not_an_old_reports():
    view = chase.ViewerView()
    eye, look_at, _up = chase.chase_view(np.zeros(3), 0.0, chase.FOLLOW)
    assert view.zoom(look_at, 9.0) is None  # a new view: its own distance
    view.done(0.0, np.zeros(3), 0.0, eye, look_at)
    assert view.zoom(look_at, 9.0) == 9.0  # the wheel moves the camera along the line to where it looks
    assert view.zoom(look_at, 100.0) == chase.DISTANCE_LIMITS_M[chase.FOLLOW][1]
    # A report from before this view looks elsewhere: the view's own distance.
    assert view.zoom(look_at + 2.0, 3.0) == pytest.approx(chase.FOLLOW_DISTANCE_M)


def test_a_viewer_view_is_due_only_when_the_vehicle_moved_and_not_too_often():
    view = chase.ViewerView()
    p = np.zeros(3)
    assert view.mode == chase.FOLLOW and view.due(0.0, p, 0.0)
    view.done(0.0, p, 0.0)
    assert not view.due(0.1, p + 1.0, 0.0)  # too soon
    assert not view.due(1.0, p + 0.01, 0.5)  # not moved enough
    assert view.due(1.0, p, 5.0)  # turned
    view.set_mode(chase.TOP)
    assert view.due(0.0, p, 0.0)  # a new view: at once
    view.done(0.0, p, 0.0)
    assert not view.due(1.0, p, 90.0)  # top: north up, turning does not matter
    view.set_mode(chase.FREE)
    assert not view.due(5.0, p + 10.0, 0.0)  # free: the pilot's
    view.centre = True
    assert view.due(5.0, p, 0.0)
    with pytest.raises(ValueError):
        view.set_mode("orbit")


# ----------------------------------------------------------------------
# The whole system, one browser
# ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def live():
    debt.decode(debt.encode(np.zeros((16, 16, 3), np.uint8), 100))  # compile the codec here, not in a wait
    runner = LoopThread()
    stack = Stack(StackConfig(bitrate_bps=19200, delay_s=0.02))
    operator = runner.run(stack.start())
    scene = ConsoleScene(operator, port=free_port()).start()
    try:
        assert wait_for(lambda: operator.last_reply is not None, 30.0), "no reply from the ROV"
        yield dataclasses.make_dataclass("Live", ["stack", "operator", "scene"])(stack, operator, scene)
    finally:
        scene.stop()
        runner.run(stack.stop())
        runner.close()


class Reports:
    """The camera states the browser reports to viser, each with the vehicle's
    received position when it arrived."""

    def __init__(self, live, client) -> None:
        self.live = live
        self.client = client
        self.lock = threading.Lock()
        self.items: list[tuple[float, Camera, np.ndarray | None]] = []
        client.camera.on_update(self._on_update)

    def _on_update(self, camera) -> None:
        state = camera._state  # the message just received, before anyone sets it again
        cam = Camera(np.array(state.position), np.array(state.wxyz), float(state.fov),
                     state.image_width / max(1, state.image_height), np.array(state.look_at))
        with self.lock:
            self.items.append((time.monotonic(), cam, received_world(self.live.operator)))

    def latest(self) -> Camera | None:
        with self.lock:
            return self.items[-1][1] if self.items else None

    def latest_with_vehicle(self) -> tuple[Camera, np.ndarray | None] | None:
        """The last camera reported, with where the vehicle was when it came."""
        with self.lock:
            return self.items[-1][1:] if self.items else None

    def count(self) -> int:
        with self.lock:
            return len(self.items)

    def quiet(self, for_s: float = 1.0, timeout_s: float = 10.0) -> bool:
        """Wait until the browser has reported nothing new for `for_s`."""
        def still() -> bool:
            with self.lock:
                return not self.items or time.monotonic() - self.items[-1][0] >= for_s
        return wait_for(still, timeout_s)


@pytest.fixture(scope="module")
def viewer(live):
    if not os.path.exists(CHROMIUM):
        pytest.skip(f"no Chromium at {CHROMIUM}")
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright's Python package is not installed")
    scene = live.scene
    before = set(scene.server.get_clients())
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            # Small: software WebGL on two shared cores renders every frame.
            page = browser.new_page(viewport={"width": 960, "height": 640})
            page.goto(scene.url)  # on its own: its panel open (it watches; its view is its own)
            assert wait_for(lambda: set(scene.server.get_clients()) - before, 30.0), "the browser did not connect"
            client_id = next(iter(set(scene.server.get_clients()) - before))
            client = scene.server.get_clients()[client_id]
            reports = Reports(live, client)
            page.get_by_role("button", name="Centre on vehicle").wait_for(timeout=60000)
            yield dataclasses.make_dataclass("Viewer", ["page", "client_id", "reports"])(page, client_id, reports)
        finally:
            browser.close()


def received_world(operator) -> np.ndarray | None:
    r = operator.last_reply
    return None if r is None else frames.ned_to_world(r.x_cm / 100, r.y_cm / 100, r.z_cm / 100)


def received_yaw(operator) -> float:
    return operator.last_reply.yaw_cdeg / 100


def choose_view(page, label: str) -> None:
    """Pick a view in the panel's dropdown, as the pilot does."""
    page.get_by_role("combobox", name="View").click()
    page.get_by_role("option", name=label, exact=True).click()


@contextlib.contextmanager
def driving(live, speedup: bool = True):
    """Control taken by a script, the vehicle armed in DEPTH_HOLD; yields the
    holder's caller; stops and releases afterwards.  With `speedup`, the
    simulated thrusters push harder so that 50 m take ~20 s, not a minute."""
    scene, sim = live.scene, live.stack.sim
    params = sim._model.params
    if speedup:
        sim._model.params = dataclasses.replace(params, thrust_surge_n=300.0)
    holder = scene.desk.take(None, "test script")
    caller = control.Caller(holder.id)
    try:
        scene.desk.submit(control.SetMode("DEPTH_HOLD"), caller)
        scene.desk.submit(control.Arm(True), caller)
        assert wait_for(lambda: live.operator.last_reply.armed, 10.0)
        yield caller
    finally:
        scene.stop_vehicle()
        scene.desk.release(holder.id)
        sim._model.params = params


@pytest.mark.browser
def test_follow_camera_keeps_the_vehicle_in_view_while_it_drives_50_m(live, viewer):
    op, scene, reports = live.operator, live.scene, viewer.reports
    view = scene.views[viewer.client_id]
    assert view.mode == chase.FOLLOW  # by default
    # The follow camera has placed itself behind the vehicle.
    assert wait_for(lambda: reports.latest() is not None and reports.latest().sees(vehicle_corners(
        received_world(op))), 10.0), "the follow camera does not show the vehicle"
    initial = reports.latest()
    start = received_world(op)
    checked, travelled, last = 0, 0.0, start
    with driving(live) as caller:
        t0, updates0 = time.monotonic(), view.updates
        scene.desk.submit(control.Drive(vx=1.0), caller)
        while travelled < 50.0 and time.monotonic() - t0 < 40.0:
            time.sleep(0.2)
            if time.monotonic() - t0 > 8.0:  # a turn half-way: "behind" changes
                scene.desk.submit(control.Drive(vx=1.0, vyaw=0.25), caller)
            now = received_world(op)
            travelled += float(np.linalg.norm(now - last))
            last = now
            camera, then = reports.latest_with_vehicle()
            # What the browser shows now contains the vehicle where it is now.
            assert camera.sees(vehicle_corners(now)), (travelled, camera, now)
            # ...from near by, as the pilot left it (not a wide shot from afar): measured
            # against where the vehicle was when the browser reported that camera (a
            # loaded run read `now` up to 0.2 s after the report: 12.27 m at 1 m/s), with
            # what it drives in one of the chase's periods besides.
            near = 2 * chase.FOLLOW_DISTANCE_M + MAX_SPEED_MPS * chase.CHASE_PERIOD_S
            assert np.linalg.norm(camera.position - then) <= near, (camera, then, now)
            checked += 1
    assert travelled >= 50.0, f"the vehicle drove only {travelled:.1f} m"
    displacement = float(np.linalg.norm(last[:2] - start[:2]))
    assert displacement > 30.0
    # A camera left where it was would now film it from afar, or not at all (whether
    # the far vehicle is still inside the first view depends on the path the turn
    # made: a CI run ended 46 m down that view, 17 pixels tall).
    assert initial.sees(vehicle_corners(start))
    assert np.linalg.norm(initial.position - last) > 3 * chase.FOLLOW_DISTANCE_M
    assert checked > 50
    # Cheap: a few camera moves a second, not one per pose update (20 Hz).
    assert 10 < view.updates - updates0 <= (time.monotonic() - t0) / chase.CHASE_PERIOD_S + 2
    # The screen came along, ahead of the vehicle and above it, and is in view
    # (where the vehicle is now: it is still gliding to a stop).
    def screen_offset():
        pose = op.predicted_pose()
        centre, _ = chase.screen_pose(frames.ned_to_world(pose.x_m, pose.y_m, pose.z_m), pose.yaw_deg)
        return float(np.linalg.norm(np.asarray(scene.screen_node.position) - centre))

    assert wait_for(lambda: screen_offset() < 0.5, 5.0), screen_offset()


@pytest.mark.browser
def test_top_and_follow_views_chosen_in_the_panel(live, viewer):
    op, scene, page, reports = live.operator, live.scene, viewer.page, viewer.reports
    view = scene.views[viewer.client_id]
    # The legend names every kind of thing drawn.
    text = page.locator("body").inner_text()
    for words in ("last pose received", "predicted", "target", "trail", "how far off", "picture's capture"):
        assert words in text, words

    # Top: straight above the vehicle, looking down, north up.
    choose_view(page, "top")
    assert wait_for(lambda: view.mode == chase.TOP, 10.0)

    def from_above():
        cam, p = reports.latest(), received_world(op)
        r = tf.SO3(cam.wxyz).as_matrix()
        return (cam.sees(vehicle_corners(p)) and r[2, 2] < -0.99 and cam.position[2] - p[2] > 5.0
                and np.linalg.norm(cam.position[:2] - p[:2]) < 2.0 and -r[1, 1] > 0
                and abs(np.linalg.norm(cam.position - cam.look_at) - chase.TOP_HEIGHT_M) < 0.3)

    assert wait_for(from_above, 10.0), reports.latest()
    # ...and stays so (a late report of the follow camera does not set its height).
    time.sleep(1.5)
    assert from_above(), reports.latest()

    # Follow: behind the vehicle's heading, above it.
    choose_view(page, "follow")

    def behind():
        cam, p = reports.latest(), received_world(op)
        ahead = p - cam.position
        horizontal = ahead[:2] / np.linalg.norm(ahead[:2])
        return (cam.sees(vehicle_corners(p)) and horizontal @ chase.heading_vector(received_yaw(op))[:2] > 0.97
                and cam.position[2] > p[2] + 1.0)

    assert wait_for(behind, 10.0), reports.latest()
    assert view.mode == chase.FOLLOW


@pytest.mark.browser
def test_free_view_stays_put_and_centre_brings_the_vehicle_back(live, viewer):
    op, scene, page, reports = live.operator, live.scene, viewer.page, viewer.reports
    view = scene.views[viewer.client_id]
    choose_view(page, "free")
    assert wait_for(lambda: view.mode == chase.FREE, 10.0)
    try:
        assert reports.quiet()  # (the last move of the view before may still be on its way)
        fixed, n = reports.latest(), reports.count()
        start = received_world(op)
        with driving(live) as caller:
            # The vehicle drives away; the camera stays.
            scene.desk.submit(control.Drive(vx=1.0), caller)
            assert wait_for(lambda: np.linalg.norm(received_world(op) - start) > 3.0, 15.0)
            scene.desk.submit(control.Drive(), caller)
            assert np.allclose(reports.latest().position, fixed.position) and reports.count() == n
            time.sleep(1.0)  # let it slow down

            # Centre on vehicle: looking at it, from the same direction.
            page.get_by_role("button", name="Centre on vehicle").click()

            def centred():
                cam = reports.latest()
                pose = op.predicted_pose()
                p = frames.ned_to_world(pose.x_m, pose.y_m, pose.z_m)
                return (reports.count() > n and np.linalg.norm(cam.look_at - p) < 0.5
                        and cam.sees(vehicle_corners(p)))

            assert wait_for(centred, 10.0), (reports.latest(), received_world(op))
            before, after = fixed.position - fixed.look_at, reports.latest().position - reports.latest().look_at
            assert before @ after / np.linalg.norm(before) / np.linalg.norm(after) > 0.99
            assert view.mode == chase.FREE
    finally:
        scene.set_view(viewer.client_id, chase.FOLLOW)


def test_uncertainty_ring_grows_with_the_odometry_age(live, monkeypatch):
    op, scene = live.operator, live.scene
    age = {"s": 0.5}
    monkeypatch.setattr(op, "odometry_age_s", lambda: age["s"])

    def ring_radius():
        if not scene.uncertainty_node.visible:
            return None
        pts = np.asarray(scene.uncertainty_node.points).reshape(-1, 3)
        ghost = np.asarray(scene.ghost_node.position)
        return float(np.median(np.linalg.norm(pts[:, :2] - ghost[:2], axis=1)))

    # Disarmed, replies coming: it cannot drive, so the ring is only its drift (it settles
    # a few cm/s), not the 4 m of full speed.
    op.arm(False)  # (an earlier test of this module may have left it armed)
    assert wait_for(lambda: op.last_reply is not None and not op.last_reply.armed, 15.0)
    age["s"] = 4.0
    assert wait_for(lambda: op.pose_state()["uncertainty_m"] is not None and op.pose_state()["uncertainty_m"] < 0.5, 5)
    time.sleep(0.5)  # (the scene's thread redraws at 10 Hz)
    assert ring_radius() is None or ring_radius() < 0.5, ring_radius()
    # Armed, it may have gone anywhere at full speed meanwhile.
    op.arm(True)
    assert wait_for(lambda: op.last_reply.armed, 15.0)
    age["s"] = 0.5
    assert wait_for(lambda: not scene.uncertainty_node.visible, 2.0)  # fresh odometry: no ring
    radii = []
    for seconds in (2.0, 4.5, 8.0):
        age["s"] = seconds
        assert wait_for(lambda seconds=seconds: ring_radius() is not None
                        and abs(ring_radius() - MAX_SPEED_MPS * seconds) < 0.06, 2.0), (seconds, ring_radius())
        radii.append(ring_radius())
    assert radii == sorted(radii) and radii[0] >= MAX_SPEED_MPS * UNCERTAINTY_SHOWN_AFTER_S
    age["s"] = 0.2
    assert wait_for(lambda: not scene.uncertainty_node.visible, 2.0)
    op.arm(False)
    assert wait_for(lambda: not op.last_reply.armed, 15.0)


def test_frustum_is_drawn_at_the_pictures_capture_pose(live, monkeypatch):
    op, scene = live.operator, live.scene
    real = op.image_state
    if "capture" in real():
        # The operator stamps its pictures: the frustum is at the current one's pose.
        assert wait_for(lambda: real()["capture"] is not None, 30.0), "no picture with its capture pose"

        def at_the_real_capture():
            capture = real()["capture"]
            return capture is not None and scene.capture_node.visible and np.allclose(
                scene.capture_node.position, frames.ned_to_world(*(capture["pose"][k] for k in ("x_m", "y_m", "z_m"))),
                atol=1e-6)

        assert wait_for(at_the_real_capture, 5.0)
        # The picture is shown where it was taken, not on the camera now.
        assert wait_for(lambda: scene.capture_frustum_node.image is not None and scene.frustum_node.image is None,
                        5.0)
    # A capture pose unlike the vehicle's: the frustum goes there, on the camera's mount.
    pose = {"x_m": 4.0, "y_m": -3.0, "z_m": 5.5, "roll_deg": 0.0, "pitch_deg": 10.0, "yaw_deg": 135.0}
    capture = {"pose": pose, "wall": time.time() - 3.0, "t": op.now() - 3.0}
    monkeypatch.setattr(op, "image_state", lambda: {**real(), "capture": capture})
    position, wxyz = frames.pose_to_world(Pose(**pose))
    # Position and orientation are set one after the other by the scene's thread: wait for both.
    assert wait_for(lambda: scene.capture_node.visible and np.allclose(scene.capture_node.position, position)
                    and (np.allclose(scene.capture_node.wxyz, wxyz, atol=1e-9)
                         or np.allclose(scene.capture_node.wxyz, -wxyz, atol=1e-9)), 3.0), scene.capture_node.wxyz
    assert np.allclose(scene.capture_frustum_node.position, CAMERA_IN_BODY_FLU)
    assert scene.capture_frustum_node.aspect == pytest.approx(scene.image_px[0] / scene.image_px[1])
    # No capture known: nothing drawn.
    monkeypatch.setattr(op, "image_state", lambda: {**real(), "capture": None})
    assert wait_for(lambda: not scene.capture_node.visible, 3.0)
    # ...and the picture back on the camera now.
    assert wait_for(lambda: scene.frustum_node.image is not None and scene.capture_frustum_node.image is None, 5.0)


def test_the_screen_holds_still_while_the_pilot_drags_on_it(live):
    scene = live.scene
    held = np.array(scene.screen_node.position)
    a = screen_point(scene, 40.0, 30.0)
    # A watcher's drag (refused, put back) holds the screen as well as the pilot's.
    drag = SimpleNamespace(phase="start", start_position=tuple(a), end_position=tuple(a),
                           client=SimpleNamespace(client_id=-1))
    scene._on_screen_drag(drag)
    assert scene.dragging
    # The vehicle "moves" far away: the screen would follow, but not under the pointer.
    scene._screen_next_at = 0.0
    scene.place_screen(Pose(30.0, 20.0, 3.0, 0.0, 0.0, 90.0))
    time.sleep(0.6)  # the scene's loop holds it too
    assert np.allclose(scene.screen_node.position, held)
    drag.phase = "end"
    scene._on_screen_drag(drag)
    assert not scene.dragging
    scene._screen_next_at = 0.0
    far = Pose(30.0, 20.0, 3.0, 0.0, 0.0, 90.0)
    scene.place_screen(far)
    centre, _ = chase.screen_pose(frames.ned_to_world(30.0, 20.0, 3.0), 90.0)
    moved_there = np.allclose(scene.screen_node.position, centre)
    # (the loop puts it back on the vehicle at its next turn)
    assert moved_there or wait_for(lambda: not np.allclose(scene.screen_node.position, held), 1.0)
