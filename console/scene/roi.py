"""The region of interest, between the pilot's mouse and the IMAGE order.

Goals: a rectangle dragged on the image shown in the scene becomes the
(x0, y0, x1, y1) pixel ROI of the IMAGE order (x1, y1 exclusive, as `debt`
takes it), and a ROI is drawn back over the image it refers to, both on the
scene's screen and on the panel's copy of the picture.

Plan: pure functions.  World points -> the screen node's local frame -> pixels
(`console.scene.frames`), rounded outwards and clipped to the image; a drag
smaller than `MIN_ROI_PX` is taken for a click and selects nothing.
"""

from __future__ import annotations

import math

import numpy as np

from .frames import image_plane_to_pixel, pixel_to_image_plane, world_to_local

MIN_ROI_PX = 4


def roi_from_pixels(uv_a, uv_b, size_px: tuple[int, int]) -> tuple[int, int, int, int] | None:
    """The pixel rectangle spanned by two corners (any order), rounded outwards
    and clipped to the image; None if too small."""
    w, h = size_px
    (ua, va), (ub, vb) = uv_a, uv_b
    x0 = max(0, min(w, math.floor(min(ua, ub))))
    x1 = max(0, min(w, math.ceil(max(ua, ub))))
    y0 = max(0, min(h, math.floor(min(va, vb))))
    y1 = max(0, min(h, math.ceil(max(va, vb))))
    if x1 - x0 < MIN_ROI_PX or y1 - y0 < MIN_ROI_PX:
        return None
    return (x0, y0, x1, y1)


def roi_from_world(point_a, point_b, *, position, wxyz, size_m: tuple[float, float],
                   size_px: tuple[int, int]) -> tuple[int, int, int, int] | None:
    """ROI from two world points on (or near) an image node at `position`/`wxyz`
    drawn `size_m` wide and high, showing an image of `size_px` (width, height)."""
    local = world_to_local(np.array([point_a, point_b], float), position, wxyz)
    uv = image_plane_to_pixel(local[:, :2], size_m, size_px)
    return roi_from_pixels(uv[0], uv[1], size_px)


def roi_outline(roi, size_m: tuple[float, float], size_px: tuple[int, int], lift_m: float) -> np.ndarray:
    """Line segments (4, 2, 3) of the ROI's border in the image node's frame,
    `lift_m` towards the viewer (the -z side) so the lines sit on the picture."""
    x0, y0, x1, y1 = roi
    corners = pixel_to_image_plane(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float), size_m, size_px)
    corners3 = np.column_stack([corners, np.full(4, -lift_m)])
    return np.stack([corners3, np.roll(corners3, -1, axis=0)], axis=1).astype(np.float32)


def draw_roi(image: np.ndarray, roi, rgb=(255, 210, 0), width_px: int = 2) -> np.ndarray:
    """A copy of `image` (H x W x 3) with the ROI's border painted in."""
    out = np.array(image, copy=True)
    h, w = out.shape[:2]
    x0, y0, x1, y1 = (int(v) for v in roi)
    x0, x1 = max(0, min(x0, w)), max(0, min(x1, w))
    y0, y1 = max(0, min(y0, h)), max(0, min(y1, h))
    if x1 <= x0 or y1 <= y0:
        return out
    colour = np.asarray(rgb, out.dtype)
    k = max(1, min(width_px, (x1 - x0) // 2, (y1 - y0) // 2))
    out[y0:y0 + k, x0:x1] = colour
    out[y1 - k:y1, x0:x1] = colour
    out[y0:y1, x0:x0 + k] = colour
    out[y0:y1, x1 - k:x1] = colour
    return out
