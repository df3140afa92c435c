"""The acoustic profile's SCENE frame (docs/PROTOCOL.md §11.2): its vectors byte for byte at
both ends, its place in the ROV's schedule, and records out of range counted and ignored."""

from __future__ import annotations

from rovlink.link import acoustic as ac
from rovlink.link.acoustic.sim import AcousticSim
from rovlink.link.scene import OP_NEW, OP_REMOVED, ObjectRecord, SeenObject

from .test_acoustic import BOOT, CHALLENGE, NONCE, STATUS0, K, _down, _feeder, _up
from .test_scene import AMPHORA, RESERVED_CLASS

SCENE_BODY = bytes((64,)) + AMPHORA.encode() + ObjectRecord(OP_REMOVED, 5).encode()  # 3.20 m, amphora 7, 5 gone
IGNORED_BODY = bytes((0,)) + RESERVED_CLASS.encode() + bytes(2)  # altitude unknown; a reserved class; padding
FRAMES = [_down(1, ac.DOWN_SCENE, SCENE_BODY).hex(" "), _down(2, ac.DOWN_SCENE, IGNORED_BODY).hex(" ")]


def _session() -> tuple[ac.AcousticRov, ac.AcousticOperator]:
    """A ROV and an operator in §9's session, the ROV's STATUS 0 taken."""
    rov = ac.AcousticRov(K, boot=BOOT, random_bytes=_feeder([NONCE]))
    op = ac.AcousticOperator(K, random_bytes=_feeder([CHALLENGE]))
    rov.receive(op.next_packet(0.0), 1.0)
    sync = rov.next_packet(1.0) + rov.next_packet(2.0)
    op.receive(sync[:8], 3.0)
    op.receive(sync[8:], 3.5)
    rov.receive(_up(0, ac.UP_POLL, ac.PollBody().encode()), 5.0)
    return rov, op


def test_the_rov_makes_the_scene_vector_after_its_status_and_the_operator_takes_it():
    rov, op = _session()
    rov.update_status(ac.VehicleState(12.5, -3.0, 4.5, 90.0, armed=True, mode=4, position_valid=True,
                                      attitude_valid=True, autopilot=True, battery_v=15.8))
    rov.scene.altitude_m = 3.2
    rov.scene.put(AMPHORA)
    rov.scene.delivered(ObjectRecord.from_si(OP_NEW, 5, "pipe", 0.5, 1, 1, 3, 0.3, 0))  # told before
    rov.scene.put(ObjectRecord(OP_REMOVED, 5))
    status = rov.next_packet(5.0) + rov.next_packet(6.0)  # the STATUS the POLL asked for goes first
    assert status == _down(0, ac.DOWN_STATUS, STATUS0.encode())
    scene = rov.next_packet(7.0) + rov.next_packet(8.0)
    assert scene.hex(" ") == FRAMES[0]
    events = op.receive(status[:8], 9.0) + op.receive(status[8:], 9.5)
    events = op.receive(scene[:8], 10.0) + op.receive(scene[8:], 11.0)
    made = 11.0 - ac.STATUS_TRANSIT_S
    assert events == [ac.SceneAltitude(3.2, made, 64),
                      ac.SceneObjectReported(SeenObject.from_record(AMPHORA), made, 9),
                      ac.SceneObjectRemoved(5, made)]
    assert rov.scene.pending() == 0 and rov.counters.scenes == 1


def test_a_record_out_of_range_in_a_scene_is_counted_and_ignored():
    _, op = _session()
    frame = bytes.fromhex(FRAMES[1])
    events = op.receive(frame[:8], 10.0) + op.receive(frame[8:], 11.0)
    assert [type(e) for e in events] == [ac.SceneAltitude, ac.SceneRecordIgnored]
    assert events[0].altitude_m is None and op.counters.records_ignored == 1 and op.counters.inauthentic == 0


def test_objects_come_after_the_status_and_ahead_of_the_thumbnail_and_an_unchanged_altitude_is_quiet():
    sim = AcousticSim(seed=3)
    sim.rov.scene.altitude_m = 2.5
    sim.at(20.0, lambda t: [sim.rov.scene.put(ObjectRecord.from_si(OP_NEW, i, "amphora", 0.9, i, 0, 0.9, 0.3, 0))
                            for i in range(4)])
    sim.at(15.0, lambda t: sim.order(ac.ThumbRequest(0, budget=198)))
    sim.run_until(120.0)
    seen = sim.events(ac.SceneObjectReported)
    assert sorted({e.obj.object_id for _, e in seen}) == [0, 1, 2, 3]
    first_object = min(t for t, _ in seen)
    assert first_object - 20.0 <= 20.0  # the target: an object in the scene within 20 s
    done = sim.events(ac.ThumbnailComplete)
    assert done and first_object < done[0][0]  # ahead of the thumbnail asked for before them
    alts = sim.events(ac.SceneAltitude)
    assert alts[0][1].altitude_m == 2.5
    # Told with each SCENE of records (4), else when it moved or every 20 s: never a stream of them.
    assert len(alts) <= 4 + 120 / 20 + 1
