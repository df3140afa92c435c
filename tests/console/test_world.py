"""The world the ROV measured (issue 38, docs/PROTOCOL.md §11) as the console keeps it:
the seabed at the depth the ROV measured, the objects it recognised, in the state the
page and the scene read, in the recording and in its replay; a record out of range is
one line; with no altitude there is no floor."""

from __future__ import annotations

import asyncio
import time

from rovlink.console.replaycontrol import replay
from rovlink.console.session.radio import Operator
from rovlink.console.session.world import SeenWorld
from rovlink.console.stack import Stack, StackConfig
from rovlink.link.scene import SeenObject
from rovlink.rov.seabed import Seabed


async def _until(predicate, timeout_s):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        await asyncio.sleep(0.1)
    return True


def test_the_world_comes_from_the_link_and_is_laid_again_on_replay(tmp_path):
    """Version 2 over the in-process stack, the ROV recognising objects: the seabed's depth
    is the vehicle's depth plus the altitude it reports (the simulator's floor, within the
    ALT byte's 5 cm), objects appear with their class, size and age; the recording lays the
    same world again."""
    record = tmp_path / "session.jsonl"
    floor = Seabed.load().depth_m

    async def main():
        # 3 m above the seabed, where the ROV's detector is meant to work (2 to 4 m).
        config = StackConfig(bitrate_bps=19200, delay_s=0.02, ber=0.0, key=bytes(range(32)), objects=True,
                             record=record, start_depth_m=floor - 3.0)
        async with Stack(config) as stack:
            op = stack.operator
            assert await _until(lambda: op.world_state()["seabed_depth_m"] is not None, 30), op.world_state()
            world = op.world_state()
            assert abs(world["seabed_depth_m"] - floor) < 0.15, (world, floor)
            assert world["altitude_m"] > 0 and not world["altitude_stale"]
            op.arm(True)
            assert await _until(lambda: op.last_reply is not None and op.last_reply.armed, 15)
            op.set_velocity(0.0, 0.0, 0.0, 0.3)  # turn on the spot: the camera sweeps the seabed
            found = await _until(lambda: len(op.world_state()["objects"]) >= 1, 90)
            op.set_velocity(0.0, 0.0, 0.0, 0.0)
            assert found, (op.world_state(), [e["text"] for e in op.log_entries(20)])
            obj = op.world_state()["objects"][0]
            assert obj["class"] in ("amphora", "pipe", "timber", "ladder", "unknown")
            assert obj["length_m"] >= obj["width_m"] > 0 and 0 < obj["confidence"] <= 1
            assert obj["record_bytes"] <= 12 and obj["age_s"] >= 0
            assert any("recognised" in e["text"] for e in op.log_entries(100))
            return op.world_state()

    live = asyncio.run(asyncio.wait_for(main(), 240))
    replayed = Operator(None)
    asyncio.run(replay(replayed, record, speed=50.0))
    again = replayed.world_state()
    assert again["seabed_depth_m"] is not None and abs(again["seabed_depth_m"] - live["seabed_depth_m"]) < 0.15
    assert {o["id"] for o in live["objects"]} <= {o["id"] for o in again["objects"]}


def test_no_altitude_no_floor_and_a_record_out_of_range_is_one_line():
    notes, published = [], []
    import threading

    world = SeenWorld(lock=threading.RLock(), record=lambda r: None, publish=lambda t, p: published.append(t),
                      note=lambda text, level="info", **kw: notes.append((level, text)))
    state = world.state(0.0)
    assert state["seabed_depth_m"] is None and state["seabed_unknown_why"] == "no report yet"
    world.depth(3.0)
    world.altitude(None, 1.0, 3.0)  # a real ArduSub with no rangefinder
    state = world.state(1.0)
    assert state["seabed_depth_m"] is None and "no rangefinder" in state["seabed_unknown_why"]
    world.altitude(2.0, 2.0, 3.0)
    assert world.state(2.0)["seabed_depth_m"] == 5.0
    assert world.state(20.0)["altitude_stale"]
    world.record_ignored("0f00", 3.0)
    world.record_ignored("0f01", 3.1)
    assert world.state(3.2)["records_ignored"] == 2
    assert [n for n in notes if n[0] == "warn"] == [("warn", notes[-1][1])] and "0f00" in notes[-1][1]
    world.object_seen(SeenObject(7, "pipe", 0.75, 1.0, 2.0, 4.0, 0.3, 30.0, True), 9, 4.0)
    world.object_removed(7, 5.0)
    assert world.state(5.0)["objects"] == [] and "world" in published


