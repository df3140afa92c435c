"""FOLLOW and the TRACK record (docs/PROTOCOL.md §10): §10's vectors byte for byte, both
ways, in version 1.1 and version 2; what the ROV's slave does with the order; the
operator's side reading a followed picture."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from rovlink.link.radio.frame import FrameDecoder, encode_frame
from rovlink.link.radio.master import ImageComplete, ImageProgress, Master
from rovlink.link.radio.messages import (
    FollowSettings,
    ImageSettings,
    InvalidOrder,
    Mode,
    Poll,
    ProtocolError,
    Reason,
    Reply,
    ReservedOrder,
    TrackRecord,
    TrackState,
    split_track,
)
from rovlink.link.radio.slave import OrderDeclined, OrderExecuted, Slave

from . import test_auth

DOC = Path(__file__).resolve().parents[2] / "docs" / "PROTOCOL.md"
FOLLOW = FollowSettings((100, 60, 160, 120), 6, False, 1000, keep=True, drawn_on=2)
FOLLOW_POLL = Poll(seq=1, size=0, order=FOLLOW, img=3, offset=8191)
NO_TRACKER = Reply(ack=1, mode=Mode.MANUAL, autopilot=True, rejected=True, reason=Reason.IMPOSSIBLE)
LOST_34 = TrackRecord(TrackState.LOST, True, 34)
# (what, message, its frame) of §10's table, version 1.1
VECTORS = [
    ("follow", FOLLOW_POLL, "55 0c 85 7f ff 19 03 c2 80 78 60 03 e8 82 73 27"),
    ("no keep", Poll(seq=1, size=0, order=FollowSettings((100, 60, 160, 120), 6, False, 1000, keep=False, drawn_on=2),
                     img=3, offset=8191), "55 0c 85 7f ff 19 03 c2 80 78 60 03 e8 02 e2 af"),
    ("no tracker", NO_TRACKER, "55 0e 21 00 00 00 00 00 00 00 00 00 00 00 00 8a 69 81"),
    ("track", Reply(ack=1, mode=Mode.MANUAL, autopilot=True, img=3, offset=0, trunk=bytes.fromhex("03e8") + LOST_34.encode()),
     "55 14 a1 00 00 00 00 00 00 00 00 00 00 00 00 80 60 00 03 e8 66 22 94 40"),
]
V2_FRAMES = ["55 11 85 7f ff 19 03 c2 80 78 60 03 e8 82 00 ab 23 66 32", "55 0c 21 8b 00 00 00 00 00 00 f1 b4 7f d2"]
V2_CHAINS = ["ab236632299f94ab97319529d12adcb5cb99e202157e471cca4097c40347db58",
             "f1b47fd2ae2cb40e306b11a5dee1de492e8e3423a942d63227719d47650c51f1"]


def _section_10_rows() -> list[list[str]]:
    text = DOC.read_text(encoding="utf-8")
    start = text.index("\n## 10.")
    section = text[start:text.find("\n## ", start + 1)]
    rows = []
    for line in section.splitlines():
        cells = [c.strip().strip("`") for c in line.strip().strip("|").split("|")]
        if len(cells) >= 3 and re.fullmatch(r"55( [0-9a-f]{2})+", cells[1]):
            rows.append(cells)
    return rows


def test_section_10_prints_exactly_the_vectors_the_tests_check():
    rows = _section_10_rows()
    assert [r[1] for r in rows] == [wire for _, _, wire in VECTORS] + V2_FRAMES
    assert [r[2] for r in rows if r[2] != "—"] == V2_CHAINS


@pytest.mark.parametrize("what,message,wire", VECTORS, ids=[v[0] for v in VECTORS])
def test_the_section_10_vectors_byte_for_byte_both_ways(what, message, wire):
    assert encode_frame(message.encode()).hex(" ") == wire
    (payload,) = FrameDecoder().feed(bytes.fromhex(wire.replace(" ", "")))
    assert type(message).decode(payload) == message


def test_the_section_10_vectors_in_version_2():
    """The FOLLOW poll chained to §8's SYNC, and the reply of a ROV without a tracker."""
    from rovlink.link.radio.auth import OperatorChain, PollIn, RovChain
    from rovlink.link.radio.wire2 import (
        NO_CONTINUATION,
        continuation_of,
        poll_from_wire,
        poll_to_wire,
        pose_of,
        reply_from_wire,
        reply_to_wire,
        request_of,
        wish_of,
    )

    wire, contents, K = test_auth.wire, test_auth.contents, test_auth.K
    op = OperatorChain(K, count=0)
    rov = RovChain(K, boot=wire("12 34 56 78"), random_bytes=test_auth.scripted(wire("9a bc de f0 11 22 33 44")))
    hello = op.seal_hello(wire("40 1f ff"), 0.0, challenge=wire("01 02 03 04 05 06 07 08"))
    got = rov.check_poll(contents(hello), 0.0)
    sync = rov.seal_sync(test_auth.SYNC_PAYLOAD, got, 0.01, info=(NO_CONTINUATION, pose_of(test_auth.SYNC_PAYLOAD), None))
    assert sync.hex(" ") == test_auth.SYNC
    op.open_reply(contents(sync), 0.02)
    poll11, reply11 = FOLLOW_POLL.encode(), NO_TRACKER.encode()
    poll = op.seal_poll(poll_to_wire(poll11, NO_CONTINUATION), 0.03)
    taken = rov.check_poll(contents(poll), 0.03)
    assert isinstance(taken, PollIn)
    continuation, pose, wish = taken.info
    assert Poll.decode(poll_from_wire(taken.payload, continuation, wish)) == FOLLOW_POLL
    rov.take(taken, 0.03)
    reply = rov.seal_reply(reply_to_wire(reply11, pose), taken, 0.03,
                           info=(continuation_of(reply11, poll11), pose_of(reply11), wish_of(poll11)))
    answer = op.open_reply(contents(reply), 0.04)
    back, _ = reply_from_wire(answer.payload, request_of(poll11), pose_of(test_auth.SYNC_PAYLOAD))
    assert Reply.decode(back) == NO_TRACKER
    assert [poll.hex(" "), reply.hex(" ")] == V2_FRAMES
    assert [taken.chain.hex(), op.chain_to.hex()] == V2_CHAINS


