"""The operator's 3-D scene in viser: what UWSim was to the published system.

Goals
- Show the pilot, in one scene, where the vehicle was when it last spoke (the
  solid ROV with its trail), where it probably is now (a translucent ghost placed
  by dead reckoning), what its camera covers (a frustum and its footprint on the
  seabed), and the latest picture as it refines trunk after trunk.
- Let the pilot act through the scene as well as the panel: drag a rectangle on
  the picture to choose the next image's region of interest; move a target with a
  gizmo, see the ghost and the predicted path there, and only then Send it.
  Nothing moves until the pilot confirms.
- Never slow the link: the scene reads the operator's state, it does not drive
  it.  Poses are pushed at `update_hz` (20 Hz) from one background thread; the
  picture only when a new decode arrives; the panel's numbers and plots at 2 Hz.

Plan
- `ConsoleScene(operator, host=, port=)`; `.start()` builds every node once and
  keeps its handle, then updates the handles in place; `.stop()`.
- Every order goes through the command layer (`rovlink.console.control`):
  the web app hands the scene its desk (`use_desk`); alone, the scene makes
  its own, which nobody holds, so that its viewers only watch.  The target
  ghost, the sliders and the ROI render the desk's and the operator's events.
- The panel is built per viewer on `client.gui`; a viewer who may not order
  gets its order controls disabled (STOP stays open).
- Frames are those of `console.scene.frames` (world ENU, z up; see there).
- Each viewer chooses its view (`console.scene.chase`): its camera follows
  the vehicle by default (follow, top) or is left to it (free); the loop sets
  it a few times a second at most, when the vehicle moved.  The picture's
  screen is carried ahead of and above the vehicle, where those views never
  find it in front of the vehicle (the decision is written in chase.py).
- A viewer opened by the operator page (its WebSocket path carries a scene
  key) gets its control panel minimized: the page has its own controls, and
  the 3-D view stays free; the pilot opens the panel with its "+" button.  The
  view's own small window (view, centre, legend) stays open in a corner.
- The picture's capture pose (the operator's `image_state()["capture"]`) is
  drawn as a second camera frustum, in its own colour, showing the picture
  where it was taken; while it is unknown the camera now shows the picture.
- viser callbacks are one-liners that delegate to plain methods, which the tests
  call directly: `preview_roi_world` / `select_roi_world` (the picture's drag),
  `move_target` (the gizmo), `send_target`, `stop_vehicle`.
  The drag callback is `async def`, so its start/update/end phases run in order
  on viser's loop; the methods it reaches only take the operator's lock briefly.
- The panel (`console.scene.panel`) holds every GUI control and the plots.
- Who may order: a viewer opened by the operator page carries the page's
  scene key in its WebSocket path (`/rovlink/<key>`); the desk allows it
  while that page holds control.  The gizmo and the picture's drag are
  shared scene nodes: a refused drag is put back, with a notification.
"""

from __future__ import annotations

import contextlib
import io
import json
import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import viser
from PIL import Image
from viser import transforms as tf

from rovlink import debt
from rovlink.assets import ASSETS_DIR
from rovlink.console import control
from rovlink.console.control import CONSOLE, Caller, ControlDesk, NotHolder
from rovlink.console.session.base import OrderError
from rovlink.console.session.contract import VehicleSession
from rovlink.console.session.odometry import Pose
from rovlink.console.session.world import CAMERA_HFOV_DEG, CAMERA_IN_BODY_FLU, CAMERA_TILT_DEG

from . import chase, frames, mosaic
from .chase import SCREEN_WIDTH_M, ViewerView
from .colours import CAPTURE_RGB, FOLLOW_RGB, FRUSTUM_RGB, GHOST_RGB, OBJECT_RGB, ROV_RGB, TARGET_RGB, UNCERTAINTY_RGB
from .follow import followed_ray
from .panel import ControlPanel, PanelCallbacks
from .roi import draw_roi, roi_from_world, roi_outline
from .rov_model import load_rov_mesh

log = logging.getLogger("rovlink.console.scene")


# The ROV's camera (CAMERA_*: rov/camera.py SimulatedCamera's defaults, a test checks they
# agree) is named once in console/session/world.py, which "Frame it" projects through.
DEFAULT_IMAGE_PX = (320, 240)
SCENE_KEY_PATH = "/rovlink/"  # the operator page opens the scene's WebSocket at SCENE_KEY_PATH + key
REFUSAL_NOTICE_S = 3.0         # at most one "not sent" notification per viewer this often
DRAG_HOLD_MAX_S = 20.0         # the screen and the views wait this long at most for a drag's end
UNCERTAINTY_SEGMENTS = 48
UNCERTAINTY_SHOWN_AFTER_S = 1.5  # odometry older than this: the ring around the ghost shows how far it may be
UNCERTAINTY_SHOWN_M = 0.1  # a ring smaller than this says nothing (a parked, disarmed vehicle)


def scene_key_from_path(path: str | None) -> str | None:
    """The scene key in a viewer's WebSocket path, or None."""
    if not path:
        return None
    path = path.partition("?")[0]
    if not path.startswith(SCENE_KEY_PATH):
        return None
    return path[len(SCENE_KEY_PATH):].strip("/") or None


def viewer_path(server, client_id: int) -> str | None:
    """The path a viewer opened its WebSocket with.  viser keeps it only in
    its WebSocket server's connection (viser 1.1); when that changes this
    gives None and the viewer can only watch (the safe side), and
    tests/console/test_scene_control.py fails."""
    try:
        return server._websock_server._live_connections[client_id].request.path
    except (AttributeError, KeyError, TypeError):
        return None

# The initial view, until the follow camera takes over: from behind the start
# point (south-east, a little above), looking down at the vehicle, 2 m deep.
VIEW_POSITION = (2.6, -5.0, -0.2)
VIEW_LOOK_AT = (-0.3, 1.2, -2.8)
START_POSITION = (0.0, 0.0, -2.0)  # where the screen waits for the first odometry

