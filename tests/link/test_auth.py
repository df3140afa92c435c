"""Version 2's authenticated chain (docs/PROTOCOL.md §8): the test vectors byte for
byte, what each end takes and refuses, key files, and the framing that
delivers an authentic frame early."""

from __future__ import annotations

import os
import random
import stat

import pytest

from rovlink.link.radio.auth import (
    AuthFrameDecoder,
    HelloIn,
    KeyFileError,
    OperatorChain,
    PollIn,
    RovChain,
    mac,
    read_key_file,
    write_key_file,
)

K = bytes(range(32))
# §8's vectors (with §8.1's bytes): a HELLO, its SYNC, then three polls and their
# replies: a poll that says its image request (none follows a SYNC) and a reply
# whose pose is six differences; a VELOCITY without ARM/MODE continuing the
# picture and a FIRST trunk; a NONE poll that repeats that wish and continues,
# and a reply whose pose is whole (its differences would be longer).
HELLO = "55 0f 40 1f ff 01 02 03 04 05 06 07 08 b9 6b 8d 9f"
SYNC = "55 1e 01 00 00 00 00 00 00 00 00 00 00 00 00 81 12 34 56 78 9a bc de f0 11 22 33 44 e9 7f 89 c4"
POLL = "55 0d 21 00 00 41 32 00 ec 0a 00 78 48 6e 1b"
REPLY = "55 0c 01 b1 00 00 00 00 00 00 5c 23 da 64"
POLL2 = "55 0a 01 32 00 ec 0a 01 8f e2 1f 06"
REPLY2 = "55 12 91 b1 14 05 04 0a 0d f0 01 00 05 61 62 63 25 8c 2e 02"
POLL3 = "55 06 00 02 db 2b ab e3"
REPLY3 = "55 14 51 b0 04 e2 fe d4 01 c2 00 96 ff 24 23 28 64 65 09 5a cf a9"
FRAMES = [HELLO, SYNC, POLL, REPLY, POLL2, REPLY2, POLL3, REPLY3]
CHAINS = ["b96b8d9fbc458dfba83713417e76d1a1a89fa90a8b3d362c094195444064981f",
          "e97f89c42a589677a98501ca4be290aa9338c0d0963ce4057a20f1b153c52bd9",
          "78486e1b471099dce51b8d157c794ae19f950e43c54801e7b1326eb4d47302f1",
          "5c23da64f2512e78313d016e76326d8bb8c6f79e21e8402766da107c5ce30563",
          "8fe21f06c3de4b604d133b5e392f76e7fe500b6343ad86a9b540ebf27369b363",
          "258c2e024d68bc2663b48a6c238acfe37ba74bcb86dbc4eeb455d6879976b8bb",
          "db2babe3439401c10e1dd0553cd5dd7e6bee08b92594606df0449a75353c55f7",
          "095acfa971f7e0bc5bd6b5744c0718683481616cb7237368ca56e7b254fbc371"]
VELOCITY_PAYLOAD = bytes.fromhex("21000041320 0ec0a".replace(" ", ""))
REPLY_PAYLOAD = bytes.fromhex("01" + "00" * 12 + "b0")
SYNC_PAYLOAD = bytes.fromhex("01" + "00" * 12 + "81")


def wire(text: str) -> bytes:
    return bytes.fromhex(text.replace(" ", ""))


def contents(frame: bytes) -> bytes:
    return frame[2:]  # version 2 has no CRC (§8.1)


def scripted(*chunks: bytes):
    """A random source that hands out the given bytes, in order."""
    queue = list(chunks)

    def take(n: int) -> bytes:
        chunk = queue.pop(0)
        assert len(chunk) == n
        return chunk

    return take


