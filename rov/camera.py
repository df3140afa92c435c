"""Camera sources: what the pilot gets to see, as HxWx3 uint8 RGB images.

Goals
- One small interface for every source, so the ROV node asks for a picture the same
  way whether it comes from the simulated seabed, a folder of images or a real
  camera: `source.capture(pose) -> np.ndarray` (H x W x 3, uint8, RGB; 320 x 240
  by default), `source.close()`.  Sources that do not care about the pose ignore it.
- The simulated camera must be cheap (a few ms per frame): it is rendered on demand
  on the ROV each time the link starts a new image.

Plan
- `SimulatedCamera`: ray-casting against the flat seabed of `rov.seabed`, all
  pixels at once with numpy.  Per-pixel ray directions are computed once for the
  camera (pinhole, `hfov_deg`, tilted down by `tilt_deg`), rotated by the vehicle's
  roll and pitch, intersected with the plane z = depth; that geometry and the
  water's effect on each pixel are cached until depth, roll or pitch change, so a
  frame is mostly a yaw rotation of the hit points and a bilinear texture lookup
  (repeating beyond its extent).  Water is modelled per channel
  (red is absorbed fastest): daylight dimming with depth, then attenuation and
  back-scatter (haze) along the line of sight.  Rays that miss the seabed see open
  water, brighter towards the surface.
- `FolderCamera`: the images of a folder in name order, in a loop, resized.
- `OpenCVCamera`: an OpenCV capture device (index or URL); cv2 comes from the
  optional `opencv` extra and its absence is one clear error.
- `open_camera(spec)`: "sim", "folder:PATH" (or a directory), "opencv:0",
  "opencv:rtsp://...".

A pose is anything with `x_m`, `y_m`, `z_m`, `yaw_rad` and optionally `roll_rad`,
`pitch_rad` (an `AutopilotSnapshot`, a `VehicleState`), or a tuple
(x_m, y_m, z_m, yaw_rad[, roll_rad, pitch_rad]).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from rovlink.rov.seabed import Seabed, SeabedObject

DEFAULT_SIZE = (320, 240)  # width, height
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".ppm", ".pgm", ".tif", ".tiff", ".webp")


class CameraError(RuntimeError):
    """A camera source that cannot deliver (missing folder, device, library)."""


@dataclass(frozen=True)
class TrueBox:
    """Where an object lies in one picture, in pixels (x0, y0, x1, y1), edges exclusive
    of nothing: `whole` as if the picture had no edges, `clipped` to the picture (None
    when nothing of it shows, or it lies behind the camera)."""

    whole: tuple[float, float, float, float] | None
    clipped: tuple[float, float, float, float] | None
    visible_fraction: float = 0.0  # of the object's area in the picture

    @property
    def in_view(self) -> bool:
        """At least half of the object in the picture: what a tracker can be asked to hold."""
        return self.visible_fraction >= 0.5


def _bounds(points) -> tuple[float, float, float, float]:
    xs, ys = [p[0] for p in points], [p[1] for p in points]
    return (min(xs), min(ys), max(xs), max(ys))


def _polygon_area(points) -> float:
    return 0.5 * abs(sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(points, points[1:] + points[:1])))


def _clip_polygon(points, width: float, height: float) -> list[tuple[float, float]]:
    """The part of a convex polygon inside 0..width x 0..height (one edge of the picture at a time)."""
    edges = ((0, 0.0, 1), (0, width, -1), (1, 0.0, 1), (1, height, -1))  # axis, bound, side kept
    for axis, bound, side in edges:
        kept: list[tuple[float, float]] = []
        for i, p in enumerate(points):
            q = points[i - 1]
            p_in, q_in = side * (p[axis] - bound) >= 0, side * (q[axis] - bound) >= 0
            if p_in != q_in:
                t = (bound - q[axis]) / (p[axis] - q[axis])
                kept.append((q[0] + t * (p[0] - q[0]), q[1] + t * (p[1] - q[1])))
            if p_in:
                kept.append(p)
        points = kept
        if not points:
            break
    return points


def box_area(box) -> float:
    return max(0.0, box[2] - box[0]) * max(0.0, box[3] - box[1])


def iou(a, b) -> float:
    """Intersection over union of two (x0, y0, x1, y1) boxes; 0 when either is None."""
    if a is None or b is None:
        return 0.0
    inter = box_area((max(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), min(a[3], b[3])))
    union = box_area(a) + box_area(b) - inter
    return inter / union if union > 0 else 0.0


class CameraSource(Protocol):
    width: int
    height: int

    def capture(self, pose: Any = None) -> np.ndarray: ...

    def close(self) -> None: ...


def _pose_tuple(pose: Any) -> tuple[float, float, float, float, float, float]:
    """(x, y, z, roll, pitch, yaw) from a pose object or tuple; NaN becomes 0."""
    if pose is None:
        values = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    elif isinstance(pose, (tuple, list, np.ndarray)):
        p = [float(v) for v in pose] + [0.0, 0.0]
        values = (p[0], p[1], p[2], p[4], p[5], p[3])
    else:
        values = (
            float(pose.x_m), float(pose.y_m), float(pose.z_m),
            float(getattr(pose, "roll_rad", 0.0)), float(getattr(pose, "pitch_rad", 0.0)), float(pose.yaw_rad),
        )
    return tuple(v if math.isfinite(v) else 0.0 for v in values)  # type: ignore[return-value]


def _check_size(width: int, height: int) -> tuple[int, int]:
    width, height = int(width), int(height)
    if not (8 <= width <= 4096 and 8 <= height <= 4096):
        raise ValueError(f"image size {width}x{height} out of range (8..4096)")
    return width, height


class SimulatedCamera:
    """Renders the seabed of `rov.seabed` from the vehicle's pose."""

    # Per-channel (R, G, B) coefficients, 1/m: coastal Mediterranean-ish water.
    ATTENUATION_PER_M = np.array([0.30, 0.11, 0.12], np.float32)
    DAYLIGHT_PER_M = np.array([0.22, 0.05, 0.06], np.float32)  # dimming of light from above
    WATER_RGB = np.array([18.0, 92.0, 108.0], np.float32)  # back-scatter colour (haze)
    SURFACE_RGB = np.array([70.0, 170.0, 190.0], np.float32)
    LAMP_GAIN = 0.9  # the vehicle's lights, relative to daylight at the surface
    LAMP_RANGE_M = 2.5
    EXPOSURE = 1.3

    def __init__(
        self,
        width: int = DEFAULT_SIZE[0],
        height: int = DEFAULT_SIZE[1],
        *,
        hfov_deg: float = 80.0,
        tilt_deg: float = 35.0,
        seabed: Seabed | None = None,
    ) -> None:
        self.width, self.height = _check_size(width, height)
        if not 10.0 <= hfov_deg <= 150.0:
            raise ValueError("hfov_deg must be within 10..150")
        self.hfov_deg = float(hfov_deg)
        self.tilt_deg = float(tilt_deg)
        self.seabed = seabed or Seabed.load()
        texture = self.seabed.texture
        padded = np.concatenate([texture, texture[:1]], axis=0)
        padded = np.concatenate([padded, padded[:, :1]], axis=1)
        self._flat_texture = np.ascontiguousarray(padded.reshape(-1, 3))
        self._rays = self._camera_rays()
        self._cached_geometry: tuple = (None, ())

    @property
    def focal_px(self) -> float:
        return (self.width / 2) / math.tan(math.radians(self.hfov_deg) / 2)

    def project(self, pose: Any, north_m, east_m, down_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where world points (local NED, arrays) fall in this camera's picture:
        fractional (column, row) of pixel centres' grid, and whether each lies in
        front of the camera.  The exact inverse of the rays `capture` casts."""
        x, y, z, roll, pitch, yaw = _pose_tuple(pose)
        rot = self._body_to_ned(roll, pitch, yaw).astype(np.float64)
        world = np.stack([np.asarray(north_m, float) - x, np.asarray(east_m, float) - y, np.asarray(down_m, float) - z])
        body = rot.T @ world.reshape(3, -1)
        tilt = math.radians(self.tilt_deg)
        forward = math.cos(tilt) * body[0] + math.sin(tilt) * body[2]
        down = -math.sin(tilt) * body[0] + math.cos(tilt) * body[2]
        right = body[1]
        ahead = forward > 1e-6
        safe = np.where(ahead, forward, 1.0)
        focal = self.focal_px
        col = focal * right / safe + self.width / 2 - 0.5
        row = focal * down / safe + self.height / 2 - 0.5
        return col, row, ahead

    def object_box(self, pose: Any, obj: SeabedObject) -> "TrueBox":
        """The object's true box in the picture taken from `pose`: the bounds of its
        footprint's four corners on the seabed (a plane maps a rectangle to a convex
        quadrilateral, so they bound it exactly), whole and clipped to the picture."""
        c, s = math.cos(obj.heading_rad), math.sin(obj.heading_rad)
        half_len, half_w = obj.length_m / 2, obj.width_m / 2
        along = np.array([1, 1, -1, -1]) * half_len
        across = np.array([1, -1, -1, 1]) * half_w
        north = obj.x_m + along * c - across * s
        east = obj.y_m + along * s + across * c
        col, row, ahead = self.project(pose, north, east, np.full(4, self.seabed.depth_m))
        if not ahead.all():
            return TrueBox(None, None)
        # Pixel edges: a pixel centre at column i covers i - 0.5 .. i + 0.5.
        corners = [(float(cx) + 0.5, float(cy) + 0.5) for cx, cy in zip(col, row)]
        inside = _clip_polygon(corners, float(self.width), float(self.height))
        whole = _bounds(corners)
        if len(inside) < 3:
            return TrueBox(whole, None)
        x0, y0, x1, y1 = _bounds(inside)  # rounding in the clipping may leave a hair outside the picture
        clipped = (max(x0, 0.0), max(y0, 0.0), min(x1, float(self.width)), min(y1, float(self.height)))
        return TrueBox(whole, clipped, _polygon_area(inside) / max(_polygon_area(corners), 1e-9))

    def _camera_rays(self) -> np.ndarray:
        """Unit ray directions in the body frame: forward, right, down arrays of H*W."""
        focal = (self.width / 2) / math.tan(math.radians(self.hfov_deg) / 2)
        cols = (np.arange(self.width, dtype=np.float32) + 0.5 - self.width / 2) / focal
        rows = (np.arange(self.height, dtype=np.float32) + 0.5 - self.height / 2) / focal
        right, down = np.meshgrid(cols, rows)
        tilt = math.radians(self.tilt_deg)
        # The camera's axes in the body frame, tilted down about the body y axis.
        forward_axis = np.array([math.cos(tilt), 0.0, math.sin(tilt)], np.float32)
        down_axis = np.array([-math.sin(tilt), 0.0, math.cos(tilt)], np.float32)
        right_axis = np.array([0.0, 1.0, 0.0], np.float32)
        rays = forward_axis + right[..., None] * right_axis + down[..., None] * down_axis
        rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
        rays = rays.reshape(-1, 3)
        return tuple(np.ascontiguousarray(rays[:, i]) for i in range(3))

    @staticmethod
    def _body_to_ned(roll: float, pitch: float, yaw: float) -> np.ndarray:
        cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch),
                                  math.cos(yaw), math.sin(yaw))
        return np.array(
            [
                [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                [-sp, cp * sr, cp * cr],
            ],
            np.float32,
        )

    def _geometry(self, z: float, roll: float, pitch: float):
        """Everything that depends on depth and tilt but not on x, y or yaw: which
        pixels see the seabed, where (relative to the vehicle, before yaw), and what
        the water does to their light.  Cached: between frames usually only x, y
        and yaw change, and yaw turns about the vertical, which leaves it all alone."""
        key = (round(z, 3), round(roll, 4), round(pitch, 4))
        cached_key, cached = self._cached_geometry  # one attribute: safe across threads
        if key == cached_key:
            return cached
        seabed = self.seabed
        rot = self._body_to_ned(roll, pitch, 0.0)
        bx, by, bz = self._rays
        # Three multiply-adds per axis: much faster than a (N,3) @ (3,3) matmul here.
        rx = rot[0, 0] * bx + rot[0, 1] * by + rot[0, 2] * bz
        ry = rot[1, 0] * bx + rot[1, 1] * by + rot[1, 2] * bz
        rz = rot[2, 0] * bx + rot[2, 1] * by + rot[2, 2] * bz
        height_m = seabed.depth_m - z
        daylight = np.exp(-self.DAYLIGHT_PER_M * max(z, 0.0))
        hits = (rz > 1e-3) if height_m > 0 else np.zeros(rz.shape, bool)
        base = np.empty((rz.shape[0], 3), np.float32)
        miss = np.flatnonzero(~hits)
        if miss.size:
            # Open water: brighter and bluer looking up, darker looking down.
            up = np.clip(-rz[miss], 0.0, 1.0)[:, None]
            base[miss] = (self.WATER_RGB + (self.SURFACE_RGB - self.WATER_RGB) * up) * (0.75 + 0.25 * up) * daylight
        idx = np.flatnonzero(hits)
        d = np.float32(max(height_m, 0.0)) / rz[idx]
        # Sunlight dimmed by the water above the seabed, plus the vehicle's lamps,
        # which give back some red close by; then absorption and haze on the way.
        lamp = self.LAMP_GAIN / (1.0 + (d / self.LAMP_RANGE_M) ** 2)
        light = np.exp(-self.DAYLIGHT_PER_M * seabed.depth_m)[None, :] + lamp[:, None]
        transmit = np.exp(-self.ATTENUATION_PER_M[None, :] * d[:, None])
        haze = self.WATER_RGB * np.exp(-self.DAYLIGHT_PER_M * (0.5 * (max(z, 0.0) + seabed.depth_m)))
        geometry = (idx, rx[idx] * d, ry[idx] * d, light * transmit, haze[None, :] * (1.0 - transmit), base)
        self._cached_geometry = (key, geometry)
        return geometry

    def capture(self, pose: Any = None) -> np.ndarray:
        x, y, z, roll, pitch, yaw = _pose_tuple(pose)
        idx, offset_n, offset_e, gain, haze, base = self._geometry(z, roll, pitch)
        colour = base.copy()
        if idx.size:
            c, s = np.float32(math.cos(yaw)), np.float32(math.sin(yaw))
            ground = self._sample(np.float32(x) + c * offset_n - s * offset_e, np.float32(y) + s * offset_n + c * offset_e)
            colour[idx] = ground * gain + haze
        image = colour.reshape(self.height, self.width, 3)
        return np.clip(image * self.EXPOSURE, 0, 255).astype(np.uint8)

    def _sample(self, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
        """Bilinear texture lookup at world points, repeating beyond the extent."""
        h, w = self.seabed.texture.shape[:2]
        seabed = self.seabed
        inv_res = np.float32(1.0 / seabed.metres_per_px)
        row = (np.float32(seabed.x_max_m) - gx) * inv_res - np.float32(0.5)
        col = (gy - np.float32(seabed.y_min_m)) * inv_res - np.float32(0.5)
        r0f, c0f = np.floor(row), np.floor(col)
        fr, fc = (row - r0f)[:, None], (col - c0f)[:, None]
        # Indices into the texture padded by one wrapped row and column, so the four
        # neighbours are i, i+1, i+W+1, i+W+2 without a second modulo.
        i = (r0f.astype(np.int32) % h) * (w + 1) + (c0f.astype(np.int32) % w)
        flat = self._flat_texture

        def texels(index: np.ndarray) -> np.ndarray:
            # Gathering bytes and converting afterwards moves a quarter of the memory.
            return np.take(flat, index, axis=0).astype(np.float32)

        a, b = texels(i), texels(i + 1)
        c, d = texels(i + (w + 1)), texels(i + (w + 2))
        top = a + (b - a) * fc
        bottom = c + (d - c) * fc
        return top + (bottom - top) * fr

    def close(self) -> None:
        pass


class FolderCamera:
    """The images of a folder in name order, played in a loop."""

    def __init__(self, folder: str | Path, width: int = DEFAULT_SIZE[0], height: int = DEFAULT_SIZE[1]) -> None:
        self.width, self.height = _check_size(width, height)
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise CameraError(f"image folder not found: {self.folder}")
        self.paths = sorted(p for p in self.folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
        if not self.paths:
            raise CameraError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in {self.folder}")
        self._next = 0

    def capture(self, pose: Any = None) -> np.ndarray:
        from PIL import Image, UnidentifiedImageError

        # Skip unreadable files rather than stall the camera; give up after a full lap.
        for _ in range(len(self.paths)):
            path = self.paths[self._next]
            self._next = (self._next + 1) % len(self.paths)
            try:
                with Image.open(path) as image:
                    image = image.convert("RGB")
                    if image.size != (self.width, self.height):
                        image = image.resize((self.width, self.height), Image.BILINEAR)
                    return np.asarray(image, dtype=np.uint8).copy()
            except (OSError, UnidentifiedImageError, ValueError):
                continue
        raise CameraError(f"none of the images in {self.folder} could be read")

    def close(self) -> None:
        pass


class OpenCVCamera:
    """An OpenCV capture device: a camera index or a stream URL."""

    def __init__(self, device: int | str = 0, width: int = DEFAULT_SIZE[0], height: int = DEFAULT_SIZE[1]) -> None:
        self.width, self.height = _check_size(width, height)
        try:
            import cv2
        except ImportError as exc:
            raise CameraError(
                "OpenCV is not installed; install rovlink with the 'opencv' extra (opencv-python-headless)"
            ) from exc
        self._cv2 = cv2
        self.device = int(device) if isinstance(device, str) and device.isdigit() else device
        self._capture = cv2.VideoCapture(self.device)
        if not self._capture.isOpened():
            raise CameraError(f"cannot open capture device {device!r}")

    def capture(self, pose: Any = None) -> np.ndarray:
        ok, frame = self._capture.read()
        if not ok or frame is None:
            raise CameraError(f"capture device {self.device!r} gave no frame")
        frame = self._cv2.resize(frame, (self.width, self.height), interpolation=self._cv2.INTER_AREA)
        return self._cv2.cvtColor(frame, self._cv2.COLOR_BGR2RGB)

    def close(self) -> None:
        self._capture.release()


def open_camera(spec: str = "sim", width: int = DEFAULT_SIZE[0], height: int = DEFAULT_SIZE[1],
                seabed: Seabed | None = None) -> CameraSource:
    """A camera source from a short spec: "sim", "folder:PATH" (or a directory),
    "opencv:INDEX_OR_URL".  `seabed`: what "sim" sees (default: the committed one)."""
    spec = (spec or "sim").strip()
    if spec == "sim":
        return SimulatedCamera(width, height, seabed=seabed)
    if spec.startswith("folder:"):
        return FolderCamera(spec[len("folder:"):], width, height)
    if spec.startswith("opencv:"):
        return OpenCVCamera(spec[len("opencv:"):], width, height)
    if Path(spec).is_dir():
        return FolderCamera(spec, width, height)
    raise CameraError(f"unknown camera {spec!r}: expected sim, folder:PATH or opencv:DEVICE")
