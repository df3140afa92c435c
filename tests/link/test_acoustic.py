"""The acoustic profile (docs/PROTOCOL.md §9): its vectors byte for byte at both
ends, and sessions over the emulated Modem-M64 in simulated time."""

from __future__ import annotations

import random
import re
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rovlink.link import acoustic as ac
from rovlink.link.acoustic.sim import AcousticSim, fixed_camera
from rovlink.link.acoustic.wire import R_INVALID
from rovlink.link.radio.messages import Mode

DOC = Path(__file__).resolve().parents[2] / "docs" / "PROTOCOL.md"
K = bytes(range(32))
CHALLENGE = bytes.fromhex("01020304")
BOOT = bytes.fromhex("12345678")
NONCE = bytes.fromhex("9abcdef0")
S = CHALLENGE + BOOT + NONCE
OBJECT = bytes.fromhex("00056162636465")  # [N = 5] "abcde"


def _up(ctr, kind, body):
    return b"".join(ac.seal_control(K, ac.LABEL_UP, S, ctr, kind, body))


def _down(ctr, kind, body):
    return b"".join(ac.seal_control(K, ac.LABEL_DOWN, S, ctr, kind, body))


STATUS0 = ac.StatusBody(x_dm=125, y_dm=-30, z_dm=45, heading_cdeg=9000, armed=True, hold=True, position_valid=True,
                    attitude_valid=True, autopilot=True, uplink=True, mode=Mode.POS_HOLD, battery_dv=158)
STATUS17 = ac.StatusBody(hold=True, autopilot=True, uplink=True, mode=Mode.POS_HOLD, result=ac.R_DONE, stop_no2=1, oid=3)
STATUS18 = ac.StatusBody(armed=True, hold=True, autopilot=True, uplink=True, mode=Mode.POS_HOLD, result=ac.R_DONE,
                     stop_no2=1, oid=3)  # STATUS17 and ARMED: a STATUS_SAME says it
GOTO = ac.GoToBody(2, 125, -30, 45, -9000, yaw_set=True)
THUMB = ac.ThumbRequest(3, budget=198, roi=(20, 15, 60, 45), shift=4, mono=True)
FOLLOW = ac.ThumbRequest(5, budget=198, roi=(20, 15, 60, 45), shift=4, mono=True, follow=True, keep=True, drawn_on=3)
FOLLOWED_OBJECT = bytes.fromhex("00056622616263")  # [N = 5] TRACK lost, KEEP, 3.4 s; "abc"


def vectors() -> list[bytes]:
    """§9's table, in its order."""
    return [
        ac.seal_hello(K, CHALLENGE),
        b"".join(ac.seal_sync(K, CHALLENGE, ac.SyncBody(BOOT, NONCE, 60, ac.FAILSAFE_HOLD))),
        _down(0, ac.DOWN_STATUS, STATUS0.encode()),
        _up(0, ac.UP_POLL, ac.PollBody(1, 3, False, 0b011 << 16, have_status=True, held=0).encode()),
        _up(1, ac.UP_ORDER, ac.OrderBody(1, ac.OP_ARM).encode()),
        _up(2, ac.UP_GOTO, GOTO.encode()),
        _up(3, ac.UP_THUMB, THUMB.encode()),
        _up(4, ac.UP_STOP, ac.StopBody(1, 3).encode()),
        ac.data_packet(1, 0, OBJECT),
        _down(1, ac.DOWN_THUMB_END, ac.ThumbEnd(3, ac.object_mac(K, S, 3, OBJECT)).encode()),
        _down(17, ac.DOWN_STATUS, STATUS17.encode()),
        _down(18, ac.DOWN_STATUS_SAME, ac.same_body(17, STATUS18.encode())),
        _up(0, ac.UP_POLL, ac.PollBody().encode()),
        _up(5, ac.UP_THUMB, FOLLOW.encode()),
        ac.data_packet(1, 0, FOLLOWED_OBJECT),
    ]


def _doc_rows() -> list[str]:
    text = DOC.read_text(encoding="utf-8")
    start = text.index("\n## 9.")
    end = text.find("\n## ", start + 1)
    section = text[start:] if end < 0 else text[start:end]
    rows = []
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 2 and re.fullmatch(r"`[0-9a-f]{2}( [0-9a-f]{2}){7}(  [0-9a-f]{2}( [0-9a-f]{2}){7})?`", cells[1]):
            rows.append(cells[1].strip("`").replace("  ", " "))
    return rows


def _chunks(frame: bytes) -> list[bytes]:
    return [frame[i:i + 8] for i in range(0, len(frame), 8)]


def _feeder(values):
    it = iter(values)
    return lambda n: next(it)


# ---------------------------------------------------------------------------
# §9's vectors
# ---------------------------------------------------------------------------


def test_section_9_prints_exactly_the_vectors_the_code_makes():
    assert _doc_rows() == [v.hex(" ") for v in vectors()]


