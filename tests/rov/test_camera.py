"""Camera sources: the simulated seabed camera, a folder of images, OpenCV."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from PIL import Image

from rovlink.rov.camera import CameraError, FolderCamera, OpenCVCamera, SimulatedCamera, open_camera
from rovlink.rov.seabed import META_PATH, SEABED_DEPTH_M, TEXTURE_PATH, Seabed, generate
from rovlink.rov.telemetry import AutopilotSnapshot
from rovlink.rov.vehicle import VehicleState


@pytest.fixture(scope="module")
def camera():
    return SimulatedCamera()


def seabed_rows(image: np.ndarray) -> np.ndarray:
    """The lower part of the frame, where the tilted camera sees the seabed close by."""
    return image[image.shape[0] // 3 :].astype(float) + 1.0


def reddish_fraction(image: np.ndarray) -> float:
    """Pixels much redder than the rest of their row: terracotta among sand.
    Row by row, because light and haze change with the distance, i.e. the row."""
    rgb = seabed_rows(image)
    ratio = rgb[..., 0] / rgb[..., 1]
    return float(np.mean(ratio > 1.3 * np.median(ratio, axis=1, keepdims=True)))


def dark_fraction(image: np.ndarray) -> float:
    luma = seabed_rows(image).mean(axis=2)
    return float(np.mean(luma < 0.7 * np.median(luma, axis=1, keepdims=True)))


def detail(image: np.ndarray) -> float:
    """Contrast left once the row-by-row trend is removed."""
    luma = image.astype(float).mean(axis=2)
    return float(np.abs(luma - np.median(luma, axis=1, keepdims=True)).mean())


def test_renders_default_size_rgb(camera):
    image = camera.capture(VehicleState(z_m=6.0))
    assert image.shape == (240, 320, 3) and image.dtype == np.uint8
    assert image.std() > 5  # not a flat colour
    small = SimulatedCamera(160, 120, seabed=camera.seabed).capture(VehicleState(z_m=6.0))
    assert small.shape == (120, 160, 3)


def test_renders_differ_with_pose(camera):
    base = camera.capture(VehicleState(z_m=6.0)).astype(int)
    for pose in (
        VehicleState(x_m=1.0, z_m=6.0),
        VehicleState(z_m=6.0, yaw_rad=0.5),
        VehicleState(z_m=4.0),
        VehicleState(z_m=6.0, pitch_rad=0.2),
    ):
        assert np.abs(camera.capture(pose).astype(int) - base).mean() > 2.0, pose


def test_amphorae_show_up_where_they_lie(camera):
    amphorae = [o for o in camera.seabed.objects if o.kind == "amphora"]
    assert len(amphorae) >= 6
    # 2 m above the seabed, 2 m short of the cluster, looking at it.
    looking = camera.capture(VehicleState(x_m=2.0, y_m=2.0, z_m=SEABED_DEPTH_M - 2.0))
    # The same height over bare sand (nothing listed within 6 m ahead).
    bare = camera.capture(VehicleState(x_m=-10.0, y_m=12.0, z_m=SEABED_DEPTH_M - 2.0, yaw_rad=math.pi))
    assert reddish_fraction(looking) > 0.03
    assert reddish_fraction(bare) < 0.005


def test_the_wreck_shows_up(camera):
    wreck_view = camera.capture(VehicleState(x_m=3.0, y_m=-7.0, z_m=SEABED_DEPTH_M - 2.0, yaw_rad=math.radians(45)))
    bare = camera.capture(VehicleState(x_m=-10.0, y_m=12.0, z_m=SEABED_DEPTH_M - 2.0, yaw_rad=math.pi))
    assert dark_fraction(wreck_view) > 0.05
    assert dark_fraction(bare) < 0.02


def test_water_hides_the_seabed_with_distance(camera):
    near = camera.capture(VehicleState(x_m=2.0, y_m=2.0, z_m=SEABED_DEPTH_M - 1.5)).astype(float)
    far = camera.capture(VehicleState(x_m=2.0, y_m=2.0, z_m=0.5)).astype(float)
    assert detail(far) < detail(near) / 2  # haze washes the detail out
    # red is absorbed first: the far view is bluer
    assert far[..., 0].mean() / far[..., 2].mean() < near[..., 0].mean() / near[..., 2].mean()


def test_pose_forms_and_bad_numbers(camera):
    snap = AutopilotSnapshot(x_m=1.0, y_m=2.0, z_m=6.0, yaw_rad=0.3)
    from_snapshot = camera.capture(snap)
    from_tuple = camera.capture((1.0, 2.0, 6.0, 0.3))
    assert np.array_equal(from_snapshot, from_tuple)
    for pose in (None, (math.nan, math.inf, -math.inf, math.nan), VehicleState(z_m=50.0), VehicleState(z_m=-3.0)):
        image = camera.capture(pose)
        assert image.shape == (240, 320, 3)


def test_bad_camera_settings_are_refused():
    with pytest.raises(ValueError):
        SimulatedCamera(0, 240)
    with pytest.raises(ValueError):
        SimulatedCamera(hfov_deg=200)


def test_seabed_asset_matches_its_description_and_generator():
    meta = json.loads(META_PATH.read_text())
    with Image.open(TEXTURE_PATH) as image:
        assert list(image.size) == meta["pixels"]
    assert meta["depth_m"] == SEABED_DEPTH_M
    assert meta["x_max_m"] - meta["x_min_m"] == meta["y_max_m"] - meta["y_min_m"] > 10
    assert {o["kind"] for o in meta["objects"]} == {"amphora", "timber", "ladder", "pipe"}
    seabed = Seabed.load()
    assert np.array_equal(generate().texture, seabed.texture)  # the PNG is the generator's output


def test_folder_camera_loops_resizes_and_skips_unreadable_files(tmp_path):
    colours = [(255, 0, 0), (0, 255, 0), (0, 0, 255)]
    for i, colour in enumerate(colours):
        Image.new("RGB", (64 + 10 * i, 48), colour).save(tmp_path / f"{i:02d}.png")
    Image.new("L", (100, 100), 128).save(tmp_path / "03.jpg")
    (tmp_path / "04.png").write_bytes(b"not an image")
    (tmp_path / "notes.txt").write_text("ignored")
    cam = FolderCamera(tmp_path)
    frames = [cam.capture() for _ in range(5)]
    for frame in frames:
        assert frame.shape == (240, 320, 3) and frame.dtype == np.uint8
    assert [tuple(int(v) for v in f[120, 160]) for f in frames[:3]] == colours
    assert tuple(frames[3][0, 0]) == (128, 128, 128)
    assert np.array_equal(frames[4], frames[0])  # the unreadable one is skipped, then the loop restarts


def test_folder_camera_errors(tmp_path):
    with pytest.raises(CameraError, match="not found"):
        FolderCamera(tmp_path / "missing")
    with pytest.raises(CameraError, match="no images"):
        FolderCamera(tmp_path)
    (tmp_path / "bad.png").write_bytes(b"\x89PNG broken")
    with pytest.raises(CameraError, match="could be read"):
        FolderCamera(tmp_path).capture()


def test_open_camera_specs(tmp_path):
    Image.new("RGB", (32, 32)).save(tmp_path / "a.png")
    assert isinstance(open_camera("sim", 160, 120), SimulatedCamera)
    assert isinstance(open_camera(f"folder:{tmp_path}"), FolderCamera)
    assert isinstance(open_camera(str(tmp_path)), FolderCamera)
    with pytest.raises(CameraError, match="unknown camera"):
        open_camera("webcam please")


def test_opencv_camera_without_opencv_is_one_clear_error():
    try:
        import cv2  # noqa: F401
    except ImportError:
        with pytest.raises(CameraError, match="opencv"):
            OpenCVCamera(0)
    else:
        with pytest.raises(CameraError):
            OpenCVCamera("/nonexistent/device/for/rovlink/tests")


def _mask_seabed(obj) -> Seabed:
    """A black seabed with only `obj` on it, painted white: what the camera shows of it is its true extent."""
    from rovlink.rov.seabed import _paint_object

    seabed = Seabed(texture=np.zeros((1024, 1024, 3), np.uint8), objects=[obj])
    image = np.zeros((1024, 1024, 3))
    height = np.zeros((1024, 1024))
    _paint_object(image, height, seabed, obj, np.random.default_rng(0))
    seabed.texture = np.where(height[..., None] > 0, 255, 0).astype(np.uint8) * np.ones(3, np.uint8)
    return seabed


@pytest.mark.parametrize("kind", ["ladder", "pipe", "amphora"])
def test_object_box_bounds_what_the_camera_shows_of_the_object(kind):
    obj = next(o for o in Seabed.load().objects if o.kind == kind)
    camera = SimulatedCamera(seabed=_mask_seabed(obj))
    empty = SimulatedCamera(seabed=Seabed(texture=np.zeros((1024, 1024, 3), np.uint8)))
    # In front of it at three ranges and headings, one with it half out of the picture.
    for back_m, side_m, yaw_deg, roll_deg in ((4.5, 0.0, 0.0, 0.0), (6.0, 1.0, 15.0, 4.0), (4.0, -0.5, -38.0, 0.0)):
        pose = (obj.x_m - back_m, obj.y_m + side_m, SEABED_DEPTH_M - 3.0, math.radians(yaw_deg), math.radians(roll_deg), 0.0)
        box = camera.object_box(pose, obj)
        lit = np.abs(camera.capture(pose).astype(int) - empty.capture(pose)).max(axis=2) > 8
        rows, cols = np.nonzero(lit)
        assert rows.size > 20 and box.clipped is not None
        shown = (cols.min(), rows.min(), cols.max() + 1, rows.max() + 1)
        # The box bounds the footprint's rectangle; an amphora tapers inside its own.
        slack = 4.0 if kind == "amphora" else 2.0
        for got, want, outwards in zip(box.clipped, shown, (-1, -1, 1, 1)):
            assert -1.5 <= outwards * (got - want) <= slack, (kind, pose, box.clipped, shown)
    # Turned away, it is behind the camera: no box at all.
    away = camera.object_box((obj.x_m - 4.5, obj.y_m, SEABED_DEPTH_M - 3.0, math.pi), obj)
    assert away.clipped is None and not away.in_view and away.visible_fraction == 0.0


def test_object_box_in_view_means_half_of_it_in_the_picture():
    obj = next(o for o in Seabed.load().objects if o.kind == "ladder")
    camera = SimulatedCamera()
    centred = camera.object_box((obj.x_m - 4.5, obj.y_m, SEABED_DEPTH_M - 3.0, 0.0), obj)
    assert centred.in_view and centred.visible_fraction == pytest.approx(1.0)
    fractions = []
    for yaw_deg in range(0, 90, 3):  # turning right: the ladder slides out on the left
        fractions.append(camera.object_box((obj.x_m - 4.5, obj.y_m, SEABED_DEPTH_M - 3.0, math.radians(yaw_deg)), obj))
    visible = [b.visible_fraction for b in fractions]
    assert visible[0] == pytest.approx(1.0) and visible[-1] == 0.0
    assert all(a >= b - 1e-9 for a, b in zip(visible, visible[1:]))  # it only ever leaves
    assert [b.in_view for b in fractions] == [v >= 0.5 for v in visible]
    assert any(0.0 < v < 0.5 for v in visible)  # a box half out of the picture is clipped, not dropped


def test_iou_of_boxes():
    from rovlink.rov.camera import iou

    assert iou((0, 0, 10, 10), (0, 0, 10, 10)) == 1.0
    assert iou((0, 0, 10, 10), (5, 0, 15, 10)) == pytest.approx(50 / 150)
    assert iou((0, 0, 10, 10), (20, 20, 30, 30)) == 0.0
    assert iou(None, (0, 0, 1, 1)) == 0.0


def test_a_clipped_box_never_reaches_outside_the_picture():
    obj = next(o for o in Seabed.load().objects if o.kind == "ladder")
    camera = SimulatedCamera()
    for yaw_deg in range(0, 80, 2):  # the ladder sliding out on the left, through every rounding of the edge
        box = camera.object_box((obj.x_m - 4.3, obj.y_m, SEABED_DEPTH_M - 3.0, math.radians(yaw_deg)), obj).clipped
        if box is not None:
            assert 0.0 <= box[0] < box[2] <= 320.0 and 0.0 <= box[1] < box[3] <= 240.0, (yaw_deg, box)