def test_the_section_8_vectors_byte_for_byte():
    """Both ends, from the text: the chain seals and checks the frames, and §8.1's
    translation makes each version 2 payload from the version 1.1 one and back."""
    import struct

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

    op = OperatorChain(K, count=0)
    rov = RovChain(K, boot=wire("12 34 56 78"), random_bytes=scripted(wire("9a bc de f0 11 22 33 44")))
    hello = op.seal_hello(wire("40 1f ff"), 0.0, challenge=wire("01 02 03 04 05 06 07 08"))
    got = rov.check_poll(contents(hello), 0.0)
    assert isinstance(got, HelloIn)
    sent, chains = [hello], [got.chain]
    sync = rov.seal_sync(SYNC_PAYLOAD, got, 0.01, info=(NO_CONTINUATION, pose_of(SYNC_PAYLOAD), None))
    answer = op.open_reply(contents(sync), 0.02)
    assert answer.sync and not answer.late and answer.boot == wire("12 34 56 78")
    sent.append(sync)
    chains.append(op.chain_to)
    # (version 1.1 poll the operator's master made, what the ROV's slave gets, its reply)
    exchanges = [
        (VELOCITY_PAYLOAD, VELOCITY_PAYLOAD, REPLY_PAYLOAD),
        (wire("01 00 00 00 32 00 ec 0a"), wire("01 00 00 00 32 00 ec 0a"),
         wire("91 000a fffd 0002 0005 fff9 0078 b0 0000 0005616263")),
        (wire("00 00 05"), wire("01 00 05 00 32 00 ec 0a"),  # NONE: the chained reply's wish again
         bytes([0x51]) + struct.pack(">hhhhhh", 1250, -300, 450, 150, -220, 9000) + wire("b0 0005 6465")),
    ]
    continuation, reference = NO_CONTINUATION, pose_of(SYNC_PAYLOAD)
    t = 0.03
    for poll11, slave_gets, reply11 in exchanges:
        poll = op.seal_poll(poll_to_wire(poll11, continuation), t)
        taken = rov.check_poll(contents(poll), t)
        assert isinstance(taken, PollIn)
        kept_continuation, kept_pose, kept_wish = taken.info
        assert poll_from_wire(taken.payload, kept_continuation, kept_wish) == slave_gets
        rov.take(taken, t)
        reply = rov.seal_reply(reply_to_wire(reply11, kept_pose), taken, t,
                               info=(continuation_of(reply11, slave_gets), pose_of(reply11), wish_of(slave_gets)))
        answer = op.open_reply(contents(reply), t + 0.01)
        assert not answer.late
        back, reference = reply_from_wire(answer.payload, request_of(poll11), reference)
        assert back == reply11 and reference == pose_of(reply11)
        continuation = continuation_of(reply11, poll11)
        sent += [poll, reply]
        chains += [taken.chain, op.chain_to]
        t += 0.1
    assert [f.hex(" ") for f in sent] == FRAMES
    assert [c.hex() for c in chains] == CHAINS


def test_a_mac_is_blake2s_of_kind_prev_and_data():
    import hashlib

    assert mac(K, b"R", b"x" * 32, b"abc") == hashlib.blake2s(b"R" + b"x" * 32 + b"abc", key=K).digest()


def _session(n_polls: int = 5):
    """An operator and a ROV chained by one HELLO/SYNC and n polls, and every frame sent."""
    op, rov = OperatorChain(K), RovChain(K)
    frames = []
    hello = op.seal_hello(wire("40 1f ff"), 0.0)
    frames.append(("hello", hello))
    sync = rov.seal_sync(SYNC_PAYLOAD, rov.check_poll(contents(hello), 0.0), 0.0)
    frames.append(("sync", sync))
    op.open_reply(contents(sync), 0.0)
    t = 0.1
    for _ in range(n_polls):
        poll = op.seal_poll(VELOCITY_PAYLOAD, t)
        frames.append(("poll", poll))
        taken = rov.check_poll(contents(poll), t)
        assert isinstance(taken, PollIn)
        rov.take(taken, t)
        reply = rov.seal_reply(REPLY_PAYLOAD, taken, t)
        frames.append(("reply", reply))
        assert not op.open_reply(contents(reply), t + 0.05).late
        t += 0.2
    return op, rov, frames, t


def test_a_replayed_poll_is_refused_and_a_replayed_hello_gets_nothing():
    op, rov, frames, t = _session()
    for kind, f in frames:
        if kind == "poll":
            assert rov.check_poll(contents(f), t) is None
        if kind == "hello":
            assert rov.check_poll(contents(f), t) is None
    assert rov.counters.replayed_hellos == 1
    # The honest operator goes on.
    poll = op.seal_poll(VELOCITY_PAYLOAD, t)
    assert isinstance(rov.check_poll(contents(poll), t), PollIn)