def test_follow_without_an_roi_is_invalid_and_reserved_bits_are_a_structural_fault():
    body = FOLLOW.encode_body()
    no_roi = bytes(5) + body[5:]
    assert isinstance(FollowSettings.decode_body(no_roi), InvalidOrder)
    with pytest.raises(ProtocolError, match="reserved"):
        FollowSettings.decode_body(body[:8] + bytes([body[8] | 0x08]))
    with pytest.raises(ProtocolError):
        FollowSettings(None, 6)
    with pytest.raises(ProtocolError):
        ReservedOrder(5)  # 5 is FOLLOW now


def test_the_slave_takes_follow_only_when_its_rov_tracks():
    plain = Slave()
    out = plain.receive(FOLLOW_POLL.encode(), 0.0)
    reply = Reply.decode(FrameDecoder().feed(out.reply)[0])
    assert reply.ack == 1 and reply.rejection == Reason.IMPOSSIBLE
    assert [type(e) for e in out.events if isinstance(e, OrderDeclined)] == [OrderDeclined]
    assert not plain.settings.follow
    tracking = Slave()
    tracking.follows = True
    out = tracking.receive(FOLLOW_POLL.encode(), 0.0)
    assert Reply.decode(FrameDecoder().feed(out.reply)[0]).rejected is False
    assert any(isinstance(e, OrderExecuted) and e.order == FOLLOW for e in out.events)
    assert tracking.settings == FOLLOW and tracking.settings.follow
    out = tracking.receive(Poll(seq=0, order=ImageSettings((1, 1, 9, 9), 4)).encode(), 0.1)
    assert not tracking.settings.follow  # IMAGE ends the following


def test_a_track_record_is_told_from_a_debt_header_and_kept_out_of_the_stream():
    import numpy as np

    from rovlink import debt

    stream = debt.encode(np.full((32, 32), 90, np.uint8), 60)
    assert split_track(stream) == (None, stream)
    assert split_track(LOST_34.encode() + stream) == (LOST_34, stream)
    assert split_track(bytes([0x61, 0])) == (None, bytes([0x61, 0]))  # its reserved bit set: not a record
    assert split_track(bytes([0x64])) == (None, bytes([0x64]))  # cut short
    for state in TrackState:
        for keep in (False, True):
            record = TrackRecord(state, keep, 255)
            assert TrackRecord.decode(record.encode()) == record
    assert TrackRecord(TrackState.LOST, True, 34).lost_for_s == pytest.approx(3.4)


def test_the_operator_gets_each_followed_picture_with_its_track_and_decodes_it():
    """The record rides in the object like any stream bytes: the master's pictures carry it,
    and split_track parts it from the DEBT stream before decoding."""
    import numpy as np

    from rovlink import debt

    picture = debt.encode(np.tile(np.arange(64, dtype=np.uint8), (48, 1)), 200, roi=(8, 8, 40, 40), shift=6)
    record = TrackRecord(TrackState.HOLDS, False, 0)
    slave = Slave(image_source=lambda img, settings: record.encode() + picture)
    master = Master(bitrate_bps=200_000, delay_s=0.0)
    events = []
    for i in range(40):
        frame = master.next_poll(i * 0.1)
        events += master.take_events()
        if frame:
            out = slave.receive_bytes(frame, i * 0.1)
            if out.reply:
                events += master.receive_bytes(out.reply, i * 0.1 + 0.01)
    done = [e for e in events if isinstance(e, ImageComplete)]
    assert done and all(split_track(e.data) == (record, picture) for e in done)
    assert debt.unpack_header(split_track(done[-1].data)[1]).roi == (8, 8, 40, 40)
    first = next(e for e in events if isinstance(e, ImageProgress))
    assert split_track(first.prefix)[0] == record  # said with the first trunk
