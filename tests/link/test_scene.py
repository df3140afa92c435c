"""What the ROV measured of the world on the wire (docs/PROTOCOL.md §11): the ALT byte, the
object records, the radio reply's annex (§11.1) with its vectors byte for byte, and what
both ends of a version 2 link do with them."""

from __future__ import annotations

import random
import re
from pathlib import Path

import pytest

from rovlink.link.radio.auth import OperatorChain, PollIn, RovChain
from rovlink.link.radio.events import AltitudeReported, ObjectRecordIgnored, ObjectRemoved, ObjectReported
from rovlink.link.radio.master import Master
from rovlink.link.radio.messages import Mode, Reply
from rovlink.link.radio.secure import SecureMaster, SecureSlave, parse_reply
from rovlink.link.radio.slave import Slave
from rovlink.link.radio.wire2 import (
    NO_CONTINUATION,
    continuation_of,
    poll_from_wire,
    pose_of,
    reply_to_wire,
    wish_of,
)
from rovlink.link.scene import (
    OP_CHANGED,
    OP_NEW,
    OP_REMOVED,
    ObjectRecord,
    SceneOutbox,
    altitude_code,
    altitude_from_code,
    decode_records,
)

from . import test_auth

DOC = Path(__file__).resolve().parents[2] / "docs" / "PROTOCOL.md"
AMPHORA = ObjectRecord.from_si(OP_NEW, 7, "amphora", 0.85, 4.0, 2.05, 0.9, 0.32, 35.2)
RESERVED_CLASS = ObjectRecord(OP_NEW, 8, 6, 3, 80, 41, 18, 16, 50)
REMOVED = ObjectRecord(OP_REMOVED, 7)
# §11.3's records, and the radio's annex vectors (§11.1) chained to §8's SYNC.
RECORDS = [("new amphora", AMPHORA, "4e 07 00 50 00 29 12 10 32"),
           ("removed", REMOVED, "c0 07"),
           ("reserved class 6 (out of range)", RESERVED_CLASS, "73 08 00 50 00 29 12 10 32")]
ANNEX_REPLY11 = Reply(mode=Mode.MANUAL, autopilot=True, position_valid=True, attitude_valid=True).encode()
V2_FRAMES = ["55 0d 21 00 00 41 32 00 ec 0a 00 78 48 6e 1b",
             "55 16 01 b7 00 00 00 00 00 00 40 4e 07 00 50 00 29 12 10 32 15 4c 11 4a",
             "55 16 01 b7 00 00 00 00 00 00 40 73 08 00 50 00 29 12 10 32 a8 c9 fb c5"]


def test_the_altitude_byte_has_fine_steps_near_the_seabed_and_coarse_ones_far():
    assert altitude_code(None) == 0 and altitude_from_code(0) is None
    assert altitude_code(3.2) == 64 and altitude_from_code(64) == 3.2
    assert altitude_code(0.01) == 1  # measured, however close: never "unknown"
    assert altitude_code(10.0) == 200 and altitude_code(10.5) == 201 and altitude_from_code(201) == 10.5
    assert altitude_code(37.0) == 254 and altitude_from_code(254) == 37.0
    assert altitude_code(80.0) == 255 and altitude_from_code(255) is None
    for metres in (0.3, 2.47, 9.99, 15.2, 30.0):
        back = altitude_from_code(altitude_code(metres))
        assert abs(back - metres) <= (0.025 if metres < 10 else 0.25) + 1e-9


@pytest.mark.parametrize("what,record,wire", RECORDS, ids=[r[0] for r in RECORDS])
def test_the_records_byte_for_byte_both_ways(what, record, wire):
    assert record.encode().hex(" ") == wire
    records, dropped = decode_records(bytes.fromhex(wire))
    if record.out_of_range():
        assert records == [] and dropped == 1
    else:
        assert records == [record] and dropped == 0


def test_a_record_in_si_rounds_to_its_steps():
    assert (AMPHORA.north_m, AMPHORA.east_m, AMPHORA.length_m, round(AMPHORA.width_m, 2)) == (4.0, 2.05, 0.9, 0.32)
    assert AMPHORA.class_name == "amphora" and AMPHORA.confidence_fraction == 7 / 8
    assert abs(AMPHORA.heading_deg - 35.2) < 180 / 512
    # The long axis has no front: 215.2 degrees is the same axis as 35.2.
    assert ObjectRecord.from_si(OP_NEW, 7, "amphora", 0.85, 4.0, 2.05, 0.9, 0.32, 215.2) == AMPHORA