def test_the_rov_end_makes_and_takes_the_vectors():
    v = [bytes.fromhex(r) for r in _doc_rows()]
    rov = ac.AcousticRov(K, boot=BOOT, random_bytes=_feeder([NONCE]))
    rov.update_status(ac.VehicleState(12.5, -3.0, 4.5, 90.0, armed=True, mode=Mode.POS_HOLD, position_valid=True,
                                      attitude_valid=True, autopilot=True, battery_v=15.8))
    assert rov.tick(0.0) == [ac.StopWanted(None)]
    assert rov.receive(v[0], 1.0) == [ac.SessionStarted(CHALLENGE)]
    assert rov.wants_flush
    assert rov.next_packet(1.0) + rov.next_packet(2.0) == v[1]
    assert rov.next_packet(3.0) + rov.next_packet(4.0) == v[1]  # the SYNC again, until a frame of its session comes
    assert rov.receive(v[3], 5.0) == []
    assert rov.next_packet(5.0) + rov.next_packet(6.0) == v[2]
    assert rov.receive(v[4], 6.0) == [ac.ArmWanted(1)]
    rov.order_outcome(1, ac.R_DONE)
    events = []
    for i, p in enumerate(_chunks(v[5]) + _chunks(v[6])):
        events += rov.receive(p, 7.0 + i)
    assert events == [ac.GoToWanted(2, GOTO), ac.ThumbnailWanted(3, THUMB)]
    assert rov.receive(v[7], 11.0) == [ac.StopWanted(1, True)]
    assert rov.last_oid == 3 and rov.hold and rov.counters.frames_taken == 5


def test_the_operator_end_makes_and_takes_the_vectors():
    v = [bytes.fromhex(r) for r in _doc_rows()]
    op = ac.AcousticOperator(K, random_bytes=_feeder([CHALLENGE]))
    assert op.next_packet(0.0) == v[0]
    events = []
    for i, p in enumerate(_chunks(v[1]) + _chunks(v[2])):
        events += op.receive(p, 5.0 + i)
    assert events[0] == ac.SessionSynced(BOOT, False, 60, ac.FAILSAFE_HOLD)
    assert events[1] == ac.StatusReceived(STATUS0, 8.0 - ac.STATUS_TRANSIT_S, 0)
    poll = ac.PollBody(have_status=True, held=0)  # nothing wanted yet; it holds STATUS 0
    assert op.ready and op.next_packet(9.0) == _up(0, ac.UP_POLL, poll.encode())
    assert op.send_order(ac.OrderBody(0, ac.OP_ARM), 9.0) == 1
    assert op.next_packet(10.0) == v[4]
    # The operator's own THUMB request 3, and the ROV's answer from the table.
    op.thumb = ac.operator._Wanted(3)
    got = op.receive(v[8], 12.0) + op.receive(v[9], 13.0)
    assert got == [ac.ThumbnailProgress(3, OBJECT), ac.ThumbnailComplete(3, OBJECT)]
    assert op.rx_last == 1
    got = op.receive(v[10][:8], 14.0) + op.receive(v[10][8:], 15.0)  # frames 2..16 lost: 17 is in the window
    assert got == [ac.StatusReceived(STATUS17, 15.0 - ac.STATUS_TRANSIT_S, 17),
                   ac.OrderFate(1, "unknown", "the ROV moved past it before reporting it")]  # our ARM: passed by OID 3
    assert op.receive(v[11], 16.0) == [ac.StatusReceived(STATUS18, 16.0 - ac.SAME_TRANSIT_S, 18)]
    assert op.counters.inauthentic == 0 and op.counters.statuses_same == 1


# ---------------------------------------------------------------------------
# Packets
# ---------------------------------------------------------------------------

u8 = st.integers(0, 255)
i16 = st.integers(-32768, 32767)
BODIES = st.one_of(
    st.builds(ac.PollBody, st.integers(0, 1), st.integers(0, 63), st.booleans(), st.integers(0, 2**ac.BITMAP_BITS - 1),
              st.booleans(), st.integers(0, 15)),
    st.builds(ac.StopBody, u8, u8),
    st.builds(ac.OrderBody, u8, u8, st.integers(0, 65535)),
    st.builds(ac.GoToBody, u8, i16, i16, i16, i16, st.booleans(), st.booleans(), st.booleans()),
    st.builds(ac.ThumbRequest, u8, st.integers(0, 65535), st.tuples(u8, u8, u8, u8), st.integers(0, 15),
              st.booleans(), follow=st.booleans(), keep=st.booleans(), drawn_on=u8),
    st.builds(ac.StatusBody, i16, i16, i16, st.integers(0, 35999), *[st.booleans()] * 8, st.integers(0, 7),
              st.integers(0, 7), st.integers(0, 3), u8, u8),
    st.builds(ac.ThumbEnd, u8, st.binary(min_size=3, max_size=3)),
)
KINDS = {ac.PollBody: (ac.UP_POLL, True), ac.StopBody: (ac.UP_STOP, True), ac.OrderBody: (ac.UP_ORDER, True),
         ac.GoToBody: (ac.UP_GOTO, True), ac.ThumbRequest: (ac.UP_THUMB, True), ac.StatusBody: (ac.DOWN_STATUS, False),
         ac.ThumbEnd: (ac.DOWN_THUMB_END, False)}


@settings(max_examples=150, deadline=None)
@given(body=BODIES, ctr=st.integers(0, 40))
def test_every_control_kind_round_trips_through_the_receiving_machine(body, ctr):
    kind, up = KINDS[type(body)]
    raw = body.encode()
    assert len(raw) in (ac.SHORT_BODY, ac.LONG_BODY) and type(body).decode(raw) == body
    label = ac.LABEL_UP if up else ac.LABEL_DOWN
    packets = ac.seal_control(K, label, S, ctr, kind, raw)
    assert len(packets) == (ac.UP_PACKETS if up else ac.DOWN_PACKETS)[kind]
    end = ac.AcousticRov(K, boot=BOOT) if up else ac.AcousticOperator(K)
    end.session, end.rx_last = S, max(-1, ctr - 16)
    for p in packets:
        end.receive(p, 1.0)
    assert end.rx_last == ctr and end.counters.frames_taken == 1


