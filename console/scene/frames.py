"""Frames of the console's 3-D scene, and the conversions into them.

Goals: one place that says how the vehicle's local NED frame, its body frame and
its camera appear in viser, so every node of the scene agrees (and the tests can
check the conventions rather than pixels).

The conventions
- World (viser's frame) is ENU, z up, the default "up" of viser: world x = east
  (NED y), world y = north (NED x), world z = up (minus NED z).  The origin is
  the NED origin, so the sea surface is z = 0 and the seabed of
  `assets/seabed.json` lies at z = -depth_m.
- The vehicle's model is drawn in body FLU (x forward, y left, z up).  The
  telemetry's attitude is NED roll/pitch/yaw of body FRD, so the node's rotation
  is  R_world_flu = M @ R_ned_frd(roll, pitch, yaw) @ F,  with M the NED to ENU
  swap and F = diag(1, -1, -1) the FLU to FRD flip.  Yaw 0 faces north (+y),
  yaw 90 degrees east (+x).
- Cameras and images follow viser's (OpenCV) convention: +x right, +y down,
  +z forward; an image node shows pixel (u, v) at local
  ((u / W - 1/2) * width_m, (v / H - 1/2) * height_m, 0), seen from its -z side.

Plan: small pure functions on numpy arrays; quaternions are viser's wxyz.
"""

from __future__ import annotations

import math

import numpy as np
from viser import transforms as tf

# NED -> ENU (a proper rotation: x and y swap, z flips).
NED_TO_WORLD = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
FLU_TO_FRD = np.diag([1.0, -1.0, -1.0])


def ned_to_world(x_m, y_m, z_m) -> np.ndarray:
    """World (ENU) coordinates of NED points; arrays broadcast, last axis xyz."""
    return np.stack(np.broadcast_arrays(np.asarray(y_m, float), np.asarray(x_m, float), -np.asarray(z_m, float)),
                    axis=-1)


def world_to_ned(points) -> np.ndarray:
    """NED coordinates of world points (..., 3)."""
    p = np.asarray(points, float)
    return np.stack([p[..., 1], p[..., 0], -p[..., 2]], axis=-1)


def rotation_ned_frd(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """Body FRD to NED (ZYX Euler angles), as the autopilot reports them."""
    r, p, y = (math.radians(v) for v in (roll_deg, pitch_deg, yaw_deg))
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def body_rotation(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """R_world_flu: the vehicle's FLU axes in the world."""
    return NED_TO_WORLD @ rotation_ned_frd(roll_deg, pitch_deg, yaw_deg) @ FLU_TO_FRD


def body_wxyz(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    return tf.SO3.from_matrix(body_rotation(roll_deg, pitch_deg, yaw_deg)).wxyz


def pose_to_world(pose) -> tuple[np.ndarray, np.ndarray]:
    """(position, wxyz) of the vehicle node for anything with NED `x_m`..`yaw_deg`."""
    position = ned_to_world(pose.x_m, pose.y_m, pose.z_m)
    return position, body_wxyz(pose.roll_deg, pose.pitch_deg, pose.yaw_deg)


def yaw_deg_from_wxyz(wxyz) -> float:
    """NED yaw of a node whose x axis is the vehicle's forward (roll/pitch ignored)."""
    forward = tf.SO3(np.asarray(wxyz, float)).as_matrix()[:, 0]  # world (east, north, up)
    return math.degrees(math.atan2(forward[0], forward[1]))


def camera_rotation_in_body(tilt_deg: float) -> np.ndarray:
    """R_flu_cam: the camera's OpenCV axes in body FLU, looking forward, tilted
    down by `tilt_deg` (as `rov.camera.SimulatedCamera` casts its rays)."""
    t = math.radians(tilt_deg)
    right = np.array([0.0, -1.0, 0.0])
    down = np.array([-math.sin(t), 0.0, -math.cos(t)])
    forward = np.array([math.cos(t), 0.0, -math.sin(t)])
    return np.column_stack([right, down, forward])


def vertical_fov_rad(hfov_deg: float, width_px: int, height_px: int) -> float:
    return 2.0 * math.atan(math.tan(math.radians(hfov_deg) / 2.0) * height_px / width_px)


def image_corner_rays(hfov_deg: float, width_px: int, height_px: int) -> np.ndarray:
    """Directions (4, 3) through the image corners in the camera's OpenCV frame:
    top-left, top-right, bottom-right, bottom-left."""
    x = math.tan(math.radians(hfov_deg) / 2.0)
    y = x * height_px / width_px
    return np.array([[-x, -y, 1.0], [x, -y, 1.0], [x, y, 1.0], [-x, y, 1.0]])


def seabed_footprint(position, r_world_cam, corner_rays, floor_z: float, max_range_m: float) -> np.ndarray:
    """Where the camera's corner rays meet the seabed plane z = floor_z (world);
    rays that miss it, or meet it beyond `max_range_m`, stop at that range."""
    dirs = corner_rays @ np.asarray(r_world_cam).T
    dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    origin = np.asarray(position, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (floor_z - origin[2]) / dirs[:, 2]
    t = np.where((dirs[:, 2] < 0) & (t > 0), np.minimum(t, max_range_m), max_range_m)
    return origin + dirs * t[:, None]


def image_plane_to_pixel(local_xy, size_m: tuple[float, float], size_px: tuple[int, int]) -> np.ndarray:
    """Pixel (u, v) of points in an image node's local frame (x right, y down)."""
    p = np.asarray(local_xy, float)
    w_m, h_m = size_m
    w_px, h_px = size_px
    return np.stack([(p[..., 0] / w_m + 0.5) * w_px, (p[..., 1] / h_m + 0.5) * h_px], axis=-1)


def pixel_to_image_plane(uv, size_m: tuple[float, float], size_px: tuple[int, int]) -> np.ndarray:
    """Local (x, y) on an image node of pixel coordinates (u, v); inverse of the above."""
    p = np.asarray(uv, float)
    w_m, h_m = size_m
    w_px, h_px = size_px
    return np.stack([(p[..., 0] / w_px - 0.5) * w_m, (p[..., 1] / h_px - 0.5) * h_m], axis=-1)


def world_to_local(points, position, wxyz) -> np.ndarray:
    """Points (..., 3) from world into a node's frame."""
    r = tf.SO3(np.asarray(wxyz, float)).as_matrix()
    return (np.asarray(points, float) - np.asarray(position, float)) @ r


def ray_plane_hit(origin, through, plane_point, plane_normal) -> np.ndarray | None:
    """Where the ray from `origin` through `through` meets a plane; None if parallel
    or behind."""
    origin = np.asarray(origin, float)
    d = np.asarray(through, float) - origin
    n = np.asarray(plane_normal, float)
    denom = float(d @ n)
    if abs(denom) < 1e-9:
        return None
    t = float((np.asarray(plane_point, float) - origin) @ n) / denom
    if t <= 0:
        return None
    return origin + t * d
