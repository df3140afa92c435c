"""Pictures laid on the seabed where they were taken (console/scene/mosaic.py): the
part of a picture whose rays meet the measured floor, resampled north up."""

from __future__ import annotations

import numpy as np

from rovlink.console.scene import mosaic

POSE = {"x_m": 0.0, "y_m": 0.0, "z_m": 5.0, "roll_deg": 0.0, "pitch_deg": 0.0, "yaw_deg": 0.0}
CAMERA = dict(hfov_deg=80.0, tilt_deg=45.0, size_px=(320, 240), camera_in_body_flu=(0.2, 0.0, 0.035))


def test_a_picture_looking_north_is_laid_ahead_of_the_camera_west_on_its_left():
    top_v, corners = mosaic.ground_quad(POSE, floor_z=-8.0, **CAMERA)
    assert 0 < top_v < 240  # the upper rows see the floor too far off: left out
    assert np.allclose(corners[:, 2], -8.0)
    assert (corners[:, 1] > 0).all()  # north of the camera (world y is north)
    assert corners[0, 0] < corners[1, 0] and corners[3, 0] < corners[2, 0]  # image left is west
    assert corners[0, 1] > corners[3, 1]  # the top row lies further off than the bottom one
    picture = np.zeros((240, 320, 3), np.uint8)
    picture[:, :160, 0] = 200  # the left half red
    picture[200:, :, 2] = 255  # the bottom rows blue
    raster, centre, width_m, height_m = mosaic.warp_to_ground(picture, top_v, corners)
    seen = raster[..., 3] > 0
    cols = raster.shape[1]
    assert raster[:, : cols // 3, 0][seen[:, : cols // 3]].mean() > 150  # west: the left half
    assert raster[:, -cols // 3:, 0][seen[:, -cols // 3:]].mean() < 50
    assert raster[-5:, :, 2][seen[-5:]].mean() > 200  # south rows: the picture's bottom
    assert raster[:5, :, 2][seen[:5]].mean() < 50
    assert abs(width_m - (corners[:, 0].max() - corners[:, 0].min())) < 0.1 and centre[1] > 0


def test_a_camera_looking_at_the_water_above_lays_nothing():
    up = dict(POSE, pitch_deg=60.0)  # nose up: even the bottom row misses the floor within range
    assert mosaic.ground_quad(up, floor_z=-8.0, **CAMERA) is None