@settings(max_examples=100, deadline=None)
@given(t=st.integers(0, 1), idx=st.integers(0, 62), chunk=st.binary(min_size=7, max_size=7))
def test_data_packets_round_trip(t, idx, chunk):
    p = ac.data_packet(t, idx, chunk)
    assert len(p) == 8 and any(p) and p[0] >> 6 & 1 == t and p[0] & 63 == idx and p[1:] == chunk


@settings(max_examples=200, deadline=None)
@given(junk=st.lists(st.binary(min_size=0, max_size=20), max_size=30))
def test_bad_packets_are_counted_and_ignored_never_a_crash(junk):
    rov, op = ac.AcousticRov(K, boot=BOOT), ac.AcousticOperator(K)
    op.thumb = ac.operator._Wanted(1)
    for end in (rov, op):
        end.session = S
        for i, p in enumerate(junk):
            end.receive(p, float(i))
        assert end.rx_last == -1 or end.counters.frames_taken  # nothing taken without a tag
        c = end.counters
        assert c.bad_size == sum(len(p) != 8 for p in junk)


def test_wrong_sizes_all_zero_and_garbage_are_counted():
    rov = ac.AcousticRov(K, boot=BOOT)
    rov.session = S
    for p in (b"", b"\x10" * 7, b"\x10" * 9, bytes(8), b"\x90" + bytes(7), b"\x70" + bytes(7), b"\x30garbage"[:8]):
        assert rov.receive(p, 0.0) == []
    c = rov.counters
    assert (c.bad_size, c.all_zero, c.bad_kind, c.inauthentic, c.frames_taken) == (3, 1, 2, 1, 0)


def test_no_packet_handed_to_the_modem_is_all_zero_or_of_another_size():
    sim = _synced(seed=3)
    sim.order(ac.ThumbRequest(0))
    sim.run_until(sim.now + 60)
    for side in "ab":
        assert sim.handed[side] and all(len(p) == 8 and any(p) for _, p in sim.handed[side])


# ---------------------------------------------------------------------------
# Sessions over the emulated M64
# ---------------------------------------------------------------------------


def _synced(seed=1, **kw) -> AcousticSim:
    kw.setdefault("camera", fixed_camera(200))
    sim = AcousticSim(K, seed=seed, **kw)
    while not sim.operator.ready:
        sim.run_until(sim.now + 1.0)
        assert sim.now < 120, "no session"
    return sim


def _fates(sim, oid):
    return [e.state for _, e in sim.events(ac.OrderFate) if e.oid == oid]


def test_a_goto_is_taken_flown_and_done_and_a_stop_is_confirmed():
    sim = _synced()
    oid = sim.order(ac.GoToBody(0, 50, 0, 0, relative=True))
    sim.run_until(sim.now + 40)
    assert _fates(sim, oid) == ["taken", "done"]
    assert abs(sim.vehicle.x - 5.0) < 1e-6
    assert [e for _, e in sim.events(ac.GoToWanted, "rov")] == [ac.GoToWanted(oid, ac.GoToBody(oid, 50, 0, 0, relative=True))]
    pressed = sim.now
    n = sim.stop()
    sim.run_until(sim.now + 15)
    (t, confirmed), = sim.events(ac.StopTaken)
    assert confirmed == ac.StopTaken(n, pressed) and t - pressed < 8.0
    assert sim.operator.ready


def test_stop_goes_first_ahead_of_an_order_and_a_thumbnail_under_way():
    sim = _synced(seed=2)
    sim.order(ac.ThumbRequest(0))
    sim.run_until(sim.now + 15)  # thumbnail data flowing
    assert sim.operator.thumb.slots
    oid = sim.order(ac.GoToBody(0, 300, 0, 0, relative=True))
    sim.run_until(sim.now + 0.3)
    assert sim.channel.queue_length("a") == 1  # the order waits in the modem
    pressed = sim.now
    n = sim.stop()
    sim.run_until(sim.now + 0.05)
    handed = [p for t, p in sim.handed["a"] if t >= pressed]
    assert handed and handed[0][0] >> 4 == ac.UP_STOP  # flushed: the STOP is the next packet on the air
    sim.run_until(pressed + 20)
    (t_rov, _), *_ = [(t, e) for t, e in sim.events(ac.StopWanted, "rov") if e.stop_no == n]
    assert t_rov - pressed <= 2.6
    assert sim.events(ac.StopTaken)
    # The order the STOP overtook: cancelled (never taken) or aborted, and never run after the STOP.
    assert _fates(sim, oid)[-1] in ("cancelled", "aborted")
    assert all(t < t_rov for t, e in sim.events(ac.GoToWanted, "rov"))
    assert sim.vehicle.target is None


