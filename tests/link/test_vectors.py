"""docs/PROTOCOL.md §6 test vectors, byte for byte, both directions."""

import pytest

from rovlink.link.radio.frame import FrameDecoder, crc16, encode_frame
from rovlink.link.radio.messages import Arm, ImageSettings, Mode, Poll, Position, Reason, Reply, Velocity

VECTORS = [
    (
        Poll(seq=0, size=2, order=Velocity(50, 0, -20, 10, Arm.ARM, Mode.MANUAL), img=0, offset=0),
        "55 08 21 00 00 41 32 00 ec 0a 83 1b",
    ),
    (
        Poll(seq=1, size=3, order=ImageSettings((100, 60, 220, 180), 6, True, 2000), img=2, offset=8191),
        "55 0b b3 5f ff 19 03 c3 70 b4 68 07 d0 22 b0",
    ),
    (
        Poll(seq=0, size=1, order=Position(1250, -300, 450, -9000), img=1, offset=40),
        "55 0c 12 20 28 00 04 e2 fe d4 01 c2 dc d8 32 f7",
    ),
    (
        Reply(ack=1, armed=True, mode=Mode.DEPTH_HOLD, x_cm=1250, y_cm=-300, z_cm=450, roll_cdeg=150,
              pitch_cdeg=-220, yaw_cdeg=9000, autopilot=True, position_valid=True, img=1, offset=0,
              trunk=bytes.fromhex("0005616263")),
        "55 15 b3 04 e2 fe d4 01 c2 00 96 ff 24 23 28 a0 20 00 00 05 61 62 63 fb ab",
    ),
    (Reply(mode=Mode.MANUAL), "55 0e 01 00 00 00 00 00 00 00 00 00 00 00 00 00 c4 8c"),
    # (1.1) rows
    (
        Reply(ack=1, mode=Mode.MANUAL, autopilot=True, rejected=True, reason=0),
        "55 0e 21 00 00 00 00 00 00 00 00 00 00 00 00 88 49 c3",
    ),
    (
        Reply(ack=1, mode=Mode.MANUAL, autopilot=True, attitude_valid=True, rejected=True, reason=2),
        "55 0e 21 00 00 00 00 00 00 00 00 00 00 00 00 9c 1b 76",
    ),
    (
        Reply(armed=True, hold=True, mode=Mode.POS_HOLD, autopilot=True, position_valid=True, attitude_valid=True),
        "55 0e 1c 00 00 00 00 00 00 00 00 00 00 00 00 b0 c8 0f",
    ),
]


def test_crc_check_value():
    assert crc16(b"123456789") == 0x29B1


@pytest.mark.parametrize("message,wire", VECTORS)
def test_vector_encodes_to_the_exact_bytes(message, wire):
    assert encode_frame(message.encode()) == bytes.fromhex(wire)


@pytest.mark.parametrize("message,wire", VECTORS)
def test_vector_decodes_to_the_same_message(message, wire):
    payloads = FrameDecoder().feed(bytes.fromhex(wire))
    assert len(payloads) == 1
    assert type(message).decode(payloads[0]) == message


def test_reply_vector_flags():
    reply = Reply.decode(FrameDecoder().feed(bytes.fromhex(VECTORS[3][1]))[0])
    assert reply.first and not reply.last
    assert reply.trunk == b"\x00\x05abc"


def test_1_1_reply_vectors_status_bits():
    invalid, refused, held = (Reply.decode(FrameDecoder().feed(bytes.fromhex(w))[0]) for _, w in VECTORS[5:8])
    assert invalid.rejection == Reason.INVALID and invalid.ack == 1 and not invalid.attitude_valid
    assert refused.rejection == Reason.REFUSED and refused.attitude_valid
    assert held.hold and held.mode == Mode.POS_HOLD and held.armed and held.rejection is None
    assert held.position_valid and held.attitude_valid and not held.sync