TRAIL_POINTS = 600
FOOTPRINT_RANGE_M = 14.0
MOSAIC_KEPT = 12  # pictures laid on the floor at once
# A floor told this much off the one a picture was laid on: the picture lifted onto it, not
# decoded and warped again (the altitude moves by its 5 cm steps as the vehicle does; twelve
# pictures re-laid at every step cost the scene's thread seconds on a loaded machine).
MOSAIC_RELAY_M = 0.1
NO_FLOOR_Z = -1.0e6  # a plane no ray meets within its range

@dataclass(frozen=True)
class SeabedAsset:
    texture: np.ndarray  # H x W x 3, row 0 north, column 0 west
    depth_m: float
    x_min_m: float
    x_max_m: float
    y_min_m: float
    y_max_m: float

    @classmethod
    def load(cls, meta_path: Path = ASSETS_DIR / "seabed.json") -> "SeabedAsset":
        meta = json.loads(meta_path.read_text())
        with Image.open(meta_path.parent / meta["texture"]) as image:
            texture = np.asarray(image.convert("RGB"), dtype=np.uint8)
        return cls(texture, float(meta["depth_m"]), float(meta["x_min_m"]), float(meta["x_max_m"]),
                   float(meta["y_min_m"]), float(meta["y_max_m"]))

    @property
    def floor_z(self) -> float:
        """The seabed's height in the world frame (z up)."""
        return -self.depth_m


def as_rgb(picture: np.ndarray) -> np.ndarray:
    """Decoded pictures are H x W (grey) or H x W x 3; viser wants RGB uint8."""
    p = np.asarray(picture)
    if p.dtype != np.uint8:
        p = np.clip(p, 0, 255).astype(np.uint8)
    if p.ndim == 2:
        p = np.repeat(p[:, :, None], 3, axis=2)
    return np.ascontiguousarray(p[:, :, :3])


def _show(handle) -> None:
    # Every assignment is a message to each browser: only when it changes.
    if not handle.visible:
        handle.visible = True


