"""The ROI that follows its object (issue 34, docs/PROTOCOL.md §10): the tracker on the
simulated seabed against the true box, and the ROV node coding pictures with it over
UDP, driven by the real master."""

from __future__ import annotations

import asyncio
import math
import random
import time

import pytest

from rovlink import debt
from rovlink.link.aio import run_master
from rovlink.link.radio.master import ImageComplete, Master, OrderAcknowledged, OrderRejected
from rovlink.link.radio.messages import FollowSettings, ImageSettings, Poll, Reason, TrackState, split_track
from rovlink.link.transports.transport import free_udp_port
from rovlink.link.transports.urls import open_transport
from rovlink.rov.camera import SimulatedCamera, iou
from rovlink.rov.follow import TRACKERS, RoiFollower, TrackerMissing, make_tracker
from rovlink.rov.node import RovNode
from rovlink.rov.seabed import SEABED_DEPTH_M, Seabed

from .test_node import exchange, fake_node


@pytest.fixture(scope="module")
def camera():
    return SimulatedCamera()


@pytest.fixture(scope="module")
def ladder():
    return next(o for o in Seabed.load().objects if o.kind == "ladder")


def facing(obj, side_m=0.0, yaw_deg=0.0, back_m=4.3):
    """A pose 3 m above the seabed, back_m behind the object (north-facing), side_m to its east."""
    return (obj.x_m - back_m, obj.y_m + side_m, SEABED_DEPTH_M - 3.0, math.radians(yaw_deg))


def box_of(camera, pose, obj):
    return tuple(int(round(v)) for v in camera.object_box(pose, obj).clipped)


@pytest.mark.parametrize("tracker", ["klt"])
def test_the_follower_keeps_the_roi_on_the_object_as_the_vehicle_passes_and_turns(camera, ladder, tracker):
    follower = RoiFollower(tracker)
    start = facing(ladder, side_m=-2.0)
    follower.start(camera.capture(start), box_of(camera, start, ladder), keep=True, now=0.0)
    t, poses = 0.0, []
    for i in range(1, 41):  # 4 s at 10 Hz: 2 m east, then turning right: the ladder slides left
        poses.append(facing(ladder, side_m=-2.0 + 0.05 * min(i, 30), yaw_deg=1.5 * max(i - 30, 0)))
    for pose in poses:
        t += 0.1
        follower.frame(camera.capture(pose), t)
        roi, record = follower.picture(t)
        truth = camera.object_box(pose, ladder)
        assert record.state == TrackState.HOLDS and record.lost_for_ds == 0
        assert iou(roi, truth.clipped) >= 0.5, (tracker, pose, roi, truth.clipped)
    first, last = box_of(camera, start, ladder), box_of(camera, poses[-1], ladder)
    assert abs((first[0] + first[2]) / 2 - (last[0] + last[2]) / 2) > 40  # the object did cross the picture
    assert follower.stats.frames == 40 and follower.stats.mean_ms > 0


@pytest.mark.parametrize("keep", [True, False])
def test_a_track_is_lost_when_the_object_leaves_the_picture_then_dropped(camera, ladder, keep):
    follower = RoiFollower("klt", drop_after_s=2.0)
    start = facing(ladder)
    follower.start(camera.capture(start), box_of(camera, start, ladder), keep=keep, now=0.0)
    t, left_view_at, said_lost_at, last_held = 0.0, None, None, None
    for i in range(1, 80):  # turning right at 30 deg/s: the ladder leaves on the left
        t = i * 0.1
        pose = facing(ladder, yaw_deg=3.0 * i)
        follower.frame(camera.capture(pose), t)
        roi, record = follower.picture(t)
        if left_view_at is None and not camera.object_box(pose, ladder).in_view:
            left_view_at = t
        if record.state == TrackState.HOLDS:
            last_held = roi
        elif said_lost_at is None:
            said_lost_at = t
            assert record.state == TrackState.LOST and record.keep == keep
            assert roi == (last_held if keep else None)
    assert left_view_at is not None and said_lost_at is not None
    assert abs(said_lost_at - left_view_at) <= 0.5  # within five frames of the truth
    roi, record = follower.picture(t)
    assert record.state == TrackState.DROPPED and record.lost_for_s == pytest.approx(t - said_lost_at, abs=0.1)
    assert roi == (last_held if keep else None)


def test_every_named_tracker_is_made_and_an_unknown_one_is_refused():
    for name in TRACKERS:
        assert hasattr(make_tracker(name), "update")
    with pytest.raises(ValueError, match="unknown tracker"):
        make_tracker("sonar")


