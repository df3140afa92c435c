"""Version 2's own bytes on the wire (docs/PROTOCOL.md §8.1), without I/O.

Goals: version 2 says no byte its chain already says.  Its tag detects every
error the CRC did, so a frame has no CRC; a reply is paired with the poll it
answers, so it repeats neither the image request nor, mostly, the pose the
operator already holds; a poll that continues the picture where the reply it
is chained to left off does not say where.  The saving goes to the picture
while the pilot steers (issue 23): 10 to 16 bytes per cycle.

Plan: the version 1.1 machines (`Master`, `Slave`) keep speaking 1.1
payloads; `link.secure` translates at the edge with the functions here, each
given what both ends know from the chain:

- `poll_to_wire` / `poll_from_wire`: a poll without its image request when
  the request is the *continuation* of the reply (or SYNC) the poll is chained
  to, and a VELOCITY without its ARM/MODE byte when that byte is 0.  Which
  fields are present follows from `LEN` and the ORDER code alone.
- `reply_to_wire` / `reply_from_wire`: a reply without IMG/OFFSET (its trunk
  is at the request of the poll it answers, or at 0 with FIRST), and its pose
  as six differences from the *reference pose* (the pose in the reply or SYNC
  that poll is chained to) when that is shorter: bit 0 of the status byte
  (SYNC in 1.1, always 0 in a reply) says DELTA.
- `continuation_of` and `pose_of`: what a reply or SYNC leaves for the next
  poll, computed the same way at both ends.

Frames: `0x55 | LEN | contents` where contents are the payload, the extra
bytes of §8 (COUNT, CHALLENGE or NONCE) and the TAG; `LEN` counts them.
"""

from __future__ import annotations

import struct

from ..scene import RECORD_BYTES, record_length
from .frame import START
from .messages import (
    MAX_TRUNK,
    NO_IMAGE_DATA,
    POLL_HEADER,
    REPLY_HEADER,
    REPLY_IMAGE_HEADER,
    REPLY_STATUS_BYTE,
    SYNC_BIT,
    OrderCode,
    ProtocolError,
)

V2_OVERHEAD = 2  # start, LEN: no CRC in version 2
V2_MAX_CONTENTS = 255
V2_MAX_FRAME = V2_MAX_CONTENTS + V2_OVERHEAD
# SIZE classes in version 2 cap the bytes of the whole cycle, the poll's frame and
# its reply's (start to TAG), not the trunk: what a shorter poll or pose saves goes
# to the picture, and the cycle's air time is fixed.  SIZE 3: the reply frame is
# at most the largest frame.  SIZE 0 is 72 bytes: a cycle of 0.477 s at 1.9 kbit/s
# and 85 ms each way, so a wish waits at most that long for its poll.  Issue 40: the
# longest cycle whose wish reaches the ROV within 0.60 s at p95 with margin (73 bytes
# measured 0.591-0.594 s, 74 bytes up to 0.601 s; `rovlink bench console`'s floor):
# every byte beyond 70 goes to the picture.
V2_CYCLE = (72, 110, 180, None)
MIN_POLL_FRAME = V2_OVERHEAD + 1 + 1 + 4  # a NONE poll continuing the picture: byte 0, COUNT, TAG
DELTA_BIT = SYNC_BIT  # reply status byte, bit 0: the pose is six differences
V2_REPLY_STATUS = 2  # byte 0 and the status byte
POSE_BYTES = 12
MAX_VARINT = 3  # bytes of one difference: |d| < 2^20
FIRST_BIT, LAST_BIT = 0x80, 0x40  # reply byte 0
# §11.1: in a reply that is not REJECTED, REASON's two bits say what the annex after the
# pose holds (a REASON without REJECTED had no meaning): ALT, an object record, or both.
REJECTED_BIT, ANNEX_ALT, ANNEX_RECORD = 0x08, 0x02, 0x04
# (decided) A record rides in at most one of every RECORD_EVERY replies carrying picture data,
# so objects take at most 9 / (4 x 45) = 5 % of a SIZE 0 picture's bytes (less above).
RECORD_EVERY = 4
ANNEX_MAX = 1 + RECORD_BYTES  # ALT and one record
NO_CONTINUATION = (0, NO_IMAGE_DATA)  # what a SYNC leaves: no image data