class ConsoleScene:
    def __init__(self, operator: VehicleSession, *, host: str = "127.0.0.1", port: int = 8080,
                 update_hz: float = 20.0, hfov_deg: float = CAMERA_HFOV_DEG, tilt_deg: float = CAMERA_TILT_DEG,
                 verbose: bool = False, sim_seabed: bool = False) -> None:
        self.operator = operator
        self.host = host
        self.port = port
        self.update_hz = float(update_hz)
        self.hfov_deg = float(hfov_deg)
        self.tilt_deg = float(tilt_deg)
        self.verbose = verbose
        # The simulator's seabed is the simulator's truth: only `rovlink demo` offers it, as a
        # layer labelled so and off by default; the floor drawn is the one the ROV measured.
        self.seabed = SeabedAsset.load()
        self.sim_seabed = sim_seabed
        self.floor_z: float | None = None  # the measured seabed (world z, up); None: no floor
        self._objects_shown: dict[int, tuple] = {}  # what each object's box was laid from
        self._object_nodes: dict[int, object] = {}
        self._mosaic: dict[int, tuple] = {}  # picture serial -> (floor it was laid on, its node)
        self.rov_mesh = load_rov_mesh()
        self.server: viser.ViserServer | None = None
        self.panels: dict[int, ControlPanel] = {}  # one per viewer, by viser's client id
        self.desk: ControlDesk | None = None
        self._own_desk = False
        self.image_px = DEFAULT_IMAGE_PX  # (width, height) of the picture shown
        self.frames_pushed = 0  # pose updates pushed; the tests watch it move
        self.images_shown = 0
        self._image_dirty = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._unsubscribe = None
        self._last_received: Pose | None = None
        self._last_predicted: Pose | None = None
        self._trail_shown = None
        self._last_preview_at = 0.0
        self._lock = threading.RLock()
        self.orders_refused = 0
        self._refused_at: dict[int, float] = {}
        self._wish_dirty = threading.Event()
        self._settings_dirty = threading.Event()
        self._control_dirty = threading.Event()
        self.views: dict[int, ViewerView] = {}  # each viewer's choice of view, by viser's client id
        self._screen_at: tuple | None = None     # the vehicle pose the screen was last placed for
        self._screen_next_at = 0.0
        self._drag_since: float | None = None    # a ROI drag on the screen: neither it nor the views move
        self._capture_shown = None

    # ------------------------------------------------------------------
    # Life cycle
    # ------------------------------------------------------------------

    @property
    def url(self) -> str:
        port = self.server.get_port() if self.server is not None else self.port
        return f"http://{self.host}:{port}"

    def _quiet(self):
        """viser prints a box of its own address (and "Server stopped") whatever `verbose`
        says, before the console names the operator page: unless verbose, it goes nowhere;
        the console's own lines give the scene's watch-only address."""
        return contextlib.nullcontext() if self.verbose else contextlib.redirect_stdout(io.StringIO())

    def start(self) -> "ConsoleScene":
        with self._quiet():
            self.server = viser.ViserServer(host=self.host, port=self.port, verbose=self.verbose)
        self.server.gui.configure_theme(control_width="large", dark_mode=True, show_logo=False)
        self._build_environment()
        if self.sim_seabed:
            self._build_seabed()
        self._build_world()
        self._build_vehicle()
        self._build_ghost()
        self._build_camera()
        self._build_screen()
        self._build_trail()
        self._build_target()
        self._build_uncertainty()
        self._build_capture()
        if self.desk is None:
            # Alone: a desk nobody holds; the viewers watch, STOP excepted.
            self.desk, self._own_desk = ControlDesk(self.operator), True
        self.server.on_client_connect(self._on_viewer_connect)
        self.server.on_client_disconnect(self._on_viewer_disconnect)
        self._unsubscribe = self.operator.subscribe(self._on_operator_event)
        if self.operator.picture() is not None:
            self._image_dirty.set()
        self._thread = threading.Thread(target=self._run, name="viser-scene", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        if self._unsubscribe is not None:
            self._unsubscribe()
            self._unsubscribe = None
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        if self.server is not None:
            with self._quiet():
                self.server.stop()

    def use_desk(self, desk: ControlDesk) -> None:
        """Order through `desk` (the web app's), so that the page holding
        control, and only it, may order from its embedded view."""
        self.desk, self._own_desk = desk, False
        self._control_dirty.set()

    def __enter__(self) -> "ConsoleScene":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # ------------------------------------------------------------------
    # Building the scene (once)
    # ------------------------------------------------------------------

    def _build_environment(self) -> None:
        scene = self.server.scene
        scene.set_up_direction("+z")
        # No HDRI: software rendering (no GPU) stays fast; plain lights instead.
        scene.configure_environment_map(hdri=None)
        scene.configure_default_lights(enabled=True, cast_shadow=False)
        # Deep water above, darker below: a gradient instead of viser's white.
        rows = np.linspace(0.0, 1.0, 64)[:, None]
        top, bottom = np.array([40, 110, 140]), np.array([6, 28, 44])
        gradient = (top * (1 - rows) + bottom * rows).astype(np.uint8)
        scene.set_background_image(np.repeat(gradient[:, None, :], 4, axis=1), format="png")
        camera = self.server.initial_camera
        camera.position = VIEW_POSITION
        camera.look_at = VIEW_LOOK_AT
        camera.up = (0.0, 0.0, 1.0)

    def _build_world(self) -> None:
        """The floor at the depth the ROV measured (hidden until it has one) and the
        objects it recognised, laid by `update_world`."""
        s = self.seabed
        self.floor_node = self.server.scene.add_grid(
            "/floor", width=60.0, height=60.0, plane="xy", cell_size=1.0, section_size=5.0,
            cell_color=(70, 110, 120), section_color=(90, 150, 160), plane_color=(20, 60, 70), plane_opacity=0.35,
            position=frames.ned_to_world((s.x_min_m + s.x_max_m) / 2, (s.y_min_m + s.y_max_m) / 2, 0.0),
            visible=False)

    def update_world(self) -> None:
        """The world as the ROV measured it: the floor at its depth, the objects on it."""
        w = self.operator.world_state()
        depth = w.get("seabed_depth_m")
        floor_z = None if depth is None else -float(depth)
        if floor_z != self.floor_z:
            if floor_z is None:
                self.floor_node.visible = False
                for _floor, node in self._mosaic.values():  # with it, at once: nothing laid on no floor
                    node.visible = False
            else:
                x, y, _ = self.floor_node.position
                self.floor_node.position = (x, y, floor_z)
                _show(self.floor_node)
            self.floor_z = floor_z
        seen = {}
        for o in w.get("objects", []):
            key = (o["north_m"], o["east_m"], o["length_m"], o["width_m"], o["heading_deg"], o["class"], floor_z)
            seen[o["id"]] = key
            if self._objects_shown.get(o["id"]) == key:
                continue
            z = (depth if depth is not None else 0.0)
            height = 0.3 if o["class"] != "ladder" else 0.1
            self._object_nodes[o["id"]] = self.server.scene.add_box(
                f"/objects/{o['id']}", color=OBJECT_RGB.get(o["class"], OBJECT_RGB["unknown"]),
                dimensions=(o["length_m"], o["width_m"], height), opacity=0.55 + 0.4 * o["confidence"],
                position=frames.ned_to_world(o["north_m"], o["east_m"], z - height / 2),
                wxyz=frames.body_wxyz(0.0, 0.0, o["heading_deg"]), cast_shadow=False, receive_shadow=False,
                visible=depth is not None)  # on a floor only: with no depth measured, no place to lay it
            self._object_nodes[o["id"]].on_click(lambda event, oid=o["id"]: self.select_object(oid, event.client))
        for gone in set(self._objects_shown) - set(seen):
            self._object_nodes.pop(gone).remove()
        self._objects_shown = seen

    def select_object(self, object_id: int, client) -> bool:
        """An object clicked in the scene: shown in that viewer's panel with Go to and Frame it
        (ordering from there goes through the desk, as every scene order: its page must hold
        control).  False when the viewer or the object is gone."""
        panel = self.panels.get(getattr(client, "client_id", client))
        obj = next((o for o in self.operator.world_state()["objects"] if o["id"] == object_id), None)
        if panel is None or obj is None:
            return False
        panel.select_object(obj)
        return True

    def update_mosaic(self) -> None:
        """The pictures received laid on the measured floor where they were taken (the
        last MOSAIC_KEPT, the newest on top); none without a floor."""
        if self.floor_z is None:
            for _floor, node in self._mosaic.values():
                node.visible = False
            return
        kept = [e for e in self.operator.image_history()
                if not e.get("partial") and (e.get("capture") or {}).get("pose")][-MOSAIC_KEPT:]
        wanted = {e["n"] for e in kept}
        for n in [n for n in self._mosaic if n not in wanted]:
            self._mosaic.pop(n)[1].remove()
        for rank, entry in enumerate(kept):
            n = entry["n"]
            laid = self._mosaic.get(n)
            if laid is not None and abs(laid[0] - self.floor_z) <= MOSAIC_RELAY_M:
                x, y, _ = laid[1].position  # a floor told a few cm off: lifted onto it, not warped again
                laid[1].position = (x, y, self.floor_z + 0.01 + 0.002 * rank)
                _show(laid[1])
                continue
            quad = mosaic.ground_quad(entry["capture"]["pose"], hfov_deg=self.hfov_deg, tilt_deg=self.tilt_deg,
                                      size_px=self.image_px, camera_in_body_flu=CAMERA_IN_BODY_FLU,
                                      floor_z=self.floor_z)
            if quad is None:
                continue
            try:
                picture = debt.decode(entry["stream"])
            except ValueError:  # a stream this codec cannot read: said when it came, not laid
                continue
            raster, centre, width_m, height_m = mosaic.warp_to_ground(as_rgb(picture), *quad)
            centre[2] = self.floor_z + 0.01 + 0.002 * rank  # the newest on top
            if laid is not None:  # before its successor takes its name (viser replaces a node by name)
                laid[1].remove()
            node = self.server.scene.add_image(f"/mosaic/{n}", raster, width_m, height_m, format="png",
                                               position=centre, wxyz=(0.0, 1.0, 0.0, 0.0), cast_shadow=False,
                                               receive_shadow=False)
            self._mosaic[n] = (self.floor_z, node)

    def show_sim_seabed(self, visible: bool) -> None:
        """The simulator's own seabed (its truth, not measured): `rovlink demo` only."""
        for node in [getattr(self, "seabed_node", None), *getattr(self, "seabed_ring", [])]:
            if node is not None:
                node.visible = bool(visible)

    def _build_seabed(self) -> None:
        """The simulated camera's texture, where the simulated camera sees it;
        the texture repeats beyond its extent there, so a ring of coarser copies
        here.  The simulator's truth: hidden until the viewer asks for it."""
        s = self.seabed
        width_m, height_m = s.y_max_m - s.y_min_m, s.x_max_m - s.x_min_m
        centre = frames.ned_to_world((s.x_min_m + s.x_max_m) / 2, (s.y_min_m + s.y_max_m) / 2, s.depth_m)
        # Image x (columns) runs east, image y (rows) south: seen from above,
        # which is the image node's -z side after a half turn about x.
        down = (0.0, 1.0, 0.0, 0.0)
        self.seabed_node = self.server.scene.add_image(
            "/seabed", s.texture, width_m, height_m, format="jpeg", jpeg_quality=85,
            position=centre, wxyz=down, cast_shadow=False, receive_shadow=False, visible=False)
        coarse = np.asarray(Image.fromarray(s.texture).resize((256, 256), Image.BILINEAR))
        self.seabed_ring = []
        for i in (-1, 0, 1):
            for j in (-1, 0, 1):
                if i == j == 0:
                    continue
                offset = np.array([i * width_m, j * height_m, -0.01])
                self.seabed_ring.append(self.server.scene.add_image(
                    f"/seabed_ring/{i + 1}{j + 1}", coarse, width_m, height_m, format="jpeg", jpeg_quality=80,
                    position=centre + offset, wxyz=down, cast_shadow=False, receive_shadow=False, visible=False))

    def _build_vehicle(self) -> None:
        self.rov_node = self.server.scene.add_frame("/rov", show_axes=False, position=(0.0, 0.0, 0.0))
        self.rov_mesh_node = self.server.scene.add_mesh_trimesh("/rov/mesh", self.rov_mesh, cast_shadow=False,
                                                                receive_shadow=False)
        self.rov_node.visible = False  # until the first odometry

    def _build_ghost(self) -> None:
        self.ghost_node = self.server.scene.add_frame("/ghost", show_axes=False, visible=False)
        self.ghost_mesh_node = self.server.scene.add_mesh_simple(
            "/ghost/mesh", self.rov_mesh.vertices, self.rov_mesh.faces, color=GHOST_RGB, opacity=0.35,
            cast_shadow=False, receive_shadow=False)

    def _build_camera(self) -> None:
        w, h = self.image_px
        r_flu_cam = frames.camera_rotation_in_body(self.tilt_deg)
        self.frustum_node = self.server.scene.add_camera_frustum(
            "/rov/camera", fov=frames.vertical_fov_rad(self.hfov_deg, w, h), aspect=w / h, scale=0.45,
            color=FRUSTUM_RGB, thickness=0.012, position=CAMERA_IN_BODY_FLU,
            wxyz=tf.SO3.from_matrix(r_flu_cam).wxyz)
        self.footprint_node = self.server.scene.add_line_segments(
            "/footprint", np.zeros((8, 2, 3), np.float32), FRUSTUM_RGB, thickness=0.03, visible=False)

    def _build_capture(self) -> None:
        """The vehicle's camera where the current picture was taken (the
        operator's `image_state()["capture"]`): the same mount as the live
        frustum, on a frame at the pose at capture, a little larger, in its own colour."""
        w, h = self.image_px
        self.capture_node = self.server.scene.add_frame("/capture", show_axes=False, visible=False)
        self.capture_frustum_node = self.server.scene.add_camera_frustum(
            "/capture/camera", fov=frames.vertical_fov_rad(self.hfov_deg, w, h), aspect=w / h, scale=0.55,
            color=CAPTURE_RGB, thickness=0.015, position=CAMERA_IN_BODY_FLU,
            wxyz=tf.SO3.from_matrix(frames.camera_rotation_in_body(self.tilt_deg)).wxyz)
        self.follow_node = self.server.scene.add_line_segments(
            "/follow", np.zeros((1, 2, 3), np.float32), FOLLOW_RGB, thickness=0.04, visible=False)
        self._follow_shown = None

    def _build_screen(self) -> None:
        w, h = self.image_px
        blank = np.full((h, w, 3), 30, np.uint8)
        centre, wxyz = chase.screen_pose(START_POSITION, 0.0)
        self.screen_node = self.server.scene.add_image(
            "/screen", blank, SCREEN_WIDTH_M, SCREEN_WIDTH_M * h / w, format="jpeg", jpeg_quality=90,
            position=centre, wxyz=wxyz, cast_shadow=False, receive_shadow=False)
        self.roi_node = self.server.scene.add_line_segments(
            "/screen/roi", np.zeros((4, 2, 3), np.float32), (255, 210, 0), thickness=0.05, visible=False)

        @self.screen_node.on_drag("left")
        async def _(event: viser.SceneNodeDragEvent) -> None:
            self._on_screen_drag(event)

    def _build_trail(self) -> None:
        self.trail_node = self.server.scene.add_line_segments(
            "/trail", np.zeros((1, 2, 3), np.float32), ROV_RGB, thickness=0.04, visible=False)

    def _build_uncertainty(self) -> None:
        """A ring around the ghost, as wide as the vehicle may have strayed
        from the prediction: it grows while nothing is heard."""
        self.uncertainty_node = self.server.scene.add_line_segments(
            "/ghost_uncertainty", np.zeros((UNCERTAINTY_SEGMENTS, 2, 3), np.float32), UNCERTAINTY_RGB,
            thickness=0.05, visible=False)
        self._uncertainty_shown = None

    def _update_uncertainty(self, predicted: Pose) -> None:
        age, radius = self.operator.odometry_age_s(), self.operator.uncertainty_m()
        if age is None or age < UNCERTAINTY_SHOWN_AFTER_S or not radius or radius < UNCERTAINTY_SHOWN_M:
            if self.uncertainty_node.visible:
                self.uncertainty_node.visible = False
            return
        key = (round(radius, 1), predicted.x_m, predicted.y_m, predicted.z_m)
        if key == self._uncertainty_shown:
            return
        self._uncertainty_shown = key
        a = np.linspace(0.0, 2 * np.pi, UNCERTAINTY_SEGMENTS + 1)
        centre = frames.ned_to_world(predicted.x_m, predicted.y_m, predicted.z_m)
        ring = np.stack([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a),
                         np.full_like(a, centre[2])], axis=1).astype(np.float32)
        self.uncertainty_node.points = np.stack([ring[:-1], ring[1:]], axis=1)
        _show(self.uncertainty_node)

    def _build_target(self) -> None:
        s = self.seabed
        limits = ((s.y_min_m, s.y_max_m), (s.x_min_m, s.x_max_m), (s.floor_z + 0.3, 0.0))
        self.gizmo = self.server.scene.add_transform_controls(
            "/target", scale=0.7, translation_limits=limits, disable_sliders=False, depth_test=False,
            opacity=0.9, position=(0.0, 0.0, -2.0))
        self.target_ghost_node = self.server.scene.add_frame("/target_ghost", show_axes=False, visible=False)
        self.server.scene.add_mesh_simple(
            "/target_ghost/mesh", self.rov_mesh.vertices, self.rov_mesh.faces, color=TARGET_RGB, opacity=0.4,
            cast_shadow=False, receive_shadow=False)
        self.preview_node = self.server.scene.add_line_segments(
            "/preview", np.zeros((1, 2, 3), np.float32), TARGET_RGB, thickness=0.05, visible=False)

        @self.gizmo.on_update
        async def _(event: viser.TransformControlsEvent) -> None:
            self._on_gizmo(event)

    # ------------------------------------------------------------------
    # Callbacks: short, delegating
    # ------------------------------------------------------------------

    def _on_operator_event(self, topic: str, payload) -> None:
        # Called from the link's loop, a web thread or the decoder: only flag work.
        if topic == "image":
            self._image_dirty.set()
        elif topic == "wish":
            self._wish_dirty.set()
        elif topic == "target":
            self.render_target(payload)
        elif topic == "control":
            self._control_dirty.set()
        elif topic == "order" and payload.get("kind") == "IMAGE":
            self._settings_dirty.set()

    def viewer_key(self, client_id: int) -> str | None:
        """The scene key a viewer connected with, or None."""
        return scene_key_from_path(viewer_path(self.server, client_id))

    def caller(self, client) -> Caller:
        """Who a viewer is to the desk (None: our own code)."""
        if client is None:
            return CONSOLE
        return Caller(scene_key=self.viewer_key(client.client_id), via="scene")

    def _on_viewer_connect(self, client) -> None:
        caller = self.caller(client)

        def notify(title: str, text: str) -> None:
            try:
                client.add_notification(title, text, auto_close_seconds=5.0, color="red")
            except Exception:  # the viewer left meanwhile
                log.debug("could not notify viewer %s", client.client_id, exc_info=True)

        with self._lock:
            self.views[client.client_id] = ViewerView()
        client_id = client.client_id
        panel = ControlPanel(client.gui, self.operator, PanelCallbacks(
            submit=lambda order: self.desk.submit(order, caller), notify=notify, refused=self.note_refusal,
            set_view=lambda mode: self.set_view(client_id, mode), centre_view=lambda: self.centre_view(client_id),
            sim_seabed=self.show_sim_seabed if self.sim_seabed else None),
            image_px=self.image_px, target=self.target_state())
        panel.set_permitted(self._may_order(caller))
        if caller.scene_key is not None:
            self._minimize_panel(client)
        if self.operator.picture() is not None:
            self._image_dirty.set()
        with self._lock:
            self.panels[client.client_id] = panel

    @staticmethod
    def _minimize_panel(client) -> None:
        """Embedded in the operator page: the panel as a bar, the view free."""
        main_panel = getattr(client.gui, "main_panel", None)  # viser >= 1.1
        if main_panel is None:
            return
        try:
            main_panel.minimize()
        except Exception:  # the viewer left meanwhile
            log.debug("could not minimize viewer %s's panel", client.client_id, exc_info=True)

    def _on_viewer_disconnect(self, client) -> None:
        with self._lock:
            self._refused_at.pop(client.client_id, None)
            self.panels.pop(client.client_id, None)
            self.views.pop(client.client_id, None)

    def _may_order(self, caller: Caller) -> bool:
        return self.desk.refusal(control.ClearTarget(), caller) is None

    def note_refusal(self) -> None:
        with self._lock:
            self.orders_refused += 1

    def permit(self, client) -> bool:
        """May this viewer move the shared gizmo or ROI now?  (None: our own
        code, always.)  If not, it is told why, once in a while."""
        if client is None:
            return True
        reason = self.desk.refusal(control.ClearTarget(), self.caller(client))
        if reason is None:
            return True
        now = time.monotonic()
        with self._lock:
            self.orders_refused += 1
            last = self._refused_at.get(client.client_id)
            notify = last is None or now - last >= REFUSAL_NOTICE_S
            if notify:
                self._refused_at[client.client_id] = now
        if notify:
            try:
                client.add_notification("Not sent", reason, auto_close_seconds=5.0, color="red")
            except Exception:  # the viewer left meanwhile
                log.debug("could not notify viewer %s", client.client_id, exc_info=True)
        return False

    def _on_screen_drag(self, event) -> None:
        # While the pilot drags, the screen stays where the drag began (it
        # moves with the vehicle otherwise), and so do the views.
        self._drag_since = None if event.phase == "end" else (self._drag_since or time.monotonic())
        if not self.permit(event.client):
            self.show_roi(self.operator.requested_settings.roi)
            return
        start = np.asarray(event.start_position, float)
        end = self._pointer_on_screen(event)
        if event.phase == "end":
            panel = self.panels.get(event.client.client_id)
            self.select_roi_world(start, end, caller=self.caller(event.client),
                                  shift=panel.shift if panel is not None else None)
        else:
            self.preview_roi_world(start, end)

    def _pointer_on_screen(self, event) -> np.ndarray:
        """viser gives the pointer on a camera-facing plane through the grab
        point; the ROI wants it on the screen itself: cast the client's view ray
        through it onto the screen's plane."""
        end = np.asarray(event.end_position, float)
        normal = tf.SO3(np.asarray(self.screen_node.wxyz)).as_matrix()[:, 2]
        try:
            eye = np.asarray(event.client.camera.position, float)
        except Exception:  # no camera state yet: fall back to the drag plane
            return end
        hit = frames.ray_plane_hit(eye, end, self.screen_node.position, normal)
        return end if hit is None else hit

    def _on_gizmo(self, event) -> None:
        if not self.permit(event.client):
            self._place_gizmo_back()
            return
        # The path costs ~10 ms of model time: at most ten a second while dragging.
        now = time.monotonic()
        preview = event.phase != "update" or now - self._last_preview_at >= 0.1
        if preview:
            self._last_preview_at = now
        if preview:
            self.move_target(event.target.position, event.target.wxyz, place_gizmo=False,
                             caller=self.caller(event.client))
        if event.phase == "end" and self.target is not None:
            # The order carries yaw only: square the gizmo up again.
            event.target.wxyz = frames.body_wxyz(0.0, 0.0, self.target[3])

    # ------------------------------------------------------------------
    # Region of interest
    # ------------------------------------------------------------------

    def screen_size_m(self) -> tuple[float, float]:
        return float(self.screen_node.render_width), float(self.screen_node.render_height)

    def roi_from_world(self, point_a, point_b) -> tuple[int, int, int, int] | None:
        return roi_from_world(point_a, point_b, position=self.screen_node.position, wxyz=self.screen_node.wxyz,
                              size_m=self.screen_size_m(), size_px=self.image_px)

    def preview_roi_world(self, point_a, point_b) -> tuple[int, int, int, int] | None:
        """While dragging: draw the rectangle, send nothing."""
        roi = self.roi_from_world(point_a, point_b)
        self.show_roi(roi)
        return roi

    def select_roi_world(self, point_a, point_b, *, caller: Caller = CONSOLE,
                         shift: int | None = None) -> tuple[int, int, int, int] | None:
        """Drag released: the IMAGE order for the next image, with the viewer's
        shift; a click (no rectangle) leaves the settings alone."""
        roi = self.roi_from_world(point_a, point_b)
        if roi is None:
            self.show_roi(self.operator.requested_settings.roi)
            return None
        try:
            self.desk.submit(control.ChangeImage(roi=roi, shift=shift), caller)
        except (NotHolder, OrderError):
            self.show_roi(self.operator.requested_settings.roi)
            raise
        self.show_roi(roi)
        self._image_dirty.set()  # redraw the panels' copy with the new box
        return roi

    def clear_roi(self, caller: Caller = CONSOLE) -> None:
        self.desk.submit(control.ChangeImage(roi=None), caller)
        self.show_roi(None)
        self._image_dirty.set()

    def show_roi(self, roi) -> None:
        if roi is None:
            self.roi_node.visible = False
            return
        self.roi_node.points = roi_outline(roi, self.screen_size_m(), self.image_px, lift_m=0.02)
        self.roi_node.visible = True

    # ------------------------------------------------------------------
    # Supervised control: target, preview, Send, Stop
    # ------------------------------------------------------------------

    @property
    def target(self) -> tuple[float, float, float, float] | None:
        """The desk's shared target, NED x, y, z and yaw_deg, or None."""
        t = self.target_state()
        return None if t is None else (t["x_m"], t["y_m"], t["z_m"], t["yaw_deg"])

    def target_state(self) -> dict | None:
        return self.desk.target_state() if self.desk is not None else None

    def move_target(self, position_world, wxyz, *, place_gizmo: bool = True,
                    caller: Caller = CONSOLE) -> list[tuple[float, float, float]]:
        """The gizmo moved: the shared target there (the desk previews the path,
        GUIDED from the predicted pose; the ghost shows it).  Sends nothing.
        Called from elsewhere than the gizmo, the gizmo follows (`place_gizmo`)."""
        s = self.seabed
        x, y, z = frames.world_to_ned(np.asarray(position_world, float))
        x = min(max(float(x), s.x_min_m), s.x_max_m)
        y = min(max(float(y), s.y_min_m), s.y_max_m)
        z = min(max(float(z), 0.0), s.depth_m - 0.3)
        yaw = frames.yaw_deg_from_wxyz(wxyz)
        self._place_gizmo = place_gizmo
        try:
            return self.desk.submit(control.PreviewTarget(x, y, z, yaw), caller)
        finally:
            self._place_gizmo = True

    def render_target(self, target: dict | None) -> None:
        """The desk's target, whoever set it: ghost, path, gizmo, every panel."""
        if target is None:
            self.target_ghost_node.visible = False
            self.preview_node.visible = False
            self._gizmo_on_vehicle()
        else:
            x, y, z, yaw = target["x_m"], target["y_m"], target["z_m"], target["yaw_deg"]
            self.target_ghost_node.position = frames.ned_to_world(x, y, z)
            self.target_ghost_node.wxyz = frames.body_wxyz(0.0, 0.0, yaw)
            self.target_ghost_node.visible = True
            if getattr(self, "_place_gizmo", True):
                self.gizmo.position = self.target_ghost_node.position
                self.gizmo.wxyz = self.target_ghost_node.wxyz
            if target["points"]:
                self._show_path(target["points"])
            else:  # sent without a preview: no path to show, and not an old one
                self.preview_node.visible = False
        for panel in list(self.panels.values()):
            panel.render_target(target)

    def _show_path(self, path) -> None:
        pts = frames.ned_to_world(*np.asarray(path, float).T).astype(np.float32)
        if len(pts) < 2:
            pts = np.vstack([pts, pts])
        self.preview_node.points = np.stack([pts[:-1], pts[1:]], axis=1)
        self.preview_node.visible = True

    def send_target(self, caller: Caller = CONSOLE) -> int | None:
        """The pilot confirmed: the POSITION order goes out (GUIDED on the ROV)."""
        if self.target is None:
            return None
        return self.desk.submit(control.SendTarget(), caller)

    def stop_vehicle(self, caller: Caller = CONSOLE) -> int:
        """STOP: neutral velocity, targets cancelled on the ROV; the preview goes."""
        return self.desk.submit(control.Stop(), caller)

    def _place_gizmo_back(self) -> None:
        """A refused drag: the gizmo back on the target, or on the vehicle."""
        target = self.target
        if target is not None:
            self.gizmo.position, self.gizmo.wxyz = frames.pose_to_world(Pose(*target[:3], 0.0, 0.0, target[3]))
        else:
            self._gizmo_on_vehicle()

    def _gizmo_on_vehicle(self) -> None:
        pose = self.operator.predicted_pose()
        if pose is not None:
            self.gizmo.position, self.gizmo.wxyz = frames.pose_to_world(
                Pose(pose.x_m, pose.y_m, pose.z_m, 0.0, 0.0, pose.yaw_deg))

    # ------------------------------------------------------------------
    # Updates (background thread)
    # ------------------------------------------------------------------

    def _run(self) -> None:
        period = 1.0 / self.update_hz
        next_panel = 0.0
        while not self._stop.is_set():
            t0 = time.monotonic()
            try:
                if self._own_desk:
                    self.desk.tick()
                self.update_poses()
                self.update_views()
                if self._image_dirty.is_set():
                    self._image_dirty.clear()
                    self.update_image()
                if self._wish_dirty.is_set():
                    self._wish_dirty.clear()
                    wish = self.operator.wish_state()
                    for panel in list(self.panels.values()):
                        panel.render_wish(wish)
                if self._settings_dirty.is_set():
                    self._settings_dirty.clear()
                    for panel in list(self.panels.values()):
                        panel.render_image_settings()
                if self._control_dirty.is_set():
                    self._control_dirty.clear()
                    self.update_permissions()
                if t0 >= next_panel:
                    next_panel = t0 + 0.5
                    self.update_trail()
                    self.update_world()
                    self.update_mosaic()
                    self.update_permissions()
                    self.refresh_panels()
            except Exception:  # a bad frame must not end the scene
                log.exception("scene update failed")
            self._stop.wait(max(0.0, period - (time.monotonic() - t0)))

    def update_permissions(self) -> None:
        """Order controls enabled for the viewers who may order, disabled for the rest."""
        for client_id, panel in list(self.panels.items()):
            panel.set_permitted(self._may_order(Caller(scene_key=self.viewer_key(client_id), via="scene")))

    def refresh_panels(self) -> None:
        pose, link, image = self.operator.pose_state(), self.operator.link_state(), self.operator.image_state()
        self.show_capture(image.get("capture"))
        self.show_followed(image)
        for panel in list(self.panels.values()):
            try:
                panel.refresh(pose, link, image)
            except Exception:  # a viewer gone meanwhile
                log.debug("panel refresh failed", exc_info=True)

    def update_poses(self) -> None:
        report = self.operator.vehicle()
        if report is None:
            return
        received = Pose.from_report(report)
        predicted = self.operator.predicted_pose() or received
        self._update_uncertainty(predicted)
        if received != self._last_received:
            self._last_received = received
            self.rov_node.position, self.rov_node.wxyz = frames.pose_to_world(received)
            _show(self.rov_node)
            self._update_footprint(received)
            if self.target is None:
                # No target yet: the gizmo waits on the vehicle.
                self.gizmo.position = frames.ned_to_world(received.x_m, received.y_m, received.z_m)
                self.gizmo.wxyz = frames.body_wxyz(0.0, 0.0, received.yaw_deg)
        if predicted != self._last_predicted:
            self._last_predicted = predicted
            self.ghost_node.position, self.ghost_node.wxyz = frames.pose_to_world(predicted)
            _show(self.ghost_node)
        # Where the views look too (throttled; also after the vehicle stopped).
        self.place_screen(predicted)
        self.frames_pushed += 1

    def _update_footprint(self, pose: Pose) -> None:
        if self.floor_z is None:  # no seabed measured: nothing to lay the picture's footprint on
            self.footprint_node.visible = False
            return
        r_world_flu = frames.body_rotation(pose.roll_deg, pose.pitch_deg, pose.yaw_deg)
        position = frames.ned_to_world(pose.x_m, pose.y_m, pose.z_m)
        cam = position + r_world_flu @ np.asarray(CAMERA_IN_BODY_FLU)
        r_world_cam = r_world_flu @ frames.camera_rotation_in_body(self.tilt_deg)
        corners = frames.seabed_footprint(cam, r_world_cam, frames.image_corner_rays(self.hfov_deg, *self.image_px),
                                          self.floor_z + 0.02, FOOTPRINT_RANGE_M)
        rays = np.stack([np.repeat(cam[None], 4, axis=0), corners], axis=1)
        edges = np.stack([corners, np.roll(corners, -1, axis=0)], axis=1)
        self.footprint_node.points = np.concatenate([rays, edges]).astype(np.float32)
        _show(self.footprint_node)

    def update_trail(self) -> None:
        trail = list(self.operator.history.trail)[-TRAIL_POINTS:]
        if len(trail) < 2 or (len(trail), trail[-1]) == self._trail_shown:
            return
        self._trail_shown = (len(trail), trail[-1])
        t = np.asarray(trail, float)
        pts = frames.ned_to_world(t[:, 1], t[:, 2], t[:, 3]).astype(np.float32)
        self.trail_node.points = np.stack([pts[:-1], pts[1:]], axis=1)
        _show(self.trail_node)

    def update_image(self) -> None:
        picture = self.operator.picture()
        if picture is None:
            return
        rgb = as_rgb(picture)
        h, w = rgb.shape[:2]
        if (w, h) != self.image_px:
            self._resize_image(w, h)
        self.screen_node.image = rgb
        # The picture where it was taken, when that is known; else on the camera now.
        self.show_capture(self.operator.image_state().get("capture"))
        on, off = ((self.capture_frustum_node, self.frustum_node) if self._capture_shown is not None
                   else (self.frustum_node, self.capture_frustum_node))
        on.image = rgb
        if off.image is not None:
            off.image = None
        roi = self.operator.requested_settings.roi
        shown = draw_roi(rgb, roi) if roi else rgb
        for panel in list(self.panels.values()):
            panel.show_picture(shown)
        self.images_shown += 1

    def _resize_image(self, w: int, h: int) -> None:
        """A camera of another size: the screen and frustum follow its aspect."""
        self.image_px = (w, h)
        self.screen_node.render_height = SCREEN_WIDTH_M * h / w
        self.frustum_node.fov = self.capture_frustum_node.fov = frames.vertical_fov_rad(self.hfov_deg, w, h)
        self.frustum_node.aspect = self.capture_frustum_node.aspect = w / h

    # ------------------------------------------------------------------
    # Views, the screen, the picture's capture pose
    # ------------------------------------------------------------------

    @property
    def dragging(self) -> bool:
        """A drag on the screen in progress (one whose end never came counts
        no longer than DRAG_HOLD_MAX_S)."""
        since = self._drag_since
        return since is not None and time.monotonic() - since < DRAG_HOLD_MAX_S

    def set_view(self, client_id: int | None, mode: str) -> None:
        """A viewer chose follow, top or free (its panel's dropdown)."""
        view = self.views.get(client_id) if client_id is not None else None
        if view is not None:
            view.set_mode(mode)

    def centre_view(self, client_id: int | None) -> None:
        """A viewer asked to see the vehicle in the middle (its panel's button):
        done by the loop at its next turn."""
        view = self.views.get(client_id) if client_id is not None else None
        if view is not None:
            view.centre = True

    def update_views(self, now: float | None = None) -> None:
        """Each following viewer's camera on the vehicle (the ghost: where it
        probably is now), when it is due (`ViewerView.due`)."""
        pose = self._last_predicted
        if pose is None or self.dragging or not self.views:
            return
        now = time.monotonic() if now is None else now
        position, yaw = frames.ned_to_world(pose.x_m, pose.y_m, pose.z_m), pose.yaw_deg
        clients = self.server.get_clients()
        for client_id, view in list(self.views.items()):
            client = clients.get(client_id)
            if client is None or not view.due(now, position, yaw):
                continue
            aimed = (None, None)
            try:
                aimed = self._aim(client, view, position, yaw)
            except Exception:  # the viewer left meanwhile, or sent no camera yet
                log.debug("could not move viewer %s's camera", client_id, exc_info=True)
            view.done(now, position, yaw, *aimed)

    @staticmethod
    def _aim(client, view: ViewerView, position: np.ndarray, yaw_deg: float) -> tuple[np.ndarray, np.ndarray]:
        """Set the viewer's camera; (eye, look_at) set."""
        camera = client.camera
        if view.mode == chase.FREE:  # a centre request: same direction, on the vehicle
            eye, look_at = chase.centred_view(camera.position, camera.look_at, position)
            up = None
        else:
            # The pilot's zoom is kept while the view stays the same.
            distance = view.zoom(camera.look_at, float(np.linalg.norm(camera.position - camera.look_at)))
            eye, look_at, up = chase.chase_view(position, yaw_deg, view.mode, distance)
        with client.atomic():
            if up is not None:
                camera.up_direction = up
            camera.position = eye  # (moves look_at along)
            camera.look_at = look_at
        return eye, look_at

    def place_screen(self, pose: Pose) -> None:
        """The screen ahead of and above the vehicle (`chase.screen_pose`),
        a few times a second at most, not while it is dragged on."""
        now = time.monotonic()
        position = frames.ned_to_world(pose.x_m, pose.y_m, pose.z_m)
        if self.dragging or now < self._screen_next_at:
            return
        last = None if self._screen_at is None else (frames.ned_to_world(*self._screen_at[:3]), self._screen_at[5])
        if not chase.moved(last, position, pose.yaw_deg, chase.SCREEN_MIN_MOVE_M, chase.SCREEN_MIN_TURN_DEG):
            return
        self._screen_at = (pose.x_m, pose.y_m, pose.z_m, 0.0, 0.0, pose.yaw_deg)
        self._screen_next_at = now + chase.CHASE_PERIOD_S
        centre, wxyz = chase.screen_pose(position, pose.yaw_deg)
        self.screen_node.position, self.screen_node.wxyz = centre, wxyz
        # The ROI drawn on it is the screen's child: it moves along.

    def show_followed(self, image: dict) -> None:
        """A followed picture (docs/PROTOCOL.md §10): the ray from the camera at capture
        through the ROI it was coded with (the last one, while the track is lost), to where
        the object lies on the seabed; gone once the track is dropped."""
        track, capture, settings = image.get("track"), image.get("capture") or {}, image.get("settings") or {}
        state = (track or {}).get("state")
        ray = None
        if state in ("holds", "lost"):
            ray = followed_ray(capture.get("pose"), settings.get("roi"), hfov_deg=self.hfov_deg, tilt_deg=self.tilt_deg,
                               size_px=self.image_px, camera_in_body_flu=CAMERA_IN_BODY_FLU,
                               # no seabed measured: the ray's direction only, to its full range
                               floor_z=self.floor_z if self.floor_z is not None else NO_FLOOR_Z)
        key = None if ray is None else (state, tuple(np.round(ray, 3).ravel()))
        if key == self._follow_shown:
            return
        self._follow_shown = key
        if ray is None:
            self.follow_node.visible = False
            return
        self.follow_node.points = ray[None].astype(np.float32)
        _show(self.follow_node)

    def show_capture(self, capture: dict | None) -> None:
        """The camera frustum at the vehicle's pose when the current picture
        was taken; nothing while that is unknown."""
        pose = None if not capture else capture.get("pose")
        key = None if not pose else tuple(float(pose[k]) for k in
                                          ("x_m", "y_m", "z_m", "roll_deg", "pitch_deg", "yaw_deg"))
        if key == self._capture_shown:
            return
        if (key is None) != (self._capture_shown is None):
            self._image_dirty.set()  # the picture moves to the other frustum
        self._capture_shown = key
        if key is None:
            self.capture_node.visible = False
            return
        self.capture_node.position, self.capture_node.wxyz = frames.pose_to_world(Pose(*key))
        _show(self.capture_node)