def test_without_opencv_the_follower_names_the_missing_extra(monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_cv2(name, *args, **kwargs):
        if name == "cv2":
            raise ImportError("No module named 'cv2'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_cv2)
    with pytest.raises(TrackerMissing, match=r"'tracking' extra \(opencv-contrib-python-headless\)"):
        RoiFollower()


def test_a_rov_without_a_tracker_rejects_follow_as_impossible_and_keeps_its_settings():
    node, _ = fake_node()
    before = node.slave.settings
    reply, _ = exchange(node, Poll(seq=1, order=FollowSettings((10, 10, 50, 50), 4, budget_bytes=900)), 0.0)
    assert reply.ack == 1 and reply.rejected and reply.rejection == Reason.IMPOSSIBLE
    assert node.slave.settings == before
    reply, _ = exchange(node, Poll(seq=0, order=ImageSettings((10, 10, 50, 50), 4, budget_bytes=900)), 0.1)
    assert reply.ack == 0 and not reply.rejected  # a fixed ROI it takes as ever


class ScriptedCamera:
    """The simulated camera on a pose the test sets (the vehicle's own pose does not
    matter here: the picture is what moves)."""

    def __init__(self, camera, pose):
        self.camera = camera
        self.pose = pose

    def grab(self, snap):
        return self.camera.capture(self.pose)


def test_the_rov_codes_each_picture_with_the_followed_roi_and_says_when_the_track_is_lost(camera, ladder):
    from .test_node import FakeBridge

    async def scenario():
        scripted = ScriptedCamera(camera, facing(ladder, side_m=-2.0))
        pm, pr = free_udp_port(), free_udp_port()
        master_ep = open_transport(f"udp://127.0.0.1:{pm}?peer=127.0.0.1:{pr}")
        rov_ep = open_transport(f"udp://127.0.0.1:{pr}?peer=127.0.0.1:{pm}")
        await master_ep.start()
        await rov_ep.start()
        bridge = FakeBridge()
        node = RovNode(rov_ep, bridge, scripted.grab, follower=RoiFollower("klt"), camera_hz=20.0, prefetch=False)
        master = Master(bitrate_bps=200_000, delay_s=0.0, margin_s=0.3, rng=random.Random(1))
        pictures, acks, rejected = [], [], []

        def on_master(events, now):
            for e in events:
                if isinstance(e, ImageComplete):
                    track, stream = split_track(e.data)
                    pictures.append((e.img, track, debt.unpack_header(stream).roi))
                elif isinstance(e, OrderAcknowledged):
                    acks.append(e.order)
                elif isinstance(e, OrderRejected):
                    rejected.append(e)

        tasks = [asyncio.create_task(node.run()), asyncio.create_task(run_master(master, master_ep, on_master))]

        async def until(predicate, timeout_s=30.0):
            for _ in range(int(timeout_s / 0.05)):
                if predicate():
                    return True
                await asyncio.sleep(0.05)
            return False

        try:
            master.send_order(ImageSettings(None, 0, budget_bytes=600))
            assert await until(lambda: len(pictures) >= 2)
            drawn_on = pictures[-1][0]
            roi = box_of(camera, scripted.pose, ladder)
            master.send_order(FollowSettings(roi, 6, budget_bytes=600, keep=False, drawn_on=drawn_on))
            assert await until(lambda: acks)
            seen = len(pictures)
            # The vehicle sways 2 m east over 2 s: the ladder slides left across the picture.
            for i in range(1, 21):
                scripted.pose = facing(ladder, side_m=-2.0 + 0.1 * i)
                await asyncio.sleep(0.1)
            # Pictures come faster than camera frames on this fast link: wait for a frame of the last pose.
            moved_at = time.monotonic()
            assert await until(lambda: (node.last_frame_at or 0) > moved_at)
            seen = len(pictures)
            assert await until(lambda: len(pictures) >= seen + 2)
            img, track, coded_roi = pictures[-1]
            assert track is not None and track.state == TrackState.HOLDS and not track.keep
            assert iou(coded_roi, camera.object_box(scripted.pose, ladder).clipped) >= 0.5
            assert (coded_roi[0] + coded_roi[2]) / 2 < (roi[0] + roi[2]) / 2 - 40  # it moved with the ladder
            # Turned away: the ladder leaves the picture, and the next picture says so, without an ROI.
            for i in range(1, 16):
                scripted.pose = facing(ladder, side_m=0.0, yaw_deg=6.0 * i)
                await asyncio.sleep(0.05)
            # Pictures come faster than camera frames on this fast link: once the ROV's camera
            # has seen the ladder go, the pictures captured from then on say so.
            assert await until(lambda: node.follower.state == TrackState.LOST)
            seen = len(pictures)
            assert await until(lambda: len(pictures) >= seen + 2)
            img, track, coded_roi = pictures[-1]
            assert track.state == TrackState.LOST and track.lost_for_ds > 0 and coded_roi is None
            # A plain IMAGE order ends the following: no TRACK record any more.
            master.send_order(ImageSettings((10, 10, 60, 60), 4, budget_bytes=600))
            assert await until(lambda: len(acks) >= 2)
            seen = len(pictures)
            assert await until(lambda: len(pictures) >= seen + 2)
            assert pictures[-1][1] is None and pictures[-1][2] == (10, 10, 60, 60)
            assert not rejected
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            await master_ep.close()
            await rov_ep.close()

    asyncio.run(asyncio.wait_for(scenario(), 90))



def test_the_acoustic_rov_follows_between_thumbnails_and_its_thumbnail_says_the_track(camera, ladder):
    """Issue 34 over the acoustic profile (§9.3, §10): the ROI drawn on one thumbnail is
    tracked in every camera frame kept since, each followed thumbnail is coded where the
    object is then and says the track; the same request again goes on with the track."""
    from rovlink.link import acoustic as ac
    from rovlink.rov.acoustic import FOLLOW_SIZE, THUMB_SIZE, AcousticNode

    from .test_node import FakeBridge

    scripted = ScriptedCamera(camera, facing(ladder, side_m=-2.0))
    node = AcousticNode(None, FakeBridge(), scripted.grab, bytes(range(32)), follower=RoiFollower("klt"))
    assert node.machine.follows
    scale = THUMB_SIZE[0] / camera.width
    clock = [100.0]

    def frames(poses):
        for pose in poses:
            scripted.pose = pose
            clock[0] += 0.1
            node.camera.take_frame(camera.capture(pose), clock[0])

    def ask(oid, **follow):
        obj = node.thumbnail_object(oid, ac.ThumbRequest(oid, budget=120, shift=4, **follow), None)
        assert int.from_bytes(obj[:2], "big") == len(obj) - 2
        track, stream = split_track(obj[2:])
        return track, debt.unpack_header(stream).roi, len(stream)

    def true_box():
        b = camera.object_box(scripted.pose, ladder).clipped
        return tuple(v * scale for v in b)

    frames([scripted.pose] * 3)
    track, roi, _ = ask(1)
    assert track is None and roi is None  # a plain thumbnail: no record
    drawn = tuple(int(round(v)) for v in true_box())  # the pilot drags it on thumbnail 1
    # The vehicle sways 2 m east over 2 s, before the pilot's FOLLOW reaches it: the ROV catches up.
    frames([facing(ladder, side_m=-2.0 + 0.1 * i) for i in range(1, 21)])
    track, roi, size = ask(3, roi=drawn, follow=True, keep=False, drawn_on=1)
    assert track is not None and track.state == TrackState.HOLDS and not track.keep
    assert size <= 120 - 2  # BUDGET counts the TRACK record
    assert iou(roi, true_box()) >= 0.5
    assert (roi[0] + roi[2]) / 2 < (drawn[0] + drawn[2]) / 2 - 8  # it moved left with the ladder (80 px wide)
    started = sum("FOLLOW from picture" in line for line in node.log)
    # A minute later, the same request again: the ROV goes on with its track (no new start).
    frames([facing(ladder, side_m=0.1 * i) for i in range(0, 11)])
    track, roi, _ = ask(5, roi=drawn, follow=True, keep=True, drawn_on=1)
    assert track.state == TrackState.HOLDS and track.keep and iou(roi, true_box()) >= 0.5
    assert sum("FOLLOW from picture" in line for line in node.log) == started == 1
    # Turned away: the ladder leaves the view; the next thumbnail says the track is lost.
    frames([facing(ladder, side_m=1.0, yaw_deg=6.0 * i) for i in range(1, 16)])
    track, roi, _ = ask(7, roi=drawn, follow=True, keep=False, drawn_on=1)
    assert track.state == TrackState.LOST and track.lost_for_ds > 0 and roi is None
    # A thumbnail without FOLLOW ends the following: no record, the ROI as asked.
    track, roi, _ = ask(9, roi=(10, 10, 30, 30))
    assert track is None and roi == (10, 10, 30, 30) and not node.camera.follower.active
    assert FOLLOW_SIZE[0] == 4 * THUMB_SIZE[0]