def test_a_poll_held_back_is_refused_once_a_newer_one_was_taken():
    op, rov, _, t = _session(1)
    held = op.seal_poll(VELOCITY_PAYLOAD, t)  # the attacker keeps this one
    newer = op.seal_poll(VELOCITY_PAYLOAD, t + 0.2)  # resent: same chain value, COUNT + 1
    taken = rov.check_poll(contents(newer), t + 0.3)
    rov.take(taken, t + 0.3)
    assert rov.check_poll(contents(held), t + 0.4) is None
    assert rov.counters.stale_count == 1


def test_chain_values_older_than_the_failsafe_time_match_nothing():
    op, rov, _, t = _session(2)
    poll = op.seal_poll(VELOCITY_PAYLOAD, t + 5.0)
    assert rov.check_poll(contents(poll), t + 5.0) is None


def test_an_authentic_poll_that_does_not_parse_moves_no_reference():
    op, rov, _, t = _session(1)
    first = op.seal_poll(VELOCITY_PAYLOAD, t)
    second = op.seal_poll(VELOCITY_PAYLOAD, t)
    assert isinstance(rov.check_poll(contents(second), t), PollIn)  # checked, not taken (did not parse)
    taken = rov.check_poll(contents(first), t)
    assert isinstance(taken, PollIn)  # the reference did not move past `first`


def test_the_operator_never_uses_a_late_or_inauthentic_reply():
    op, rov, _, t = _session(1)
    p1 = rov.check_poll(contents(op.seal_poll(VELOCITY_PAYLOAD, t, deadline=t + 0.5)), t)
    rov.take(p1, t)
    r1 = rov.seal_reply(REPLY_PAYLOAD, p1, t)
    p2 = rov.check_poll(contents(op.seal_poll(VELOCITY_PAYLOAD, t + 1.0, deadline=t + 1.5)), t + 1.0)
    rov.take(p2, t + 1.0)
    r2 = rov.seal_reply(REPLY_PAYLOAD, p2, t + 1.0)
    assert not op.open_reply(contents(r2), t + 1.1).late
    chained = op.chain_to
    assert op.open_reply(contents(r1), t + 1.2).late  # answers an older poll than the last sent
    assert op.open_reply(contents(r2), t + 1.2).late  # answered already
    assert op.chain_to == chained
    p3 = rov.check_poll(contents(op.seal_poll(VELOCITY_PAYLOAD, t + 2.0, deadline=t + 2.5)), t + 2.0)
    rov.take(p3, t + 2.0)
    assert op.open_reply(contents(rov.seal_reply(REPLY_PAYLOAD, p3, t + 2.0)), t + 2.6).late  # past its deadline
    forged = bytearray(contents(r2))
    forged[3] ^= 1
    assert op.open_reply(bytes(forged), t + 3.1) is None
    assert op.counters.late == 3 and op.counters.inauthentic == 1


def test_a_reply_to_a_poll_before_the_last_sent_is_late_even_unanswered():
    """One poll at a time: a reply held back past the next poll answers a poll
    that is no longer the present, even if nothing answered it yet (issue 16)."""
    op, rov, _, t = _session(1)
    p1 = rov.check_poll(contents(op.seal_poll(VELOCITY_PAYLOAD, t, deadline=t + 0.5)), t)
    rov.take(p1, t)
    held = rov.seal_reply(REPLY_PAYLOAD, p1, t)  # the radio keeps it
    op.seal_poll(VELOCITY_PAYLOAD, t + 0.5, deadline=t + 1.0)  # the resend, after p1's deadline
    answer = op.open_reply(contents(held), t + 0.6)  # within p1's own timeout of the resend, but not p1's
    assert answer is not None and answer.late


def test_a_sync_after_its_hellos_deadline_is_late():
    op, rov, _, t = _session(1)
    hello = op.seal_hello(wire("40 1f ff"), t, deadline=t + 0.58)
    sync = rov.seal_sync(SYNC_PAYLOAD, rov.check_poll(contents(hello), t), t)
    boot = op.boot
    answer = op.open_reply(contents(sync), t + 1.0)
    assert answer.late and op.boot == boot