def test_a_thumbnail_is_decoded_and_verified():
    import numpy as np

    from rovlink import debt
    from rovlink.debt.samples import seabed

    def camera(settings):  # an 80x60 grey DEBT picture of the simulated seabed
        grey = seabed(ac.THUMB_H, ac.THUMB_W, seed=3).mean(axis=2).astype(np.uint8)
        stream = debt.encode(grey, settings.budget, mono=True)
        return len(stream).to_bytes(2, "big") + stream

    sim = _synced(seed=4, camera=camera)
    oid = sim.order(ac.ThumbRequest(0, budget=198))
    sim.run_until(sim.now + 80)
    (_, done), = sim.events(ac.ThumbnailComplete)
    assert done.oid == oid and done.verified and len(done.object) == 200
    picture = debt.decode(done.object[2:])
    assert picture.shape == (60, 80)
    progress = [e for _, e in sim.events(ac.ThumbnailProgress)]
    assert progress and not any(e.verified for e in progress)
    assert all(done.object.startswith(e.prefix) for e in progress)
    assert _fates(sim, oid) == ["taken", "done"]


def test_a_forged_thumbnail_byte_fails_verification_is_counted_and_the_thumbnail_comes_again():
    sim = _synced(seed=5)
    forged = []

    def tamper(to, packet, now):
        if to == "a" and packet[0] & 0x80 and packet[0] & 63 == 4 and not forged:
            forged.append(now)
            return packet[:3] + bytes([packet[3] ^ 1]) + packet[4:]
        return packet

    sim.tamper = tamper
    oid = sim.order(ac.ThumbRequest(0))
    sim.run_until(sim.now + 150)
    assert forged
    assert [e for _, e in sim.events(ac.ThumbnailRejected)] == [ac.ThumbnailRejected(oid)]
    assert sim.operator.counters.thumbnail_mismatches == 1
    (_, done), = sim.events(ac.ThumbnailComplete)
    assert done.object == fixed_camera(200)(None)


def test_a_replayed_or_held_back_packet_is_refused():
    sim = _synced(seed=6)
    arm = sim.order(ac.OrderBody(0, ac.OP_ARM))
    sim.run_until(sim.now + 12)
    assert _fates(sim, arm)[-1] == "done"
    order_packets = [p for _, p in sim.handed["a"] if p[0] >> 4 == ac.UP_ORDER]
    disarm = sim.order(ac.OrderBody(0, ac.OP_DISARM))
    sim.run_until(sim.now + 12)
    assert _fates(sim, disarm)[-1] == "done" and not sim.vehicle.armed
    rov = sim.rov
    taken, stale = rov.counters.frames_taken, rov.counters.inauthentic
    for p in order_packets:  # the ARM, recorded and played again: behind the window
        assert rov.receive(p, sim.now) == []
    assert rov.counters.frames_taken == taken and rov.counters.inauthentic == stale + len(order_packets)
    assert not sim.vehicle.armed


def test_a_held_back_frame_is_refused_once_a_newer_one_was_taken():
    rov = ac.AcousticRov(K, boot=BOOT)
    rov.session = S
    older, newer = _up(0, ac.UP_ORDER, ac.OrderBody(1, ac.OP_ARM).encode()), _up(1, ac.UP_POLL, ac.PollBody().encode())
    rov.update_status(ac.VehicleState(autopilot=True))
    assert rov.receive(newer, 0.0) == [] and rov.rx_last == 1
    assert rov.receive(older, 0.1) == [] and rov.counters.inauthentic == 1 and rov.last_oid == 0


def test_a_replayed_hello_gets_no_sync():
    rov = ac.AcousticRov(K, boot=BOOT)
    hello = ac.seal_hello(K, CHALLENGE)
    assert rov.receive(hello, 0.0) == [ac.SessionStarted(CHALLENGE)]
    session = rov.session
    rov.next_packet(0.0), rov.next_packet(1.0)
    assert rov.receive(hello, 5.0) == []
    assert rov.session == session and rov.counters.replayed_hellos == 1


def test_a_rov_restart_is_seen_by_its_boot_and_the_pending_order_is_of_unknown_fate():
    sim = _synced(seed=7)
    first_boot = sim.rov.boot
    sim.rov_down = True  # the ROV's process dies ...
    oid = sim.order(ac.GoToBody(0, 50, 0, 0, relative=True))
    sim.run_until(sim.now + 10)
    sim.restart_rov()  # ... and starts again
    sim.rov_down = False
    sim.run_until(sim.now + 60)
    synced = [e for _, e in sim.events(ac.SessionSynced)]
    assert synced[-1].restarted and synced[-1].boot != first_boot
    assert _fates(sim, oid) == ["unknown"]
    assert sim.operator.ready  # orders again once the new ROV's STATUS came


@pytest.mark.parametrize("action,mode", [(ac.FAILSAFE_HOLD, Mode.POS_HOLD), (ac.FAILSAFE_SURFACE, Mode.SURFACE)])
def test_failsafe_after_failsafe_s_of_silence_with_the_configured_action(action, mode):
    sim = _synced(seed=8, failsafe_s=30, failsafe_action=action)
    synced = [e for _, e in sim.events(ac.SessionSynced)][-1]
    assert (synced.failsafe_s, synced.failsafe_action) == (30, action)
    oid = sim.order(ac.GoToBody(0, 400, 0, 0, relative=True))
    sim.run_until(sim.now + 8)
    silent_from = sim.now
    sim.tamper = lambda to, p, now: None if to == "b" else p  # the uplink goes silent
    sim.run_until(sim.now + 45)
    (t, entered), = sim.events(ac.FailsafeStarted, "rov")
    assert entered.action == action and 30 - 3 <= t - silent_from <= 30 + 3
    assert sim.vehicle.mode == mode and sim.vehicle.target is None
    statuses = [e.status for _, e in sim.events(ac.StatusReceived) if _ > t]
    assert statuses and statuses[-1].failsafe and statuses[-1].hold
    assert _fates(sim, oid)[-1] == "aborted"
    sim.tamper = None
    sim.run_until(sim.now + 40)
    assert sim.events(ac.FailsafeEnded, "rov")