def test_out_of_range_records_are_counted_and_ignored_and_a_cut_one_is_a_fault():
    zero_length = ObjectRecord(OP_CHANGED, 9, 2, 0, 0, 0, 0, 10, 0)
    too_wide = ObjectRecord(OP_CHANGED, 10, 2, 0, 0, 0, 10, 100, 0)  # 2.0 m wide, 0.5 m long
    data = RESERVED_CLASS.encode() + zero_length.encode() + AMPHORA.encode() + too_wide.encode()
    assert decode_records(data) == ([AMPHORA], 3)
    with pytest.raises(ValueError):
        decode_records(AMPHORA.encode()[:-1])
    assert decode_records(AMPHORA.encode() + bytes(3), padded=True) == ([AMPHORA], 0)


def _doc_rows() -> list[list[str]]:
    text = DOC.read_text(encoding="utf-8")
    start = text.index("\n## 11.")
    end = text.find("\n## ", start + 1)
    rows = []
    for line in text[start:end if end > 0 else None].splitlines():
        cells = [c.strip().strip("`").replace("  ", " ") for c in line.strip().strip("|").split("|")]
        if len(cells) >= 2 and re.fullmatch(r"[0-9a-f]{2}( [0-9a-f]{2})+", cells[1]):
            rows.append(cells)
    return rows


def test_section_11_prints_exactly_the_vectors_the_tests_check():
    from . import test_acoustic_scene

    printed = [row[1] for row in _doc_rows()]
    assert printed == [w for _, _, w in RECORDS] + V2_FRAMES + test_acoustic_scene.FRAMES


def test_the_annex_vectors_chained_to_section_8s_sync():
    """§8's SYNC, its first poll, and the reply to it with ALT 3.20 m and a new amphora; in
    place of that reply, the same with a record of a reserved class: authentic, taken,
    its record counted and ignored."""
    wire, contents, K = test_auth.wire, test_auth.contents, test_auth.K
    frames = []
    for record in (AMPHORA, RESERVED_CLASS):
        op = OperatorChain(K, count=0)
        rov = RovChain(K, boot=wire("12 34 56 78"), random_bytes=test_auth.scripted(wire("9a bc de f0 11 22 33 44")))
        hello = op.seal_hello(wire("40 1f ff"), 0.0, challenge=wire("01 02 03 04 05 06 07 08"))
        sync = rov.seal_sync(test_auth.SYNC_PAYLOAD, rov.check_poll(contents(hello), 0.0), 0.01,
                             info=(NO_CONTINUATION, pose_of(test_auth.SYNC_PAYLOAD), None))
        op.open_reply(contents(sync), 0.02)
        poll = op.seal_poll(contents(wire(test_auth.POLL))[:-5], 0.03)
        taken = rov.check_poll(contents(poll), 0.03)
        assert isinstance(taken, PollIn)
        continuation, pose, wish = taken.info
        poll11 = poll_from_wire(taken.payload, continuation, wish)
        rov.take(taken, 0.03)
        reply = rov.seal_reply(reply_to_wire(ANNEX_REPLY11, pose, altitude_code(3.2), record.encode()), taken, 0.03,
                               info=(continuation_of(ANNEX_REPLY11, poll11), pose_of(ANNEX_REPLY11), wish_of(poll11)))
        got = op.open_reply(contents(reply), 0.04, lambda p, s, a, poll11=poll11, pose=pose: parse_reply(p, poll11, pose))
        assert not got.malformed
        payload, _, _, alt, annex = got.parsed
        assert Reply.decode(payload) == Reply.decode(ANNEX_REPLY11) and alt == 64 and annex == record.encode()
        frames += [poll.hex(" "), reply.hex(" ")]
    assert frames[0] == frames[2] == test_auth.POLL
    assert [frames[0], frames[1], frames[3]] == V2_FRAMES


def _link(images: bool = True):
    master = SecureMaster(Master(rng=random.Random(1), images=images), test_auth.K)
    slave = SecureSlave(Slave(image_source=lambda img, settings: bytes(range(256)) * 8 if images else None),
                        test_auth.K)
    return master, slave


def _run(master, slave, cycles: int, t0: float = 0.0, lose=lambda n: False) -> tuple[list, float]:
    events, t = [], t0
    for n in range(cycles):
        poll = master.next_poll(t)
        if poll is None:
            t += 0.05
            continue
        out = slave.receive_bytes(poll, t + 0.01)
        if out.reply and not lose(n):
            events += master.receive_bytes(out.reply, t + 0.05)
        else:
            t = max(t, master.deadline() or t)
        events += master.take_events()
        t += 0.1
    return events, t


