"""Objects recognised on the ROV (rov/objects.py): measured on the seabed from a rendered
frame, merged across frames with stable ids, told as §11 records; a detector that fails is
said once and the node goes on."""

from __future__ import annotations

import math
import time

import pytest

pytest.importorskip("cv2")

from rovlink.link.scene import OP_CHANGED, OP_NEW, SceneOutbox  # noqa: E402
from rovlink.rov.camera import SimulatedCamera  # noqa: E402
from rovlink.rov.objects import CameraGeometry, Detection, ObjectMap, ObjectWatcher, SeabedDetector  # noqa: E402
from rovlink.rov.seabed import generate  # noqa: E402

DEV_SEED = 2  # a seed the detector was developed on (rovlink bench objects uses others)


@pytest.fixture(scope="module")
def scene():
    seabed = generate(seed=DEV_SEED)
    camera = SimulatedCamera(seabed=seabed)
    return seabed, camera, SeabedDetector(CameraGeometry.of(camera))


@pytest.mark.parametrize("kind", ["amphora", "pipe", "timber", "ladder"])
def test_an_object_in_view_is_measured_on_the_seabed(scene, kind):
    seabed, camera, detector = scene
    obj = next(o for o in seabed.objects if o.kind == kind)
    yaw = math.radians(150)
    pose = (obj.x_m - 4.3 * math.cos(yaw), obj.y_m - 4.3 * math.sin(yaw), seabed.depth_m - 3.0, yaw)
    assert camera.object_box(pose, obj).visible_fraction == 1.0
    found = detector.detect(camera.capture(pose), pose, 3.0)
    d = min(found, key=lambda d: math.hypot(d.north_m - obj.x_m, d.east_m - obj.y_m))
    assert d.class_name == kind
    assert math.hypot(d.north_m - obj.x_m, d.east_m - obj.y_m) < 0.3
    assert abs(d.length_m - obj.length_m) < 0.15 * obj.length_m
    if kind != "amphora":
        axis = abs(d.heading_deg - math.degrees(obj.heading_rad)) % 180
        assert min(axis, 180 - axis) < 10


def test_without_an_altitude_nothing_is_measured(scene):
    seabed, camera, detector = scene
    assert detector.detect(camera.capture((0, 0, 5, 0)), (0, 0, 5, 0), None) == []


def _d(north, east, length=2.0, heading=30.0, cls="timber"):
    return Detection(cls, north, east, length, 0.3, heading, 0.75, 0.9)


def test_sightings_merge_into_one_object_with_a_stable_id_told_new_then_changed():
    box = SceneOutbox()
    m = ObjectMap(box)
    m.add([_d(5.0, 2.0)], 0.0)
    assert box.pending() == 0  # one sighting is a candidate, never told
    m.add([_d(5.04, 2.02, heading=31.0), _d(-3.0, 1.0, cls="amphora", length=0.9)], 0.5)
    assert box.pending() == 0  # two sightings: still a candidate
    m.add([_d(4.98, 1.99, heading=30.0)], 0.7)
    first = box.next_record()
    assert first.op == OP_NEW and first.class_name == "timber" and abs(first.north_m - 5.0) < 0.05
    box.delivered(first)
    for t in (1.0, 1.5, 2.0):
        m.add([_d(5.02, 2.01, heading=30.5)], t)  # jitter: only the confidence grows with the sightings
    again = box.next_record()
    if again is not None:  # told again only for its confidence, never for a jitter of its centre
        assert again.object_id == first.object_id and again.north == first.north and again.confidence > first.confidence
        box.delivered(again)
    for t in (2.5, 3.0, 3.5, 4.0, 4.5, 5.0, 5.5, 6.0, 6.5, 7.0, 7.5, 8.0, 8.5, 9.0):
        m.add([_d(5.4, 2.0)], t)  # it was measured better later: a change
    changed = box.next_record()
    assert changed.op == OP_CHANGED and changed.object_id == first.object_id and changed.north_m > 5.1
    # The amphora seen once never became an object.
    m.add([], 20.0)
    assert [oid for oid, _ in m.told()] == [first.object_id]