def test_thirty_percent_loss_still_converges():
    sim = _synced(seed=9, loss=0.3)
    oid = sim.order(ac.GoToBody(0, 30, 0, 0, relative=True))
    sim.run_until(sim.now + 90)
    assert _fates(sim, oid)[-1] == "done"
    thumb = sim.order(ac.ThumbRequest(0))
    sim.run_until(sim.now + 300)
    assert [e.oid for _, e in sim.events(ac.ThumbnailComplete)] == [thumb]
    n = sim.stop()
    sim.run_until(sim.now + 60)
    assert [e.stop_no for _, e in sim.events(ac.StopTaken)] == [n]


# ---------------------------------------------------------------------------
# STATUS_SAME: a still vehicle told in one packet, never a position it did not name
# ---------------------------------------------------------------------------

STILL = ac.VehicleState(12.5, -3.0, 4.5, 90.0, armed=True, mode=Mode.POS_HOLD, position_valid=True,
                        attitude_valid=True, autopilot=True, battery_v=15.8)


def _rov_in_session() -> ac.AcousticRov:
    rov = ac.AcousticRov(K, boot=BOOT, random_bytes=_feeder([NONCE]))
    rov.update_status(STILL)
    rov.tick(0.0)
    rov.receive(ac.seal_hello(K, CHALLENGE), 0.0)
    rov.next_packet(0.0), rov.next_packet(1.0)  # the SYNC
    return rov


def _status_frame(rov, now) -> tuple[int, bytes]:
    """The next status frame the ROV hands: (KIND, whole frame)."""
    first = rov.next_packet(now)
    kind = first[0] >> 4 & 7
    rest = b"".join(rov.next_packet(now + 1 + i) for i in range(ac.DOWN_PACKETS[kind] - 1))
    return kind, first + rest


def test_the_rov_sends_status_same_only_for_a_full_status_the_operator_says_it_holds():
    rov = _rov_in_session()
    rov.receive(_up(0, ac.UP_POLL, ac.PollBody(have_status=True, held=0).encode()), 2.0)  # HELD 0: no full sent yet
    assert _status_frame(rov, 2.0)[0] == ac.DOWN_STATUS  # CTR 0
    assert _status_frame(rov, 4.0)[0] == ac.DOWN_STATUS  # the last POLL named nothing of ours: full again
    rov.receive(_up(1, ac.UP_POLL, ac.PollBody(have_status=True, held=1).encode()), 6.0)  # holds CTR 1
    kind, frame = _status_frame(rov, 6.0)
    assert kind == ac.DOWN_STATUS_SAME and frame == _down(2, ac.DOWN_STATUS_SAME, ac.same_body(1, rov.status(6.0).encode()))
    rov.update_status(replace(STILL, armed=False))  # flags travel in STATUS_SAME too
    kind, frame = _status_frame(rov, 7.0)
    assert kind == ac.DOWN_STATUS_SAME and frame[2] >> 7 == 0
    rov.update_status(replace(STILL, z_m=4.6))  # 1 dm deeper: the position is news, a full STATUS
    assert _status_frame(rov, 8.0)[0] == ac.DOWN_STATUS  # CTR 4
    assert _status_frame(rov, 10.0)[0] == ac.DOWN_STATUS  # HELD still names CTR 1, not the newest (4)
    rov.receive(_up(2, ac.UP_POLL, ac.PollBody(have_status=False).encode()), 12.0)
    assert _status_frame(rov, 12.0)[0] == ac.DOWN_STATUS
    assert rov.counters.statuses_same == 2


def test_the_operator_takes_status_same_only_naming_the_newest_full_status_it_took():
    op = ac.AcousticOperator(K, random_bytes=_feeder([CHALLENGE]))
    op.next_packet(0.0)
    for i, p in enumerate(_chunks(b"".join(ac.seal_sync(K, CHALLENGE, ac.SyncBody(BOOT, NONCE, 60, 0))))):
        op.receive(p, 1.0 + i)
    assert ac.PollBody.decode(op._poll().encode()).have_status is False  # no STATUS yet
    same = ac.same_body(0, STATUS0.encode())
    assert op.receive(_down(0, ac.DOWN_STATUS_SAME, same), 3.0) == []  # names a STATUS it never took
    assert op.counters.same_unmatched == 1 and op.last_status is None
    full = _down(1, ac.DOWN_STATUS, STATUS0.encode())
    (got,) = op.receive(full[:8], 4.0) + op.receive(full[8:], 5.0)
    assert got == ac.StatusReceived(STATUS0, 5.0 - ac.STATUS_TRANSIT_S, 1)
    poll = ac.PollBody.decode(op._poll().encode())
    assert poll.have_status and poll.held == 1
    renewed = replace(STATUS0, armed=False, result=ac.R_DONE, oid=7)
    (got,) = op.receive(_down(2, ac.DOWN_STATUS_SAME, ac.same_body(1, renewed.encode())), 7.0)
    assert got == ac.StatusReceived(renewed, 7.0 - ac.SAME_TRANSIT_S, 2)
    # One naming CTR 17 (REF 17) when it holds CTR 1: ignored, and its POLLs ask for a full one.
    assert op.receive(_down(3, ac.DOWN_STATUS_SAME, ac.same_body(17, renewed.encode())), 8.0) == []
    assert op.counters.same_unmatched == 2 and op.last_status == renewed
    assert not ac.PollBody.decode(op._poll().encode()).have_status
    assert op.receive(_down(4, ac.DOWN_STATUS_SAME, ac.same_body(1, renewed.encode())), 9.0) == []  # forgotten: no
    assert op.counters.same_unmatched == 3