def test_the_altitude_and_objects_reach_the_operator_and_a_lost_reply_costs_no_record():
    master, slave = _link()
    slave.scene.altitude_m = 3.21
    records = [ObjectRecord.from_si(OP_NEW, i, "pipe", 0.9, i, -i, 4.0, 0.3, 70.0) for i in range(5)]
    for r in records:
        slave.scene.put(r)
    slave.scene.put(REMOVED)  # 7 was never told: nothing to take back
    events, t = _run(master, slave, 80, lose=lambda n: n % 3 == 2)  # one reply in three lost
    alts = [e for e in events if isinstance(e, AltitudeReported) and e.altitude_m is not None]
    assert alts and alts[0].altitude_m == 3.2
    seen = [e.obj.object_id for e in events if isinstance(e, ObjectReported)]
    assert sorted(set(seen)) == [0, 1, 2, 3, 4] and slave.scene.pending() == 0
    assert not [e for e in events if isinstance(e, ObjectRemoved)]
    # A removal of a told object goes; the altitude, unchanged, is told again every 2 s at most.
    slave.scene.put(ObjectRecord(OP_REMOVED, 3))
    more, t2 = _run(master, slave, 40, t)
    assert [e.object_id for e in more if isinstance(e, ObjectRemoved)] == [3]
    assert 1 <= len([e for e in more if isinstance(e, AltitudeReported)]) <= (t2 - t) / 2 + 1


def test_records_give_the_picture_at_most_one_reply_in_four_and_never_lengthen_a_cycle():
    master, slave = _link()
    for i in range(200):
        slave.scene.put(ObjectRecord.from_si(OP_NEW, i, "timber", 0.5, 0, 0, 2, 0.3, 0))
    cycles = []
    t = 0.0
    for _ in range(120):
        poll = master.next_poll(t)
        out = slave.receive_bytes(poll, t)
        size = master._last_size
        cap = master.master.reply_frame_bytes(size) + len(poll)
        cycles.append((len(poll) + len(out.reply), cap))
        master.receive_bytes(out.reply, t + 0.05)
        master.take_events()
        t += 0.5
    assert all(n <= cap for n, cap in cycles)  # the SIZE class's cap holds, annex and all
    sent = 200 - slave.scene.pending()
    assert 0 < sent <= 120 / 4 + 1


def test_a_rov_without_a_rangefinder_sends_no_altitude_byte():
    master, slave = _link(images=False)
    events, _ = _run(master, slave, 10)
    assert [e.code for e in events if isinstance(e, AltitudeReported)] == [0]  # the SYNC's: unknown


def test_a_record_out_of_range_in_a_reply_is_counted_and_ignored_the_reply_taken():
    master, slave = _link(images=False)
    slave.scene.put(RESERVED_CLASS)
    events, _ = _run(master, slave, 6)
    assert [type(e) for e in events if isinstance(e, (ObjectReported, ObjectRecordIgnored))] == [ObjectRecordIgnored]
    assert master.stats2.records_ignored == 1 and master.master.stats.protocol_errors == 0


def test_the_outbox_keeps_the_newest_record_per_object_and_a_change_to_an_untold_one_is_new():
    box = SceneOutbox()
    box.put(ObjectRecord.from_si(OP_NEW, 1, "pipe", 0.5, 0, 0, 3, 0.3, 0))
    box.put(ObjectRecord.from_si(OP_CHANGED, 1, "pipe", 0.9, 1, 0, 3, 0.3, 0))
    r = box.next_record()
    assert r.op == OP_NEW and r.north_m == 1.0 and box.pending() == 1
    box.delivered(r)
    box.put(ObjectRecord.from_si(OP_CHANGED, 1, "pipe", 0.9, 2, 0, 3, 0.3, 0))
    assert box.next_record().op == OP_CHANGED
    box.put(ObjectRecord(OP_REMOVED, 1))
    assert box.next_record() == ObjectRecord(OP_REMOVED, 1)


def test_the_vehicle_report_carries_the_altitude_and_the_seabed_depth_in_si():
    from rovlink.link.report import report_from_reply

    reply = Reply.decode(bytes.fromhex("01" + "00" * 4 + "01c2" + "00" * 6 + "b0"))  # 4.50 m deep
    report = report_from_reply(reply, arrived_at=1.0, frame_bytes=None, bitrate_bps=1900, delay_s=0.085,
                               altitude_m=altitude_from_code(64))
    assert report.altitude_m == 3.2 and abs(report.seabed_depth_m - 7.7) < 1e-9
    assert report_from_reply(reply, arrived_at=1.0, frame_bytes=None, bitrate_bps=1900,
                             delay_s=0.085).seabed_depth_m is None
