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