def _record_truth(sim) -> tuple[dict, list]:
    """What the ROV meant by each STATUS / STATUS_SAME it sealed, (session, CTR) ->
    Status; and what the operator took, [(session, CTR, Status)]."""
    intended: dict[tuple[bytes, int], ac.StatusBody] = {}
    taken: list[tuple[bytes, int, ac.StatusBody]] = []
    rov, op = sim.rov, sim.operator
    status, seal, op_status = rov.status, rov._seal, op._status
    last: list[ac.StatusBody] = []

    def spy_status(now):
        last[:] = [status(now)]
        return last[0]

    def spy_seal(kind, body):
        ctr, packets = seal(kind, body)
        if kind in (ac.DOWN_STATUS, ac.DOWN_STATUS_SAME):
            intended[rov.session, ctr] = last[0]
        return ctr, packets

    def spy_op_status(st, ctr, *args):
        taken.append((op.session, ctr, st))
        return op_status(st, ctr, *args)

    rov.status, rov._seal, op._status = spy_status, spy_seal, spy_op_status
    return intended, taken


@pytest.mark.parametrize("loss,burst", [(0.0, 1.0), (0.1, 1.0), (0.3, 3.0)])
def test_every_status_the_operator_takes_is_what_the_rov_meant_while_it_moves_and_holds(loss, burst):
    sim = AcousticSim(K, seed=11, loss=loss, burst=burst, camera=fixed_camera(200))
    intended, taken = _record_truth(sim)  # from the start: every STATUS sealed is known
    while not sim.operator.ready:
        sim.run_until(sim.now + 1.0)
    for k in range(3):  # hold still with a thumbnail, then move, then hold again
        sim.order(ac.ThumbRequest(0))
        sim.run_until(sim.now + 50)
        sim.order(ac.GoToBody(0, 40, 30 * k, 10, relative=True))
        sim.run_until(sim.now + 30)
    assert len(taken) > 30
    for session, ctr, status in taken:
        assert status == intended[session, ctr]
    same = sim.operator.counters.statuses_same
    assert same > 10 and sim.rov.counters.statuses_same >= same
    assert len({status.x_dm for _, _, status in taken}) > 3  # positions changed: full STATUSes told them


def test_a_still_vehicle_gets_its_thumbnail_sooner_and_its_status_as_fresh():
    def run(same: bool) -> tuple[float, float]:
        sim = _synced(seed=12, loss=0.1)
        if not same:  # an operator that never says it holds a STATUS: every STATUS full, as before
            sim.operator._poll = _without_held(sim.operator._poll)
        start = sim.now
        oid = sim.order(ac.ThumbRequest(0, budget=198))
        sim.run_until(sim.now + 150)
        (t, done), = sim.events(ac.ThumbnailComplete)
        assert done.oid == oid
        got = [(t2, e.at) for t2, e in sim.events(ac.StatusReceived) if start < t2 < t]
        oldest = max(got[i + 1][0] - got[i][1] for i in range(len(got) - 1))  # just before the next came
        return t - start, oldest
    with_same, without = run(True), run(False)
    assert with_same[0] < without[0] - 5.0
    assert with_same[1] <= without[1] + 0.5


def _without_held(poll):
    return lambda: replace(poll(), have_status=False, held=0)


def test_a_thumbnail_packet_past_the_polls_bitmap_is_not_sent_again_until_the_bitmap_reaches_it():
    rov = _rov_in_session()
    order = b"".join(ac.seal_control(K, ac.LABEL_UP, S, 0, ac.UP_THUMB, ac.ThumbRequest(2, budget=198).encode()))
    for p in _chunks(order):
        rov.receive(p, 2.0)
    rov.thumbnail_ready(2, fixed_camera(200)(None))  # 29 data packets, IDX 0..28
    sent: list[int] = []
    now = 3.0
    for _ in range(60):
        p = rov.next_packet(now)
        if p[0] & 0x80:
            sent.append(p[0] & 63)
        now += 1.0
    assert sent == list(range(29))  # each once, then nothing until a POLL tells
    # Packet 1 lost: LOWEST_MISSING 1, the bitmap tells of 2..20 (all held); 21..28 lie past it.
    rov.receive(_up(1, ac.UP_POLL, ac.PollBody(0, 1, False, (1 << ac.BITMAP_BITS) - 1).encode()), now)
    again = [p[0] & 63 for p in (rov.next_packet(now + k) for k in range(20)) if p[0] & 0x80]
    assert again == [1]
    # Packets 1..20 held: now 21..28 are within the bitmap, and it says 21 and 25 are missing.
    bitmap = sum(1 << (ac.BITMAP_BITS - 1 - k) for k in range(8) if 22 + k != 25)
    rov.receive(_up(2, ac.UP_POLL, ac.PollBody(0, 21, False, bitmap).encode()), now + 20)
    again = [p[0] & 63 for p in (rov.next_packet(now + 20 + k) for k in range(10)) if p[0] & 0x80]
    assert again == [21, 25]