def test_a_detector_that_fails_is_said_once_and_looks_no_more():
    said = []

    class Broken:
        def detect(self, frame, pose, altitude):
            raise RuntimeError("bad frame")

    watcher = ObjectWatcher(lambda: (None, (0, 0, 0, 0), 3.0), SceneOutbox(), said.append, hz=50.0,
                            detector_factory=Broken).start()
    deadline = time.monotonic() + 5
    while watcher.failed is None and time.monotonic() < deadline:
        time.sleep(0.02)
    time.sleep(0.1)
    watcher.stop()
    assert len(said) == 1 and "object detector stopped: RuntimeError: bad frame" in said[0]


def test_a_detector_that_cannot_start_is_said_once():
    said = []

    def missing():
        raise ImportError("No module named 'cv2'")

    watcher = ObjectWatcher(lambda: None, SceneOutbox(), said.append, detector_factory=missing).start()
    watcher._thread.join(2.0)
    assert said == ["object detector stopped: ImportError: No module named 'cv2'; the ROV goes on without objects"]


def test_the_rov_node_recognises_what_lies_ahead_and_puts_it_in_its_scene_outbox():
    """The node's own wiring: the bridge's altitude (the simulated echosounder) and pose, the
    camera, the watcher's thread, the version 2 link end's outbox."""
    from rovlink.link.transports.transport import inproc_pair
    from rovlink.rov.autopilot import AutopilotBridge
    from rovlink.rov.node import RovNode
    from rovlink.rov.simulator import SimulatedVehicle

    camera = SimulatedCamera()
    with SimulatedVehicle("udpin:127.0.0.1:0") as sim, AutopilotBridge(sim.bridge_url) as bridge:
        _, rov_end = inproc_pair("rov")
        node = RovNode(rov_end, bridge, camera.capture, key=bytes(32), objects=CameraGeometry.of(camera),
                       prefetch=False)
        deadline = time.monotonic() + 15
        while bridge.snapshot().altitude_m is None and time.monotonic() < deadline:
            time.sleep(0.05)
        node._start_objects(node.scene)
        try:
            while node.scene.pending() < 1 and time.monotonic() < deadline:
                time.sleep(0.1)
        finally:
            node.objects.stop()
        told = [d for _, d in node.objects.map.told()]
        assert len(told) >= 1 and node.objects.failed is None
        # The committed seabed's amphorae lie in a cluster (touching ones are one object to this
        # detector), about 4 m north and 2 m east of the start.
        assert all(1.0 < d.north_m < 8.0 and -2.0 < d.east_m < 6.0 for d in told)


def test_a_detector_that_fails_in_a_running_rov_node_is_said_once_and_the_node_goes_on(monkeypatch, caplog):
    """The whole radio stack (version 2, the ROV recognising objects), its detector failing on
    every frame: one warning in the ROV's log, no object told; the node goes on answering,
    its pictures keep coming, and the vehicle still moves when asked."""
    import asyncio
    import logging

    from rovlink.console.stack import Stack, StackConfig

    def broken(self, frame, pose, altitude):
        raise RuntimeError("bad frame")

    monkeypatch.setattr(SeabedDetector, "detect", broken)
    caplog.set_level(logging.WARNING, logger="rovlink")

    async def until(predicate, timeout_s):
        deadline = time.monotonic() + timeout_s
        while not predicate() and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        return predicate()

    async def main():
        config = StackConfig(bitrate_bps=19200, delay_s=0.02, ber=0.0, key=bytes(range(32)), objects=True,
                             start_depth_m=5.0)
        async with Stack(config) as stack:
            op, node = stack.operator, stack.node
            assert await until(lambda: node.objects is not None and node.objects.failed is not None, 30)
            serial, replies = op.image_state()["serial"], op.link_state()["reports"]
            op.arm(True)
            assert await until(lambda: op.last_reply is not None and op.last_reply.armed, 15)
            start = op.vehicle()
            op.set_velocity(0.5, 0.0, 0.0, 0.0)
            assert await until(lambda: op.vehicle().x_m > start.x_m + 0.5, 20), "the vehicle did not move"
            op.set_velocity(0.0, 0.0, 0.0, 0.0)
            assert await until(lambda: op.image_state()["serial"] >= serial + 2, 30), "no picture since"
            assert op.link_state()["reports"] > replies and op.world_state()["objects"] == []
            return node.objects.failed

    failed = asyncio.run(asyncio.wait_for(main(), 120))
    assert failed == "RuntimeError: bad frame"
    said = [r.getMessage() for r in caplog.records if "object detector stopped" in r.getMessage()]
    assert said == ["object detector stopped: RuntimeError: bad frame; the ROV goes on without objects"], said
