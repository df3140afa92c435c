"""Every field at every legal value round-trips; illegal values raise ProtocolError."""

import re

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rovlink.link.radio.frame import FrameDecoder, encode_frame
from rovlink.link.radio.messages import (
    FollowSettings,
    ImageSettings,
    InvalidOrder,
    NoOrder,
    Poll,
    Position,
    ProtocolError,
    Reply,
    ReservedOrder,
    Stop,
    Velocity,
)

axis = st.integers(-127, 127)
velocities = st.builds(Velocity, axis, axis, axis, axis, st.integers(0, 2), st.integers(0, 6))
int16 = st.integers(-32768, 32767)
yaw = st.integers(-18000, 18000)


@st.composite
def positions(draw):
    relative = draw(st.booleans())
    body = draw(st.booleans()) if relative else False
    return Position(draw(int16), draw(int16), draw(int16), draw(yaw), relative, body)


@st.composite
def image_settings(draw):
    roi = None
    if draw(st.booleans()):
        x0 = draw(st.integers(0, 1022))
        y0 = draw(st.integers(0, 1022))
        roi = (x0, y0, draw(st.integers(x0 + 1, 1023)), draw(st.integers(y0 + 1, 1023)))
    return ImageSettings(roi, draw(st.integers(0, 15)), draw(st.booleans()), draw(st.integers(0, 8189)))


@st.composite
def follow_settings(draw):
    x0, y0 = draw(st.integers(0, 1022)), draw(st.integers(0, 1022))
    roi = (x0, y0, draw(st.integers(x0 + 1, 1023)), draw(st.integers(y0 + 1, 1023)))
    return FollowSettings(roi, draw(st.integers(0, 15)), draw(st.booleans()), draw(st.integers(0, 8189)),
                          keep=draw(st.booleans()), drawn_on=draw(st.integers(0, 7)))


reserved = st.builds(ReservedOrder, st.integers(6, 15), st.binary(max_size=9))
orders = st.one_of(st.just(NoOrder()), velocities, positions(), image_settings(), st.just(Stop()), reserved,
                   follow_settings())
polls = st.builds(Poll, st.integers(0, 1), st.integers(0, 3), orders, st.integers(0, 7), st.integers(0, 8191))


@st.composite
def replies(draw):
    fields = dict(
        ack=draw(st.integers(0, 1)), armed=draw(st.booleans()), mode=draw(st.integers(0, 7)),
        x_cm=draw(int16), y_cm=draw(int16), z_cm=draw(int16),
        roll_cdeg=draw(yaw), pitch_cdeg=draw(yaw), yaw_cdeg=draw(yaw),
        autopilot=draw(st.booleans()), failsafe=draw(st.booleans()), position_valid=draw(st.booleans()),
        hold=draw(st.booleans()), attitude_valid=draw(st.booleans()), rejected=draw(st.booleans()),
        reason=draw(st.integers(0, 3)),
    )
    if draw(st.booleans()):
        trunk = draw(st.binary(min_size=1, max_size=239))
        offset = draw(st.integers(0, 8191 - len(trunk)))
        fields.update(img=draw(st.integers(0, 7)), offset=offset, trunk=trunk, last=draw(st.booleans()))
    return Reply(**fields)


@settings(max_examples=500)
@given(polls)
def test_poll_round_trips(poll):
    payload = poll.encode()
    assert Poll.decode(payload) == poll
    assert FrameDecoder().feed(encode_frame(payload)) == [payload]


@settings(max_examples=500)
@given(replies())
def test_reply_round_trips(reply):
    payload = reply.encode()
    assert Reply.decode(payload) == reply
    assert len(payload) <= 255


@pytest.mark.parametrize("make", [
    lambda: Velocity(128, 0, 0, 0),
    lambda: Velocity(-128, 0, 0, 0),
    lambda: Velocity(0, 0, 0, 0, arm=3),
    lambda: Velocity(0, 0, 0, 0, mode=7),
    lambda: Velocity(1.5, 0, 0, 0),
    lambda: Position(40000, 0, 0, 0),
    lambda: Position(0, 0, 0, 18001),
    lambda: Position(0, 0, 0, 0, relative=False, body=True),
    lambda: ImageSettings((10, 10, 5, 20)),
    lambda: ImageSettings((0, 0, 1024, 10)),
    lambda: ImageSettings(shift=16),
    lambda: ImageSettings(budget_bytes=8190),
    lambda: ImageSettings(budget_bytes=-1),
    lambda: Poll(seq=2),
    lambda: Poll(size=4),
    lambda: Poll(img=8),
    lambda: Poll(offset=8192),
    lambda: ReservedOrder(4),
    lambda: ReservedOrder(6, bytes(10)),
    lambda: ReservedOrder(5),  # FOLLOW (§10)
    lambda: Reply(reason=4),
    lambda: Reply(ack=2),
    lambda: Reply(mode=8),
    lambda: Reply(yaw_cdeg=18001),
    lambda: Reply(img=1, offset=0),
    lambda: Reply(last=True),
    lambda: Reply(img=0, offset=8190, trunk=b"ab"),
    lambda: Reply(img=0, offset=0, trunk=bytes(240)),
])
def test_illegal_values_raise_protocol_error(make):
    with pytest.raises(ProtocolError):
        make()