@pytest.mark.parametrize("seed", [0, 2])
def test_at_no_loss_the_status_shown_is_never_older_than_10_s_also_when_orders_cut_a_status_short(seed):
    """§9.4, §9.5 (issue 33): orders arriving while a full STATUS is in the air make the
    ROV flush its second packet; a STATUS_SAME never names that STATUS, so the operator
    never drops the statuses it holds and the status it shows stays fresh."""
    sim = _synced(seed=seed)
    rng = random.Random(seed)
    shown: list[float] = []  # when the newest STATUS taken was made, as the operator dates it
    sim.on_operator_event = lambda e, t: shown.append(e.at) if isinstance(e, ac.StatusReceived) else None
    end, next_order, k, oldest = sim.now + 600, sim.now + 3, 0, 0.0
    while sim.now < end:  # the vehicle still (its thumbnail already there), orders now and then
        sim.run_until(min(next_order, sim.now + 0.5))
        if sim.now >= next_order:
            next_order = sim.now + rng.uniform(3, 12)
            if sim.operator.sending_oid is None and not sim.operator.orders_waiting:
                k += 1
                sim.order(ac.OrderBody(0, ac.OP_ARM if k % 2 else ac.OP_HOLD))
        if shown:
            oldest = max(oldest, sim.now - shown[-1])
    assert k > 50 and sim.rov.counters.fulls_flushed > 5  # it happened, many times
    assert oldest <= 10.0
    assert sim.rov.counters.statuses_same > 300 and sim.operator.counters.same_unmatched == 0


# -- §9 read one way (issue 33) ------------------------------------------------------


def test_no_failsafe_before_the_first_frame_of_a_session():
    rov = ac.AcousticRov(K, failsafe_s=12, boot=BOOT, random_bytes=_feeder([NONCE]))
    rov.update_status(STILL)
    assert rov.tick(0.0) == [ac.StopWanted(None)]  # the start's brake holds it
    assert rov.tick(100.0) == [] and rov.failsafe_at is None and not rov.status(100.0).failsafe
    rov.receive(ac.seal_hello(K, CHALLENGE), 100.0)
    assert rov.tick(130.0) == [] and not rov.status(130.0).failsafe  # a HELLO starts no timer
    rov.receive(_up(0, ac.UP_POLL, ac.PollBody().encode()), 131.0)  # the session's first frame
    assert rov.failsafe_at == 143.0 and rov.tick(142.9) == []
    assert [type(e) for e in rov.tick(143.0)] == [ac.FailsafeStarted]


def test_the_first_status_of_a_rov_with_a_short_failsafe_time_shows_no_failsafe():
    sim = _synced(seed=3, failsafe_s=5)  # a failsafe time shorter than the session takes to start
    (_, first), *_ = sim.events(ac.StatusReceived)
    assert first.status.hold and not first.status.failsafe
    assert not sim.events(ac.FailsafeStarted, "rov")


def _going(rov, now):
    """A go-to taken and flown (GUIDED, GOING), its STATUS sent."""
    for p in _chunks(_up(0, ac.UP_GOTO, ac.GoToBody(1, 50, 0, 0, relative=True).encode())):
        rov.receive(p, now)
    rov.update_status(replace(STILL, mode=Mode.GUIDED, going=True))
    _status_frame(rov, now)
    assert rov.status(now).going and rov.status(now).mode == Mode.GUIDED


def test_the_status_after_a_stop_waits_for_the_brake_to_show():
    rov = _rov_in_session()
    _going(rov, 2.0)
    rov.receive(_up(1, ac.UP_STOP, ac.StopBody(1, 1).encode()), 3.0)
    assert rov.next_packet(3.0) is None and rov.next_packet(4.0) is None  # the autopilot still says GUIDED
    rov.update_status(replace(STILL, mode=Mode.POS_HOLD, going=True))  # the brake shows (GOING not yet refreshed)
    kind, frame = _status_frame(rov, 4.2)
    status = ac.StatusBody.decode(frame[1:13])
    assert kind == ac.DOWN_STATUS and status.mode == Mode.POS_HOLD and status.hold and not status.going
    assert (status.stop_no2, status.result) == (1, ac.R_ABORTED)
    # A brake that never shows: the STATUS goes after BRAKE_SHOWN_S and tells the truth.
    rov.update_status(replace(STILL, mode=Mode.GUIDED))
    rov.receive(_up(2, ac.UP_STOP, ac.StopBody(2, 1).encode()), 10.0)
    assert rov.next_packet(10.0 + ac.BRAKE_SHOWN_S - 0.1) is None
    kind, frame = _status_frame(rov, 10.0 + ac.BRAKE_SHOWN_S)
    assert ac.StatusBody.decode(frame[1:13]).mode == Mode.GUIDED


@pytest.mark.parametrize("action,mode", [(ac.FAILSAFE_HOLD, Mode.POS_HOLD), (ac.FAILSAFE_SURFACE, Mode.SURFACE)])
def test_the_status_reporting_a_failsafe_shows_the_brake_and_no_goto(action, mode):
    rov = ac.AcousticRov(K, failsafe_s=20, failsafe_action=action, boot=BOOT, random_bytes=_feeder([NONCE]))
    rov.update_status(STILL)
    rov.tick(0.0)
    rov.receive(ac.seal_hello(K, CHALLENGE), 0.0)
    rov.next_packet(0.0), rov.next_packet(1.0)
    _going(rov, 2.0)
    assert [type(e) for e in rov.tick(22.0)] == [ac.FailsafeStarted]
    assert rov.next_packet(22.0) is None  # GUIDED still: the STATUS waits
    rov.update_status(replace(STILL, mode=mode, going=True))
    kind, frame = _status_frame(rov, 22.5)
    status = ac.StatusBody.decode(frame[1:13])
    assert (status.failsafe, status.hold, status.going, status.mode, status.result) == (
        True, True, False, mode, ac.R_ABORTED)