_BODY = {OrderCode.NONE: (0,), OrderCode.VELOCITY: (4, 5), OrderCode.POSITION: (9,), OrderCode.IMAGE: (8,),
         OrderCode.STOP: (0,)}

Pose = tuple[int, int, int, int, int, int]  # X, Y, Z cm; ROLL, PITCH, YAW centidegrees, as carried


def encode_frame2(contents: bytes) -> bytes:
    n = len(contents)
    if not 1 <= n <= V2_MAX_CONTENTS:
        raise ValueError(f"version 2 frame contents must be 1..{V2_MAX_CONTENTS} bytes, got {n}")
    return bytes((START, n)) + bytes(contents)


def frame2_contents(frame: bytes) -> bytes:
    return bytes(frame[V2_OVERHEAD:])


# -- the poll ------------------------------------------------------------------


def _request(payload11: bytes) -> tuple[int, int]:
    word = (payload11[1] << 8) | payload11[2]
    return word >> 13, word & 0x1FFF


def request_of(poll11: bytes) -> tuple[int, int]:
    """(IMG, OFFSET) a version 1.1 poll payload asks for."""
    return _request(poll11)


def poll_to_wire(poll11: bytes, continuation: tuple[int, int]) -> bytes:
    """A version 1.1 poll payload as version 2 sends it, chained to a reply or
    SYNC whose continuation is `continuation`."""
    head, body = poll11[0], poll11[POLL_HEADER:]
    code = head & 0x0F
    if code == OrderCode.VELOCITY and len(body) == 5 and body[0] == 0:
        body = body[1:]  # no ARM or MODE request: the four axes only
    request = b"" if code in _BODY and _request(poll11) == continuation else poll11[1:POLL_HEADER]
    return bytes((head,)) + request + body


def poll_from_wire(wire: bytes, continuation: tuple[int, int], wish: bytes | None = None) -> bytes:
    """The version 1.1 poll payload of a version 2 poll (ProtocolError if its
    length fits no layout of its ORDER).  `wish`: the VELOCITY body the reply it
    is chained to stands for; a NONE poll repeats it (a VELOCITY poll in 1.1)."""
    if not wire:
        raise ProtocolError("empty poll")
    head, rest = wire[0], wire[1:]
    code = head & 0x0F
    if code not in _BODY:  # reserved orders always carry their request (their body has any length)
        if len(rest) < 2:
            raise ProtocolError("a reserved order's poll carries its image request")
        return bytes(wire)
    for body_len in _BODY[code]:
        for with_request in (False, True):
            if len(rest) == body_len + 2 * with_request:
                if with_request:
                    request, body = rest[:2], rest[2:]
                else:
                    img, offset = continuation
                    request, body = ((img << 13) | offset).to_bytes(2, "big"), rest
                if code == OrderCode.VELOCITY and body_len == 4:
                    body = b"\x00" + body
                if code == OrderCode.NONE and wish is not None:
                    head, body = (head & ~0x0F & 0xFF) | OrderCode.VELOCITY, wish
                return bytes((head,)) + bytes(request) + bytes(body)
    raise ProtocolError(f"a version 2 poll with ORDER {code} has no layout of {len(wire)} bytes")


# -- the reply -----------------------------------------------------------------


def _zigzag(value: int) -> bytes:
    z = value * 2 if value >= 0 else -value * 2 - 1
    out = bytearray()
    while True:
        if z < 0x80:
            out.append(z)
            return bytes(out)
        out.append(0x80 | (z & 0x7F))
        z >>= 7