@pytest.mark.parametrize("payload,words", [
    (b"", "at least 3"),
    (bytes([0x41, 0, 0, 0x40, 0, 0, 0, 0]), "bit 6"),
    (bytes([0x01, 0, 0, 0x08, 0, 0, 0, 0]), "reserved"),
    (bytes([0x01, 0, 0, 0x00, 0, 0, 0]), "5 bytes"),
    (bytes([0x02, 0, 0]) + bytes([0x01]) + bytes(8), "reserved"),
    (bytes([0x03, 0, 0]) + bytes(5) + bytes([0x01, 0, 0]), "reserved"),
    (bytes([0x04, 0, 0, 0]), "STOP"),
    (bytes([0x00, 0, 0, 0]), "NONE"),
    (bytes([0x06, 0, 0]) + bytes(10), "at most 9"),
    (bytes([0x05, 0, 0]) + bytes(10), "FOLLOW body must be 9"),
])
def test_structural_faults_in_polls_are_protocol_errors(payload, words):
    """§1 (1.1): a body length that does not match its ORDER, a reserved bit, a reserved order's body over 9 B."""
    with pytest.raises(ProtocolError, match=words):
        Poll.decode(payload)


@pytest.mark.parametrize("payload,words", [
    # Well-formed orders with a value out of range (§1 (1.1)): decoded as InvalidOrder
    # (the ROV answers and rejects, REASON 0), never a ProtocolError.
    (bytes([0x01, 0, 0, 0x40, 0x80, 0, 0, 0]), "-128"),
    (bytes([0x01, 0, 0, 0xC0, 0, 0, 0, 0]), "ARM 3"),
    (bytes([0x01, 0, 0, 0x07, 0, 0, 0, 0]), "MODE 7"),
    (bytes([0x02, 0, 0]) + bytes([0x40]) + bytes(8), "RELATIVE"),
    (bytes([0x02, 0, 0]) + bytes([0xC0]) + bytes(6) + (18001).to_bytes(2, "big"), "yaw"),
    (bytes([0x03, 0, 0]) + bytes(5) + bytes([0x00, 0x1F, 0xFE]), "BUDGET"),
    (bytes([0x03, 0, 0]) + ((50 << 30) | (10 << 20) | (40 << 10) | 20).to_bytes(5, "big") + bytes(3), "X0 < X1"),
])
def test_out_of_range_values_decode_to_an_invalid_order(payload, words):
    order = Poll.decode(payload).order
    assert isinstance(order, InvalidOrder) and order.code == payload[0] & 0xF
    assert re.search(words, order.why)
    assert order.one_shot == (order.code != 1)


@pytest.mark.parametrize("payload,words", [
    (bytes(13), "at least 14"),
    (bytes(15), "no trunk"),
    (bytes(16), "no trunk"),
    (bytes(13) + bytes([0x01]), "SYNC"),
    (bytes([0x80]) + bytes(13), "FIRST"),
    (bytes([0x40]) + bytes(13), "LAST"),
    (bytes(14) + bytes([0x1F, 0xFE, 0x61, 0x62]), "past"),
    (bytes(14) + bytes([0x00, 0x00, 0x61]), "FIRST=0 disagrees"),
    (bytes([0x80]) + bytes(13) + bytes([0x00, 0x05, 0x61]), "FIRST=1 disagrees"),
])
def test_bad_reply_payloads_say_what_is_wrong(payload, words):
    with pytest.raises(ProtocolError, match=words):
        Reply.decode(payload)


def test_reply_meaningless_values_are_shown_not_refused():
    # §5 (1.1): REASON 3, or a REASON without REJECTED, is unknown, not an error; byte 0 bit 3 is HOLD.
    reply = Reply.decode(bytes([0x08]) + bytes(12) + bytes([0b00000110]))
    assert reply.hold and reply.mode == 0 and reply.reason == 3 and reply.rejection is None
    assert Reply.decode(bytes(13) + bytes([0b00001110])).rejection.name == "UNKNOWN"


def test_sync_is_allowed_only_for_version_2():
    assert Reply.decode(bytes(13) + bytes([0x01]), allow_sync=True).sync