def test_forged_first_halves_count_as_inauthentic_and_alert_like_one_packet_forgeries():
    op = ac.AcousticOperator(K, random_bytes=_feeder([CHALLENGE]))
    op.next_packet(0.0)
    for i, p in enumerate(_chunks(b"".join(ac.seal_sync(K, CHALLENGE, ac.SyncBody(BOOT, NONCE, 60, 0))))):
        op.receive(p, 1.0 + i)
    rng = random.Random(5)
    alerts = []
    for k in range(6):  # six forged first halves of a STATUS, one a second, nothing authentic since 2 s
        events = op.receive(bytes([0x10 | k]) + rng.randbytes(7), 20.0 + k)
        alerts += [e.alert for e in events if isinstance(e, ac.InauthenticPacket)]
    assert op.counters.unpaired == 5 and op.counters.inauthentic == 5  # the sixth waits for its pair
    assert alerts == [False, False, False, True, True]


def test_the_poll_before_any_thumbnail_has_t_0_and_asks_for_nothing():
    sim = _synced(seed=4)
    polls = [ac.PollBody.decode(p[1:5]) for _, p in sim.handed["a"] if p[0] >> 4 == ac.UP_POLL]
    assert polls and all((p.t, p.lowest_missing, p.have_end, p.bitmap) == (0, ac.MAX_SLOTS, True, 0) for p in polls)


@pytest.mark.parametrize("latency_s", [1.5, 2.0, 2.5])
def test_the_first_status_comes_without_a_second_hello_crossing_the_first_sync(latency_s):
    """Modems that start 3 s after the programs and take up to 2.5 s from host to host:
    the HELLO waits in the operator's modem, and its 8 s count from when it left."""
    from rovlink.link.emulators.m64 import M64Params

    sim = AcousticSim(K, seed=1, params=M64Params(latency_s=latency_s, sync_s=3.0))
    sim.run_until(40.0)
    hellos = [t for t, p in sim.handed["a"] if p[0] == 0]
    (first, _), *_ = sim.events(ac.StatusReceived)
    assert len(hellos) == 1 and len(sim.events(ac.SessionSynced)) == 1
    assert first <= 18.0  # was 22-24 s when the second HELLO crossed the first SYNC


def test_the_operators_first_poll_after_the_sync_is_the_vector():
    v = [bytes.fromhex(r) for r in _doc_rows()]
    op = ac.AcousticOperator(K, random_bytes=_feeder([CHALLENGE]))
    assert op.next_packet(0.0) == v[0]
    for i, p in enumerate(_chunks(v[1])):
        op.receive(p, 5.0 + i)
    assert op.next_packet(7.0) == v[12]  # no thumbnail asked for yet, no STATUS taken


# ---------------------------------------------------------------------------
# FOLLOW in THUMB (issue 34: §9.3 and §10)
# ---------------------------------------------------------------------------


def _take_thumb(rov: ac.AcousticRov, request: ac.ThumbRequest, ctr: int) -> list:
    events = []
    for i, p in enumerate(_chunks(_up(ctr, ac.UP_THUMB, request.encode()))):
        events += rov.receive(p, 2.0 + ctr + i * 0.5)
    return events


def test_a_rov_with_a_tracker_takes_a_followed_thumbnail_and_one_without_says_impossible_now():
    rov = _rov_in_session()
    rov.follows = True
    assert _take_thumb(rov, FOLLOW, 0) == [ac.ThumbnailWanted(5, FOLLOW)]
    assert rov.result == ac.R_TAKEN and rov.last_oid == 5
    plain = _rov_in_session()  # no tracker: the order is consumed and answered RESULT 4
    assert _take_thumb(plain, FOLLOW, 0) == []
    assert plain.result == ac.R_IMPOSSIBLE and plain.last_oid == 5 and plain.thumb is None


@pytest.mark.parametrize("request_, why", [
    (replace(FOLLOW, roi=(0, 0, 0, 0), shift=0), "FOLLOW without an ROI"),
    (replace(FOLLOW, follow=False), "KEEP or DRAWN_ON without FOLLOW"),
    (replace(FOLLOW, follow=False, keep=False), "KEEP or DRAWN_ON without FOLLOW"),
])
def test_a_followed_thumbnail_that_makes_no_sense_is_invalid_and_nothing_is_captured(request_, why):
    assert request_.invalid() == why
    rov = _rov_in_session()
    rov.follows = True
    assert _take_thumb(rov, request_, 0) == []
    assert rov.result == R_INVALID and rov.thumb is None


def test_a_thumb_from_before_follow_decodes_as_it_did_and_reserved_bit_0_stays_reserved():
    assert ac.ThumbRequest.decode(THUMB.encode()) == THUMB and not THUMB.follow and THUMB.invalid() is None
    body = bytearray(FOLLOW.encode())
    body[5] |= 1  # bit 0 of the flags byte
    assert ac.ThumbRequest.decode(bytes(body)).invalid() == "reserved bits set"
    body = bytearray(FOLLOW.encode())
    body[11] = 1  # the last of the 3 zero bytes
    assert ac.ThumbRequest.decode(bytes(body)).invalid() == "reserved bits set"
