"""Pictures laid on the seabed where they were taken (issue 38): each picture received,
projected through its capture pose onto the floor the ROV measured, as a top-down
raster the scene draws flat on that floor.

Geometry only, no viser: `ground_quad` finds where the picture's rows meet the floor
(the rows whose rays meet it within `max_range_m`: a tilted camera's upper rows see the
floor too far off, or the water above it), `warp_to_ground` resamples that part of the
picture onto a north-up raster of the quad's bounding box (transparent outside it).
"""

from __future__ import annotations

import math

import numpy as np
from PIL import Image

from . import frames

MOSAIC_RES_M = 0.04       # ground size of a raster pixel
MOSAIC_RANGE_M = 8.0      # rows whose rays meet the floor further off are left out (too coarse)


def _hit(origin: np.ndarray, direction: np.ndarray, floor_z: float) -> np.ndarray | None:
    if direction[2] >= -1e-9:
        return None
    t = (floor_z - origin[2]) / direction[2]
    return origin + t * direction if t > 0 else None


def ground_quad(pose: dict, *, hfov_deg: float, tilt_deg: float, size_px: tuple[int, int], camera_in_body_flu,
                floor_z: float, max_range_m: float = MOSAIC_RANGE_M) -> tuple[int, np.ndarray] | None:
    """(the first image row laid, the world corners (4, 3) of rows from it down: top-left,
    top-right, bottom-right, bottom-left), or None when even the bottom row misses the floor."""
    w, h = size_px
    p = type("P", (), pose)
    r_world_flu = frames.body_rotation(p.roll_deg, p.pitch_deg, p.yaw_deg)
    origin = np.asarray(frames.ned_to_world(p.x_m, p.y_m, p.z_m), float) + r_world_flu @ np.asarray(camera_in_body_flu)
    r_world_cam = r_world_flu @ frames.camera_rotation_in_body(tilt_deg)
    fx = (w / 2) / math.tan(math.radians(hfov_deg) / 2)

    def row_hits(v: float):
        left = _hit(origin, r_world_cam @ np.array([(0 - w / 2) / fx, (v - h / 2) / fx, 1.0]), floor_z)
        right = _hit(origin, r_world_cam @ np.array([(w - w / 2) / fx, (v - h / 2) / fx, 1.0]), floor_z)
        if left is None or right is None:
            return None
        if max(np.linalg.norm(left - origin), np.linalg.norm(right - origin)) > max_range_m:
            return None
        return left, right

    bottom = row_hits(float(h))
    if bottom is None:
        return None
    top_v = None
    for v in range(0, h, max(1, h // 24)):
        if row_hits(float(v)) is not None:
            top_v = v
            break
    if top_v is None or top_v >= h - 2:
        return None
    top = row_hits(float(top_v))
    return top_v, np.array([top[0], top[1], bottom[1], bottom[0]])


def _perspective_coefficients(out_pts: np.ndarray, in_pts: np.ndarray) -> tuple[float, ...]:
    """PIL's PERSPECTIVE coefficients mapping output pixels to input pixels (4 pairs)."""
    rows, rhs = [], []
    for (x, y), (u, v) in zip(out_pts, in_pts):
        rows.append([x, y, 1, 0, 0, 0, -u * x, -u * y])
        rows.append([0, 0, 0, x, y, 1, -v * x, -v * y])
        rhs += [u, v]
    return tuple(np.linalg.solve(np.asarray(rows, float), np.asarray(rhs, float)))


def warp_to_ground(picture: np.ndarray, top_v: int, corners: np.ndarray, res_m: float = MOSAIC_RES_M):
    """(RGBA raster, north up and east right, its centre in the world, its width and height in
    metres) of the picture's rows from `top_v` down laid on the ground quad `corners`."""
    rgb = np.asarray(picture)
    if rgb.ndim == 2:
        rgb = np.repeat(rgb[:, :, None], 3, axis=2)
    h, w = rgb.shape[:2]
    east, north = corners[:, 0], corners[:, 1]
    e0, e1, n0, n1 = east.min(), east.max(), north.min(), north.max()
    cols, rows = max(2, int(math.ceil((e1 - e0) / res_m))), max(2, int(math.ceil((n1 - n0) / res_m)))
    out_pts = np.stack([(east - e0) / res_m, (n1 - north) / res_m], axis=1)  # raster columns east, rows south
    in_pts = np.array([[0, top_v], [w, top_v], [w, h], [0, h]], float)
    coeffs = _perspective_coefficients(out_pts, in_pts)
    rgba = np.dstack([rgb[:, :, :3].astype(np.uint8), np.full((h, w), 255, np.uint8)])
    warped = Image.fromarray(rgba, "RGBA").transform((cols, rows), Image.PERSPECTIVE, coeffs, Image.BILINEAR,
                                                     fillcolor=(0, 0, 0, 0))
    centre = np.array([(e0 + e1) / 2, (n0 + n1) / 2, float(corners[:, 2].mean())])
    return np.asarray(warped), centre, cols * res_m, rows * res_m