def _world_with_a_pipe(seabed_depth_m: float = 8.0):
    import threading

    notes = []
    world = SeenWorld(lock=threading.RLock(), record=lambda r: None, publish=lambda t, p: None,
                      note=lambda text, level="info", **kw: notes.append((level, text)))
    world.altitude(seabed_depth_m - 5.5, 1.0, 5.5)
    world.object_seen(SeenObject(3, "pipe", 0.9, 4.0, 2.0, 2.4, 0.3, 60.0, True), 9, 1.0)
    return world


def test_frame_it_projects_the_object_where_the_camera_sees_it():
    """"Frame it"'s ROI, from the stand-off the go-to to it stops at, covers the object's
    true box in the simulated camera's picture taken there (the ROV's own projection,
    rov/camera.py), with a margin, and stays inside the picture."""
    import math
    from types import SimpleNamespace

    from rovlink.console.session.odometry import Pose
    from rovlink.rov.camera import SimulatedCamera
    from rovlink.rov.seabed import SeabedObject

    world = _world_with_a_pipe()
    stand = world.approach(3, 0.0, 0.0, 5.5)
    pose = Pose(stand["x_m"], stand["y_m"], stand["z_m"], 0.0, 0.0, stand["yaw_deg"])
    camera = SimulatedCamera(seabed=SimpleNamespace(texture=Seabed.load().texture, depth_m=8.0))
    for size in ((320, 240), (80, 60)):
        camera.width, camera.height = size
        roi, words = world.frame(3, pose, size)
        assert roi is not None, words
        truth = camera.object_box(SimpleNamespace(x_m=pose.x_m, y_m=pose.y_m, z_m=pose.z_m, roll_rad=0.0,
                                                  pitch_rad=0.0, yaw_rad=math.radians(pose.yaw_deg)),
                                  SeabedObject("pipe", 4.0, 2.0, 2.4, 0.3, math.radians(60.0))).clipped
        assert truth is not None
        # The ROI holds the object (the camera's 0.2 m dome offset and the margin aside)...
        assert roi[0] <= truth[0] + 1 and roi[1] <= truth[1] + 1 and roi[2] >= truth[2] - 1 and roi[3] >= truth[3] - 1
        # ... and is not the whole picture: it frames the object.
        assert (roi[2] - roi[0]) * (roi[3] - roi[1]) < 0.6 * size[0] * size[1], (roi, truth)
        assert 0 <= roi[0] < roi[2] <= size[0] and 0 <= roi[1] < roi[3] <= size[1]
        assert "framed" in words


def test_frame_it_says_why_not_rather_than_a_wrong_roi():
    """Behind the camera, too far, off to the side, or no seabed measured: no ROI, one line."""
    from rovlink.console.session.odometry import Pose

    world = _world_with_a_pipe()
    away = Pose(0.0, 0.0, 5.5, 0.0, 0.0, 180.0)  # the pipe lies north-east: looking south
    roi, words = world.frame(3, away, (320, 240))
    assert roi is None and "not in view of the camera from where the ROV is" in words
    far = Pose(-20.0, 2.0, 5.5, 0.0, 0.0, 0.0)
    roi, words = world.frame(3, far, (320, 240))
    assert roi is None and "beyond" in words and "Go to first" in words
    aside = Pose(4.0, -1.5, 5.5, 0.0, 0.0, 0.0)  # beside it, looking north: it is off to the right
    roi, words = world.frame(3, aside, (320, 240))
    assert roi is None and "not in view" in words
    assert world.frame(9, away, (320, 240))[0] is None
    world.altitude(None, 2.0, 5.5)  # the altitude gone: nowhere to lay it in the picture
    roi, words = world.frame(3, Pose(0.0, 0.0, 5.5, 0.0, 0.0, 27.0), (320, 240))
    assert roi is None and "seabed depth unknown" in words