def test_a_hello_with_an_order_is_a_protocol_error_and_gets_no_sync():
    op, rov = OperatorChain(K), RovChain(K)
    hello = bytearray(op.seal_hello(wire("40 1f ff"), 0.0))
    # An authentic HELLO carrying STOP (ORDER 4): made with the key, as a buggy operator would.
    signed = bytes((0x44, 0x1F, 0xFF)) + bytes(hello[5:13])
    tag = mac(K, b"H", b"", signed)[:4]
    assert rov.check_poll(signed + tag, 0.0) is None
    assert rov.counters.bad_hellos == 1 and rov.counters.hellos == 0


def test_a_restarted_rov_is_known_by_its_boot():
    op, _, _, t = _session(1)
    new_rov = RovChain(K)
    hello = op.seal_hello(wire("40 1f ff"), t)
    sync = new_rov.seal_sync(SYNC_PAYLOAD, new_rov.check_poll(contents(hello), t), t)
    old_boot = op.boot
    answer = op.open_reply(contents(sync), t + 0.1)
    assert answer.sync and answer.boot == new_rov.boot != old_boot and op.boot == new_rov.boot


def test_a_hundred_thousand_forged_replayed_and_flipped_frames_are_never_taken():
    """Every frame of a session, replayed, bit-flipped, truncated, or made up,
    at a ROV that has seen the session: none is taken, none gets a SYNC."""
    op, rov, frames, t = _session(8)
    rng = random.Random(7)
    sent = [contents(f) for kind, f in frames if kind in ("hello", "poll")]
    taken_before = rov.counters.polls_taken
    accepted = 0
    for i in range(100_000):
        base = bytearray(rng.choice(sent))
        how = i % 4
        if how == 1:
            bit = rng.randrange(len(base) * 8)
            base[bit // 8] ^= 1 << (bit % 8)
        elif how == 2:
            base = bytearray(os.urandom(rng.randint(1, 40)))
        elif how == 3:
            base = base[:rng.randint(0, len(base))] + bytearray(os.urandom(rng.randint(0, 6)))
        if rov.check_poll(bytes(base), t) is not None:
            accepted += 1
    assert accepted == 0
    assert rov.counters.polls_taken == taken_before


def test_key_files_are_made_private_and_never_overwritten(tmp_path):
    path = tmp_path / "link.key"
    key = write_key_file(str(path))
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert read_key_file(str(path)) == key and len(path.read_text().strip()) == 64
    with pytest.raises(FileExistsError):
        write_key_file(str(path))
    assert read_key_file(str(path)) == key
    path.chmod(0o640)
    with pytest.raises(KeyFileError, match="readable by others"):
        read_key_file(str(path))
    bad = tmp_path / "bad.key"
    bad.write_text("xyz\n")
    bad.chmod(0o600)
    with pytest.raises(KeyFileError, match="64 hex digits"):
        read_key_file(str(bad))
    with pytest.raises(KeyFileError, match="no such key file"):
        read_key_file(str(tmp_path / "missing"))


def test_an_authentic_frame_behind_an_incomplete_candidate_is_delivered_at_once():
    op, rov, _, t = _session(1)
    reply_frame = rov.seal_reply(REPLY_PAYLOAD, rov.check_poll(contents(op.seal_poll(VELOCITY_PAYLOAD, t)), t), t)

    def authentic(c: bytes) -> bool:
        return any(mac(K, b"R", s.value, c[:-4])[:4] == c[-4:] for s in op._polls)

    decoder = AuthFrameDecoder(authentic)
    noise = bytes([0x55, 200])  # a false start whose LEN would swallow the reply
    assert decoder.feed(noise + reply_frame) == [contents(reply_frame)]
    # The false candidate completes later; nothing is delivered twice.
    assert decoder.feed(os.urandom(200)) == []
    assert decoder.counters.frames == 1


def test_a_crc_valid_frame_with_a_wrong_tag_is_dropped_like_a_crc_failure():
    from rovlink.link.radio.frame import encode_frame

    decoder = AuthFrameDecoder(lambda c: False)
    forged = encode_frame(REPLY_PAYLOAD + b"\0\0\0\0")
    assert decoder.feed(forged) == []
    assert decoder.counters.rejected >= 1