def _unzigzag(data: bytes, i: int) -> tuple[int, int]:
    z = shift = 0
    for k in range(MAX_VARINT):
        if i + k >= len(data):
            raise ProtocolError("a reply's pose difference runs past its end")
        byte = data[i + k]
        if k and byte == 0:
            # (decided) one encoding per value: a last byte of 0 adds nothing (`80 00`)
            raise ProtocolError("a reply's pose difference is not in its shortest form")
        z |= (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            return (z >> 1) ^ -(z & 1), i + k + 1
    raise ProtocolError(f"a reply's pose difference is longer than {MAX_VARINT} bytes")


def pose_of(payload11: bytes) -> Pose:
    """The six pose values a version 1.1 reply payload carries (as carried)."""
    return struct.unpack(">hhhhhh", payload11[1:POSE_BYTES + 1])  # type: ignore[return-value]


def encode_pose(pose: Pose, reference: Pose | None) -> tuple[bytes, bool]:
    """(bytes, delta): the shorter of the six differences from `reference` and the full pose."""
    full = struct.pack(">hhhhhh", *pose)
    if reference is None:
        return full, False
    delta = b"".join(_zigzag(v - r) for v, r in zip(pose, reference))
    return (delta, True) if len(delta) < len(full) else (full, False)


def pose_wire_bytes(pose: Pose, reference: Pose | None) -> int:
    return len(encode_pose(pose, reference)[0])


def reply_to_wire(reply11: bytes, reference: Pose | None, alt: int | None = None, record: bytes = b"") -> bytes:
    """A version 1.1 reply payload as version 2 sends it: no IMG/OFFSET, the pose
    as differences from `reference` when shorter; its annex (§11.1): the ALT byte
    `alt` and one object `record` when given (never in a REJECTED reply: the caller
    keeps them for the next)."""
    if len(reply11) < REPLY_HEADER:
        raise ValueError("a reply payload is at least 14 bytes")
    pose, delta = encode_pose(pose_of(reply11), reference)
    status = (reply11[REPLY_STATUS_BYTE] & ~SYNC_BIT & 0xFF) | (DELTA_BIT if delta else 0)
    annex = b""
    if not status & REJECTED_BIT:
        # A REASON without REJECTED meant nothing in 1.1 (shown unknown); here its bits are the annex's.
        status &= ~(ANNEX_ALT | ANNEX_RECORD) & 0xFF
        if alt is not None:
            status |= ANNEX_ALT
            annex += bytes((alt,))
        if record:
            status |= ANNEX_RECORD
            annex += bytes(record)
    trunk = reply11[REPLY_IMAGE_HEADER:] if len(reply11) > REPLY_HEADER else b""
    return bytes((reply11[0], status)) + pose + annex + bytes(trunk)


def annex_bytes(alt: int | None, record: bytes = b"") -> int:
    return (alt is not None) + len(record)


def reply_from_wire(wire: bytes, request: tuple[int, int], reference: Pose | None) -> tuple[bytes, Pose]:
    """(the version 1.1 reply payload, the pose as carried) of a version 2 reply
    that answers a poll asking for `request`, chained to a reply or SYNC of
    pose `reference` (ProtocolError for a structural fault)."""
    reply, pose, _, _ = reply_from_wire_annex(wire, request, reference)
    return reply, pose


def reply_from_wire_annex(wire: bytes, request: tuple[int, int],
                          reference: Pose | None) -> tuple[bytes, Pose, int | None, bytes]:
    """As `reply_from_wire`, with the annex (§11.1): the ALT byte (None: not in this
    reply) and the object record's bytes (empty: none)."""
    if len(wire) < V2_REPLY_STATUS:
        raise ProtocolError(f"a version 2 reply is at least {V2_REPLY_STATUS} bytes")
    head, status = wire[0], wire[1]
    if status & DELTA_BIT:
        if reference is None:
            raise ProtocolError("a pose difference without a reference pose")
        values, i = [], V2_REPLY_STATUS
        for ref in reference:
            d, i = _unzigzag(wire, i)
            values.append(ref + d)
        if any(not -32768 <= v <= 32767 for v in values):
            raise ProtocolError("a reply's pose difference leads out of its range")
        pose: Pose = tuple(values)  # type: ignore[assignment]
    else:
        i = V2_REPLY_STATUS + POSE_BYTES
        if len(wire) < i:
            raise ProtocolError("a version 2 reply's pose is cut short")
        pose = struct.unpack(">hhhhhh", wire[V2_REPLY_STATUS:i])  # type: ignore[assignment]
    alt, record = None, b""
    if not status & REJECTED_BIT and status & (ANNEX_ALT | ANNEX_RECORD):
        if status & ANNEX_ALT:
            if i >= len(wire):
                raise ProtocolError("a reply's ALT byte is missing")
            alt, i = wire[i], i + 1
        if status & ANNEX_RECORD:
            n = record_length(wire[i]) if i < len(wire) else 0
            if n == 0 or i + n > len(wire):
                raise ProtocolError("a reply's object record is missing or cut short")
            record, i = bytes(wire[i:i + n]), i + n
        status &= ~(ANNEX_ALT | ANNEX_RECORD) & 0xFF  # the 1.1 payload: no REASON without REJECTED
    trunk = bytes(wire[i:])
    out = bytes((head,)) + struct.pack(">hhhhhh", *pose) + bytes((status & ~DELTA_BIT & 0xFF,))
    if trunk:
        img, offset = request
        if offset == NO_IMAGE_DATA:
            raise ProtocolError("a trunk in answer to a poll that asked for no image data")
        if head & 0x80:
            offset = 0
        elif offset == 0:
            raise ProtocolError("a trunk at offset 0 without FIRST")
        out += ((img << 13) | offset).to_bytes(2, "big") + trunk
    elif head & (FIRST_BIT | LAST_BIT):
        raise ProtocolError("a reply's FIRST/LAST need a trunk")  # §1: never chained to
    return out, pose, alt, record


def wish_of(poll11: bytes) -> bytes | None:
    """The VELOCITY body a reply to this version 1.1 poll stands for (§8.1): its
    own, when it is a VELOCITY with ARM and MODE 0 and no axis -128; else none."""
    if poll11[0] & 0x0F != OrderCode.VELOCITY or len(poll11) != POLL_HEADER + 5:
        return None
    body = poll11[POLL_HEADER:]
    return bytes(body) if body[0] == 0 and 0x80 not in body[1:] else None


def continuation_of(reply11: bytes, poll11: bytes | None) -> tuple[int, int]:
    """Where the picture continues after a reply (version 1.1 payload) to the
    poll `poll11`: after its trunk, or the poll's own request when it had none;
    after a SYNC (`poll11` None) nowhere (OFFSET 8191)."""
    if poll11 is None:
        return NO_CONTINUATION
    if len(reply11) > REPLY_HEADER:
        word = (reply11[REPLY_HEADER] << 8) | reply11[REPLY_HEADER + 1]
        img, offset = word >> 13, word & 0x1FFF
        return img, min(offset + len(reply11) - REPLY_IMAGE_HEADER, NO_IMAGE_DATA)
    return _request(poll11)


def reply_frame_cap(size: int, max_frame: int, poll_frame: int = MIN_POLL_FRAME) -> int:
    """The longest reply frame a poll frame of `poll_frame` bytes and SIZE `size`
    allows on a link capped at `max_frame`."""
    cycle = V2_CYCLE[size]
    return min(max_frame, V2_MAX_FRAME) if cycle is None else min(cycle - poll_frame, max_frame, V2_MAX_FRAME)


def trunk_room(size: int, max_frame: int, pose_bytes: int, tag_bytes: int, poll_frame: int = MIN_POLL_FRAME) -> int:
    """Trunk bytes that fit the reply to such a poll with a pose of `pose_bytes`."""
    room = reply_frame_cap(size, max_frame, poll_frame) - V2_OVERHEAD - V2_REPLY_STATUS - pose_bytes - tag_bytes
    return max(0, min(room, MAX_TRUNK))  # MAX_TRUNK: version 1.1's largest, what the machines carry
