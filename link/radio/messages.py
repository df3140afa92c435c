"""Payloads of docs/PROTOCOL.md §2–5: the poll (operator → ROV) and the reply.

Goals: one dataclass per thing on the wire, each able to `encode()` itself to
the exact payload bytes and to be rebuilt by `decode(payload)`; an illegal
value, on either path, raises `ProtocolError` with a message naming the field.

Plan: the orders (`Velocity`, `Position`, `ImageSettings`, `Stop`, `NoOrder`,
`ReservedOrder`) validate themselves in `__post_init__`, so a value that could
not be sent can never be constructed.  `Poll` and `Reply` carry the header
fields and delegate the order body to the order classes.

Two kinds of bad payload (docs/PROTOCOL.md §1 (1.1)):
- A structural fault raises `ProtocolError` (the receiver counts it and
  ignores the frame): a body length that does not match its ORDER, a
  reserved bit set (poll bit 6 in 1.1, VELOCITY byte 0 bits 5–3, POSITION
  flags bits 5–0, IMAGE byte 5 bits 2–0), a reserved order's body over 9
  bytes, a reply payload of 15 or 16 bytes, FIRST/LAST without a trunk,
  FIRST with an OFFSET other than 0, a trunk past byte 8190, SYNC set in 1.1.
- A well-formed order with a value out of range decodes to `InvalidOrder`
  (the ROV answers the poll and rejects the order, REASON 0): VELOCITY -128,
  ARM 3 or MODE 7; POSITION BODY without RELATIVE or a YAW outside
  -18000..18000; IMAGE X1 <= X0 or Y1 <= Y0 (unless all four are zero),
  BUDGET above 8189.  The order dataclasses refuse such values when built.

Decisions where docs/PROTOCOL.md is silent (kept strict: a frame whose bits are
not exactly as specified is refused rather than guessed at):
- Reply: a trunk at OFFSET 0 without FIRST is a structural fault too (§5:
  FIRST is set exactly when the trunk starts at offset 0).  An angle outside
  -18000..18000 centidegrees is a value out of range, not a fault (§5): the
  reply decodes with ATTITUDE_VALID cleared and roll, pitch and yaw 0 (the
  attitude is unknown), the rest of it used.  REASON 3, or a REASON without
  REJECTED, decodes as it is (shown as unknown, not an error).
- Reserved order codes 6–15 decode to `ReservedOrder` with the body that
  follows (at most 9 bytes).

FOLLOW (ORDER 5, docs/PROTOCOL.md §10) is IMAGE settings whose ROI follows its
content: `FollowSettings`, an `ImageSettings` (the slave takes it as one), and
each picture coded under it starts its stream with a `TrackRecord`.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass, field
from typing import ClassVar, Union

from ..vocabulary import REQUESTABLE_MODES, FollowRequest, Mode, PictureRequest, TrackState  # noqa: F401 (the radio names them here too)
from .frame import MAX_PAYLOAD, OVERHEAD

NO_IMAGE_DATA = 8191  # OFFSET that asks for no image data
MAX_OBJECT = 8191  # bytes in an image object: [N:uint16][N bytes]
OBJECT_LENGTH_BYTES = 2  # the object's length field, before its DEBT stream
MAX_BUDGET = MAX_OBJECT - OBJECT_LENGTH_BYTES
IMG_IDS = 8  # IMG is 3 bits: images are numbered 0..7, then 0 again
SIZE_CLASS_BYTES = (24, 48, 96, 239)
POLL_HEADER = 3  # poll payload bytes before the order's body
HELLO_BIT = 0x40  # poll byte 0, bit 6: a HELLO in version 2 (§8), a structural fault in 1.1
ORDER_BITS = 0x0F  # poll byte 0: the ORDER code
REPLY_HEADER = 14  # reply payload bytes without image data
REPLY_IMAGE_HEADER = 16  # reply payload bytes before the trunk
FAILSAFE_S = 3.0  # §3: the ROV with no poll this long brakes and holds (its default)
VELOCITY_LAPSE_S = 1.5  # §5: a VELOCITY the ROV applies lapses after this long without another
MIN_FRAME = OVERHEAD + REPLY_IMAGE_HEADER + 1  # the smallest frame a link may cap at: a reply with a 1-byte trunk
MAX_TRUNK = MAX_PAYLOAD - REPLY_IMAGE_HEADER
REPLY_STATUS_BYTE = 13  # AUTOPILOT FAILSAFE POSITION_VALID ATTITUDE_VALID REJECTED REASON(2) SYNC
ATTITUDE_VALID_BIT = 0x10
SYNC_BIT = 0x01  # version 2 only (§8)
XYZ_CM = (-32768, 32767)  # a position's range on the wire, both ways
VELOCITY_FULL = 127  # a VELOCITY axis at the vehicle's maximum speed (-127..127; -128 is invalid)
ANGLE_CDEG = (-18000, 18000)  # a yaw or an attitude angle's range


def next_img(img: int) -> int:
    """The IMG after `img` (they wrap)."""
    return (img + 1) % IMG_IDS


def is_sync(reply_payload: bytes) -> bool:
    """Whether a reply payload has SYNC set (version 2's answer to a HELLO)."""
    return len(reply_payload) > REPLY_STATUS_BYTE and bool(reply_payload[REPLY_STATUS_BYTE] & SYNC_BIT)


class ProtocolError(ValueError):
    """A payload or a field value that the protocol does not allow."""


class Arm(enum.IntEnum):
    NONE = 0
    ARM = 1
    DISARM = 2


class OrderCode(enum.IntEnum):
    NONE = 0
    VELOCITY = 1
    POSITION = 2
    IMAGE = 3
    STOP = 4
    FOLLOW = 5  # §10: IMAGE settings whose ROI follows its content


def _check_int(name: str, value: object, lo: int, hi: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ProtocolError(f"{name} must be an integer, got {value!r}")
    if not lo <= value <= hi:
        raise ProtocolError(f"{name} must be in {lo}..{hi}, got {value}")


def _check_bool(name: str, value: object) -> None:
    if not isinstance(value, bool):
        raise ProtocolError(f"{name} must be a bool, got {value!r}")


# --------------------------------------------------------------------------
# Orders
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class NoOrder:
    code: ClassVar[int] = OrderCode.NONE
    one_shot: ClassVar[bool] = False

    def encode_body(self) -> bytes:
        return b""

    @classmethod
    def decode_body(cls, body: bytes) -> "NoOrder":
        if body:
            raise ProtocolError(f"NONE order takes no body, got {len(body)} bytes")
        return cls()


@dataclass(frozen=True)
class Velocity:
    """Soft-state velocity wish, -127..127 per axis (percent of the maximum x 1.27).

    Body frame: vx forward, vy right, vz down, vyaw clockwise from above.
    """

    vx: int = 0
    vy: int = 0
    vz: int = 0
    vyaw: int = 0
    arm: Arm = Arm.NONE
    mode: Mode = Mode.KEEP

    code: ClassVar[int] = OrderCode.VELOCITY
    one_shot: ClassVar[bool] = False

    def __post_init__(self) -> None:
        for name in ("vx", "vy", "vz", "vyaw"):
            _check_int(f"VELOCITY {name.upper()}", getattr(self, name), -VELOCITY_FULL, VELOCITY_FULL)
        _check_int("VELOCITY ARM", self.arm, 0, 2)
        _check_int("VELOCITY MODE", self.mode, 0, 6)
        object.__setattr__(self, "arm", Arm(self.arm))
        object.__setattr__(self, "mode", Mode(self.mode))

    @property
    def is_neutral(self) -> bool:
        return self.vx == self.vy == self.vz == self.vyaw == 0

    def encode_body(self) -> bytes:
        return struct.pack(">Bbbbb", (self.arm << 6) | self.mode, self.vx, self.vy, self.vz, self.vyaw)

    @classmethod
    def decode_body(cls, body: bytes) -> "Velocity | InvalidOrder":
        if len(body) != 5:
            raise ProtocolError(f"VELOCITY body must be 5 bytes, got {len(body)}")
        flags, vx, vy, vz, vyaw = struct.unpack(">Bbbbb", body)
        arm, reserved, mode = flags >> 6, (flags >> 3) & 0x7, flags & 0x7
        if reserved:
            raise ProtocolError("VELOCITY byte 0 bits 5-3 are reserved and must be 0")
        if arm == 3:
            return InvalidOrder(cls.code, bytes(body), "VELOCITY ARM 3 is invalid")
        if mode == 7:
            return InvalidOrder(cls.code, bytes(body), "VELOCITY MODE 7 is reserved")
        for name, v in (("VX", vx), ("VY", vy), ("VZ", vz), ("VYAW", vyaw)):
            if v == -128:
                return InvalidOrder(cls.code, bytes(body), f"VELOCITY {name} -128 is invalid")
        return cls(vx, vy, vz, vyaw, Arm(arm), Mode(mode))


@dataclass(frozen=True)
class Position:
    """One-shot position target: centimetres and centidegrees (local NED)."""

    x_cm: int
    y_cm: int
    z_cm: int
    yaw_cdeg: int = 0
    relative: bool = False
    body: bool = False

    code: ClassVar[int] = OrderCode.POSITION
    one_shot: ClassVar[bool] = True

    def __post_init__(self) -> None:
        for name in ("x_cm", "y_cm", "z_cm"):
            _check_int(f"POSITION {name}", getattr(self, name), *XYZ_CM)
        _check_int("POSITION yaw_cdeg", self.yaw_cdeg, *ANGLE_CDEG)
        _check_bool("POSITION relative", self.relative)
        _check_bool("POSITION body", self.body)
        if self.body and not self.relative:
            raise ProtocolError("POSITION BODY is only allowed with RELATIVE")

    def encode_body(self) -> bytes:
        flags = (self.relative << 7) | (self.body << 6)
        return struct.pack(">Bhhhh", flags, self.x_cm, self.y_cm, self.z_cm, self.yaw_cdeg)

    @classmethod
    def decode_body(cls, body: bytes) -> "Position | InvalidOrder":
        if len(body) != 9:
            raise ProtocolError(f"POSITION body must be 9 bytes, got {len(body)}")
        flags, x, y, z, yaw = struct.unpack(">Bhhhh", body)
        if flags & 0x3F:
            raise ProtocolError("POSITION flags bits 5-0 are reserved and must be 0")
        try:
            return cls(x, y, z, yaw, bool(flags & 0x80), bool(flags & 0x40))
        except ProtocolError as exc:  # BODY without RELATIVE, YAW out of range
            return InvalidOrder(cls.code, bytes(body), str(exc))


@dataclass(frozen=True)
class ImageSettings(PictureRequest):
    """The IMAGE order: a picture request (link/vocabulary.py) as the radio carries it,
    one-shot DEBT settings: ROI (x0, y0, x1, y1) or None, SHIFT, MONO, BUDGET."""

    code: ClassVar[int] = OrderCode.IMAGE
    one_shot: ClassVar[bool] = True
    follow: ClassVar[bool] = False  # the ROI stays where it is in the picture

    def __post_init__(self) -> None:
        if self.roi is not None:
            if not isinstance(self.roi, tuple) or len(self.roi) != 4:
                raise ProtocolError(f"IMAGE roi must be a tuple (x0, y0, x1, y1), got {self.roi!r}")
            for name, v in zip(("X0", "Y0", "X1", "Y1"), self.roi):
                _check_int(f"IMAGE ROI {name}", v, 0, 1023)
            x0, y0, x1, y1 = self.roi
            if (x0, y0, x1, y1) == (0, 0, 0, 0):
                object.__setattr__(self, "roi", None)
            elif not (x0 < x1 and y0 < y1):
                raise ProtocolError(f"IMAGE ROI needs X0 < X1 and Y0 < Y1, got {self.roi}")
        _check_int("IMAGE SHIFT", self.shift, 0, 15)
        _check_bool("IMAGE MONO", self.mono)
        _check_int("IMAGE BUDGET", self.budget_bytes, 0, MAX_BUDGET)

    def encode_body(self) -> bytes:
        x0, y0, x1, y1 = self.roi or (0, 0, 0, 0)
        packed = (x0 << 30) | (y0 << 20) | (x1 << 10) | y1
        return packed.to_bytes(5, "big") + struct.pack(">BH", (self.shift << 4) | (self.mono << 3), self.budget_bytes)

    @classmethod
    def decode_body(cls, body: bytes) -> "ImageSettings | InvalidOrder":
        if len(body) != 8:
            raise ProtocolError(f"IMAGE body must be 8 bytes, got {len(body)}")
        packed = int.from_bytes(body[:5], "big")
        roi = ((packed >> 30) & 0x3FF, (packed >> 20) & 0x3FF, (packed >> 10) & 0x3FF, packed & 0x3FF)
        flags, budget = struct.unpack(">BH", body[5:])
        if flags & 0x07:
            raise ProtocolError("IMAGE byte 5 bits 2-0 are reserved and must be 0")
        try:
            return cls(roi, flags >> 4, bool(flags & 0x08), budget)
        except ProtocolError as exc:  # empty ROI, BUDGET over 8189
            return InvalidOrder(cls.code, bytes(body), str(exc))


@dataclass(frozen=True)
class Stop:
    """Not sequenced (1.1): carries SEQ = ACK and never flips ACK (§2)."""

    code: ClassVar[int] = OrderCode.STOP
    one_shot: ClassVar[bool] = False

    def encode_body(self) -> bytes:
        return b""

    @classmethod
    def decode_body(cls, body: bytes) -> "Stop":
        if body:
            raise ProtocolError(f"STOP takes no body, got {len(body)} bytes")
        return cls()


@dataclass(frozen=True)
class FollowSettings(ImageSettings, FollowRequest):
    """FOLLOW (§10): a follow request (link/vocabulary.py) as the radio carries it:
    IMAGE settings whose ROI follows what it framed in picture `drawn_on` (its IMG);
    `keep`: a lost track keeps its last ROI, else the pictures go without one until
    it holds again."""

    code: ClassVar[int] = OrderCode.FOLLOW
    follow: ClassVar[bool] = True

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.roi is None:
            raise ProtocolError("FOLLOW needs an ROI to follow")
        _check_bool("FOLLOW KEEP", self.keep)
        _check_int("FOLLOW IMG", self.drawn_on, 0, IMG_IDS - 1)

    def encode_body(self) -> bytes:
        return super().encode_body() + bytes(((self.keep << 7) | self.drawn_on,))

    @classmethod
    def decode_body(cls, body: bytes) -> "FollowSettings | InvalidOrder":
        if len(body) != 9:
            raise ProtocolError(f"FOLLOW body must be 9 bytes, got {len(body)}")
        if body[8] & 0x78:
            raise ProtocolError("FOLLOW byte 8 bits 6-3 are reserved and must be 0")
        settings = ImageSettings.decode_body(body[:8])
        if isinstance(settings, InvalidOrder):
            return InvalidOrder(cls.code, bytes(body), settings.why)
        try:
            return cls(settings.roi, settings.shift, settings.mono, settings.budget_bytes,
                       keep=bool(body[8] & 0x80), drawn_on=body[8] & 0x07)
        except ProtocolError as exc:  # no ROI
            return InvalidOrder(cls.code, bytes(body), str(exc))


TRACK_MAGIC = 0b0110  # a stream's first four bits: a TRACK record, never a DEBT header's (debt/header.py MAGIC)
TRACK_RECORD_BYTES = 2
TRACK_LOST_FOR_MAX_DS = 255  # LOST_FOR saturates: 25.5 s or more


@dataclass(frozen=True)
class TrackRecord:
    """The track as the ROV saw it when it captured a picture coded under FOLLOW:
    [0110:4][STATE:2][KEEP:1][0:1] [LOST_FOR:8, tenths of a second]."""

    state: int = TrackState.HOLDS
    keep: bool = True
    lost_for_ds: int = 0

    def __post_init__(self) -> None:
        _check_int("TRACK STATE", int(self.state), 0, 3)
        _check_bool("TRACK KEEP", self.keep)
        _check_int("TRACK LOST_FOR", self.lost_for_ds, 0, TRACK_LOST_FOR_MAX_DS)

    @property
    def lost_for_s(self) -> float:
        return self.lost_for_ds / 10.0

    def encode(self) -> bytes:
        return bytes(((TRACK_MAGIC << 4) | (int(self.state) << 2) | (self.keep << 1), self.lost_for_ds))

    @classmethod
    def decode(cls, data: bytes) -> "TrackRecord":
        if len(data) < TRACK_RECORD_BYTES or data[0] >> 4 != TRACK_MAGIC:
            raise ProtocolError("not a TRACK record")
        if data[0] & 0x01:
            raise ProtocolError("TRACK byte 0 bit 0 is reserved and must be 0")
        return cls((data[0] >> 2) & 0x3, bool(data[0] & 0x02), data[1])


def split_track(stream: bytes) -> tuple[TrackRecord | None, bytes]:
    """A picture's stream as (its TRACK record or None, its DEBT stream).  A record
    cut short or with its reserved bit set is left in the stream (the picture then
    does not decode: it is not one this page describes)."""
    if len(stream) >= TRACK_RECORD_BYTES and stream[0] >> 4 == TRACK_MAGIC:
        try:
            return TrackRecord.decode(stream[:TRACK_RECORD_BYTES]), bytes(stream[TRACK_RECORD_BYTES:])
        except ProtocolError:
            pass
    return None, bytes(stream)


MAX_RESERVED_BODY = 9
MAX_POLL_PAYLOAD = POLL_HEADER + MAX_RESERVED_BODY  # the largest poll: a POSITION (9) or a reserved order


@dataclass(frozen=True)
class ReservedOrder:
    """An order code 6..15 with a body of 0..9 bytes: a one-shot the ROV rejects (REASON 0)."""

    order_code: int
    body: bytes = b""

    one_shot: ClassVar[bool] = True

    def __post_init__(self) -> None:
        _check_int("reserved ORDER", self.order_code, 6, 15)
        if not isinstance(self.body, (bytes, bytearray)):
            raise ProtocolError("reserved order body must be bytes")
        object.__setattr__(self, "body", bytes(self.body))
        if len(self.body) > MAX_RESERVED_BODY:
            raise ProtocolError(f"reserved order body must be at most {MAX_RESERVED_BODY} bytes, got {len(self.body)}")

    @property
    def code(self) -> int:  # type: ignore[override]
        return self.order_code

    def encode_body(self) -> bytes:
        return bytes(self.body)


@dataclass(frozen=True)
class InvalidOrder:
    """A well-formed order body with a value out of range (§1, §3): decoded, never built by a sender.

    For VELOCITY the wish is invalid (neutral, no ARM/MODE action, does not feed
    the failsafe); for a one-shot order the ROV rejects it with REASON 0.
    """

    order_code: int
    body: bytes
    why: str

    @property
    def code(self) -> int:
        return self.order_code

    @property
    def one_shot(self) -> bool:
        return self.order_code not in (OrderCode.NONE, OrderCode.VELOCITY, OrderCode.STOP)

    def encode_body(self) -> bytes:
        return bytes(self.body)


Order = Union[NoOrder, Velocity, Position, ImageSettings, Stop, ReservedOrder, InvalidOrder]

_ORDER_CLASSES = {c.code: c for c in (NoOrder, Velocity, Position, ImageSettings, Stop, FollowSettings)}


# --------------------------------------------------------------------------
# Poll
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class Poll:
    """Operator → ROV: the token, with one order and one image request."""

    seq: int = 0
    size: int = 0
    order: Order = field(default_factory=NoOrder)
    img: int = 0
    offset: int = NO_IMAGE_DATA

    def __post_init__(self) -> None:
        _check_int("poll SEQ", self.seq, 0, 1)
        _check_int("poll SIZE", self.size, 0, 3)
        _check_int("poll IMG", self.img, 0, 7)
        _check_int("poll OFFSET", self.offset, 0, NO_IMAGE_DATA)
        if not isinstance(self.order, (NoOrder, Velocity, Position, ImageSettings, Stop, ReservedOrder, InvalidOrder)):
            raise ProtocolError(f"poll order must be an order dataclass, got {self.order!r}")

    @property
    def wants_image(self) -> bool:
        return self.offset != NO_IMAGE_DATA

    @property
    def order_key(self) -> tuple[int, bytes]:
        """What tells one order from another for the supersede rule (§3): ORDER and body."""
        return (self.order.code, self.order.encode_body())

    def encode(self) -> bytes:
        head = (self.seq << 7) | (self.size << 4) | self.order.code
        return bytes((head,)) + ((self.img << 13) | self.offset).to_bytes(2, "big") + self.order.encode_body()

    @classmethod
    def decode(cls, payload: bytes) -> "Poll":
        seq, size, code, img, offset = cls.decode_header(payload)
        body = bytes(payload[POLL_HEADER:])
        if code in _ORDER_CLASSES:
            order: Order = _ORDER_CLASSES[code].decode_body(body)
        else:
            order = ReservedOrder(code, body)
        return cls(seq, size, order, img, offset)

    @staticmethod
    def decode_header(payload: bytes) -> tuple[int, int, int, int, int]:
        """(SEQ, SIZE, ORDER code, IMG, OFFSET) of a poll, without its body.

        Bit 6 (HELLO in version 2) is a structural fault in version 1.1.
        """
        if len(payload) < POLL_HEADER:
            raise ProtocolError(f"poll payload must be at least {POLL_HEADER} bytes, got {len(payload)}")
        head = payload[0]
        if head & HELLO_BIT:
            raise ProtocolError("poll byte 0 bit 6 (HELLO) must be 0 in version 1.1")
        request = (payload[1] << 8) | payload[2]
        return head >> 7, (head >> 4) & 0x3, head & ORDER_BITS, request >> 13, request & 0x1FFF


# --------------------------------------------------------------------------
# Reply
# --------------------------------------------------------------------------


class Reason(enum.IntEnum):
    """REASON of a rejected order (§3, §5)."""

    INVALID = 0  # invalid body or reserved order code
    IMPOSSIBLE = 1  # impossible now: no position estimate, no autopilot, disarmed; abandoned by STOP/failsafe
    REFUSED = 2  # the autopilot refused, or gave no answer within 2 s
    UNKNOWN = 3  # reserved: shown as unknown


REASON_TEXT = {
    Reason.INVALID: "invalid order",
    Reason.IMPOSSIBLE: "impossible now",
    Reason.REFUSED: "refused by the autopilot",
    Reason.UNKNOWN: "unknown reason",
}


@dataclass(frozen=True)
class Reply:
    """ROV → operator: odometry, status and optionally a trunk of an image object."""

    ack: int = 0
    armed: bool = False
    mode: int = Mode.UNKNOWN
    x_cm: int = 0
    y_cm: int = 0
    z_cm: int = 0
    roll_cdeg: int = 0
    pitch_cdeg: int = 0
    yaw_cdeg: int = 0
    autopilot: bool = False
    failsafe: bool = False
    position_valid: bool = False
    img: int | None = None
    offset: int | None = None
    trunk: bytes = b""
    last: bool = False
    hold: bool = False  # (1.1) non-zero velocity ignored until a neutral wish
    attitude_valid: bool = False  # (1.1) roll/pitch/yaw from the autopilot, < 1 s old
    rejected: bool = False  # (1.1) the order named by ACK was rejected ...
    reason: int = 0  # (1.1) ... for this REASON (meaningful only with `rejected`)
    sync: bool = False  # version 2 only (§8); a structural fault in 1.1

    def __post_init__(self) -> None:
        _check_int("reply ACK", self.ack, 0, 1)
        _check_bool("reply ARMED", self.armed)
        _check_int("reply MODE", self.mode, 0, 7)
        for name in ("x_cm", "y_cm", "z_cm"):
            _check_int(f"reply {name}", getattr(self, name), *XYZ_CM)
        for name in ("roll_cdeg", "pitch_cdeg", "yaw_cdeg"):
            _check_int(f"reply {name}", getattr(self, name), *ANGLE_CDEG)
        for name in ("autopilot", "failsafe", "position_valid", "last", "hold", "attitude_valid", "rejected", "sync"):
            _check_bool(f"reply {name}", getattr(self, name))
        _check_int("reply REASON", self.reason, 0, 3)
        if not isinstance(self.trunk, (bytes, bytearray)):
            raise ProtocolError("reply trunk must be bytes")
        object.__setattr__(self, "trunk", bytes(self.trunk))
        if self.trunk:
            _check_int("reply IMG", self.img, 0, 7)
            _check_int("reply OFFSET", self.offset, 0, MAX_OBJECT - 1)
            if self.offset + len(self.trunk) > MAX_OBJECT:
                raise ProtocolError(
                    f"reply trunk of {len(self.trunk)} bytes at OFFSET {self.offset} runs past the "
                    f"object's last byte ({MAX_OBJECT - 1})"
                )
            if len(self.trunk) > MAX_TRUNK:
                raise ProtocolError(f"reply trunk must be at most {MAX_TRUNK} bytes")
        else:
            if self.img is not None or self.offset is not None:
                raise ProtocolError("reply IMG/OFFSET need a trunk of at least one byte")
            if self.last:
                raise ProtocolError("reply LAST needs a trunk")

    @property
    def first(self) -> bool:
        return bool(self.trunk) and self.offset == 0

    @property
    def has_trunk(self) -> bool:
        return bool(self.trunk)

    @property
    def rejection(self) -> "Reason | None":
        """The REASON of a rejection this reply reports (UNKNOWN for 3), None without REJECTED."""
        return Reason(self.reason) if self.rejected else None

    def encode(self) -> bytes:
        head = (
            (self.first << 7) | (self.last << 6) | (self.ack << 5) | (self.armed << 4) | (self.hold << 3) | self.mode
        )
        status = (
            (self.autopilot << 7)
            | (self.failsafe << 6)
            | (self.position_valid << 5)
            | (self.attitude_valid << 4)
            | (self.rejected << 3)
            | (self.reason << 1)
            | self.sync
        )
        out = bytes((head,)) + struct.pack(
            ">hhhhhhB", self.x_cm, self.y_cm, self.z_cm, self.roll_cdeg, self.pitch_cdeg, self.yaw_cdeg, status
        )
        if self.trunk:
            out += ((self.img << 13) | self.offset).to_bytes(2, "big") + self.trunk
        return out

    @classmethod
    def decode(cls, payload: bytes, *, allow_sync: bool = False) -> "Reply":
        """Parse a reply payload; `allow_sync` only for version 2 (SYNC is a fault in 1.1)."""
        n = len(payload)
        if n < REPLY_HEADER:
            raise ProtocolError(f"reply payload must be at least {REPLY_HEADER} bytes, got {n}")
        if REPLY_HEADER < n <= REPLY_IMAGE_HEADER:
            raise ProtocolError(f"reply of {n} bytes has an image header but no trunk byte")
        head = payload[0]
        first, last, ack, armed, hold, mode = (
            head >> 7, (head >> 6) & 1, (head >> 5) & 1, (head >> 4) & 1, (head >> 3) & 1, head & 0x7
        )
        x, y, z, roll, pitch, yaw, status = struct.unpack(">hhhhhhB", payload[1:REPLY_HEADER])
        if any(not ANGLE_CDEG[0] <= a <= ANGLE_CDEG[1] for a in (roll, pitch, yaw)):
            # §5: out of range is not a fault: the attitude is unknown, the rest stands.
            roll = pitch = yaw = 0
            status &= ~ATTITUDE_VALID_BIT & 0xFF
        if status & SYNC_BIT and not allow_sync:
            raise ProtocolError("reply SYNC must be 0 in version 1.1")
        img = offset = None
        trunk = b""
        if n > REPLY_HEADER:
            request = (payload[REPLY_HEADER] << 8) | payload[REPLY_HEADER + 1]
            img, offset = request >> 13, request & 0x1FFF
            trunk = bytes(payload[REPLY_IMAGE_HEADER:])
            if bool(first) != (offset == 0):
                raise ProtocolError(f"reply FIRST={first} disagrees with OFFSET {offset}")
        elif first or last:
            raise ProtocolError("reply FIRST/LAST need a trunk")
        return cls(
            ack=ack,
            armed=bool(armed),
            mode=mode,
            x_cm=x,
            y_cm=y,
            z_cm=z,
            roll_cdeg=roll,
            pitch_cdeg=pitch,
            yaw_cdeg=yaw,
            autopilot=bool(status & 0x80),
            failsafe=bool(status & 0x40),
            position_valid=bool(status & 0x20),
            attitude_valid=bool(status & 0x10),
            rejected=bool(status & 0x08),
            reason=(status >> 1) & 0x3,
            sync=bool(status & SYNC_BIT),
            img=img,
            offset=offset,
            trunk=trunk,
            last=bool(last),
            hold=bool(hold),
        )
