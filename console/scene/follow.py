"""Where the followed object lies in the 3-D scene (issue 34, docs/PROTOCOL.md §10): the
ray from the camera, at the pose the picture was captured from, through the centre of
the ROI that picture was coded with, to the seabed.

A pure function on the conventions of frames.py; the scene draws its result.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from . import frames


def followed_ray(pose: dict, roi, *, hfov_deg: float, tilt_deg: float, size_px: tuple[int, int],
                 camera_in_body_flu, floor_z: float, max_range_m: float = 30.0) -> np.ndarray | None:
    """(2, 3) world points: the camera at capture and where the ray through the ROI's
    centre meets the seabed plane z = floor_z (or `max_range_m` along it when it misses).
    None without a pose or an ROI."""
    if not pose or not roi:
        return None
    p = SimpleNamespace(**pose)
    position, wxyz = frames.pose_to_world(p)
    r_world_flu = frames.body_rotation(p.roll_deg, p.pitch_deg, p.yaw_deg)
    origin = np.asarray(position, float) + r_world_flu @ np.asarray(camera_in_body_flu, float)
    w, h = size_px
    focal = (w / 2) / math.tan(math.radians(hfov_deg) / 2)
    u, v = (roi[0] + roi[2]) / 2, (roi[1] + roi[3]) / 2
    ray_cam = np.array([(u - w / 2) / focal, (v - h / 2) / focal, 1.0])  # OpenCV axes: x right, y down, z ahead
    direction = r_world_flu @ frames.camera_rotation_in_body(tilt_deg) @ ray_cam
    direction /= np.linalg.norm(direction)
    hit = frames.ray_plane_hit(origin, origin + direction, (0.0, 0.0, floor_z), (0.0, 0.0, 1.0))
    if hit is None or np.linalg.norm(hit - origin) > max_range_m:
        hit = origin + direction * max_range_m
    return np.stack([origin, hit])
