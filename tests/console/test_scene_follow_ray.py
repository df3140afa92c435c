"""The scene's ray to the followed object (console/scene/follow.py): from the camera at
capture through the coded ROI's centre, it meets the seabed where the simulated camera
shows the object (rov/camera.py's truth), whatever the heading."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rovlink.console.scene import frames
from rovlink.console.scene.app import CAMERA_IN_BODY_FLU
from rovlink.console.scene.follow import followed_ray
from rovlink.rov.camera import SimulatedCamera
from rovlink.rov.seabed import Seabed


@pytest.mark.parametrize("yaw_deg,side_m", [(0.0, 0.0), (20.0, -1.0), (-35.0, 1.5), (120.0, 0.0)])
def test_the_ray_through_the_coded_roi_meets_the_seabed_at_the_object(yaw_deg, side_m):
    seabed = Seabed.load()
    ladder = next(o for o in seabed.objects if o.kind == "ladder")
    camera = SimulatedCamera(seabed=seabed)
    yaw = math.radians(yaw_deg)
    # 4.3 m behind the ladder along the heading, side_m to its right, 3 m over the seabed.
    x = ladder.x_m - 4.3 * math.cos(yaw) - side_m * -math.sin(yaw)
    y = ladder.y_m - 4.3 * math.sin(yaw) - side_m * math.cos(yaw)
    z = seabed.depth_m - 3.0
    box = camera.object_box((x, y, z, yaw), ladder).clipped
    assert box is not None
    pose = {"x_m": x, "y_m": y, "z_m": z, "roll_deg": 0.0, "pitch_deg": 0.0, "yaw_deg": yaw_deg}
    ray = followed_ray(pose, box, hfov_deg=camera.hfov_deg, tilt_deg=camera.tilt_deg, size_px=(320, 240),
                       camera_in_body_flu=CAMERA_IN_BODY_FLU, floor_z=-seabed.depth_m)
    hit_ned = frames.world_to_ned(ray[1])
    assert hit_ned[2] == pytest.approx(seabed.depth_m)
    # The box's centre is the ladder's within its own size (a box's centre is not its object's, in perspective).
    assert np.hypot(hit_ned[0] - ladder.x_m, hit_ned[1] - ladder.y_m) < 0.5
    assert np.allclose(frames.world_to_ned(ray[0])[:2], (x, y), atol=0.25)  # from the camera


def test_no_ray_without_a_pose_or_an_roi():
    kw = dict(hfov_deg=80.0, tilt_deg=35.0, size_px=(320, 240), camera_in_body_flu=(0, 0, 0), floor_z=-8.0)
    assert followed_ray(None, (1, 1, 5, 5), **kw) is None
    assert followed_ray({"x_m": 0, "y_m": 0, "z_m": 1, "roll_deg": 0, "pitch_deg": 0, "yaw_deg": 0}, None, **kw) is None
