"""Payloads of PROTOCOL.md §2–5: the poll (operator → ROV) and the reply.

Goals: one dataclass per thing on the wire, each able to `encode()` itself to
the exact payload bytes and to be rebuilt by `decode(payload)`; an illegal
value, on either path, raises `ProtocolError` with a message naming the field.

Plan: the orders (`Velocity`, `Position`, `ImageSettings`, `Stop`, `NoOrder`,
`ReservedOrder`) validate themselves in `__post_init__`, so a value that could
not be sent can never be constructed.  `Poll` and `Reply` carry the header
fields and delegate the order body to the order classes.

Decisions where PROTOCOL.md is silent (kept strict: a frame whose bits are
not exactly as specified is refused rather than guessed at):
- Reserved bits set (poll bit 6, VELOCITY byte 0 bits 5–3, POSITION flags
  bits 5–0, IMAGE byte 5 bits 2–0, reply byte 13 bits 4–0) are errors.
- VELOCITY MODE 7 (reserved) and ARM 3 are errors, as is -128 in any axis.
- POSITION with BODY but not RELATIVE is an error: a body-frame absolute
  target has no meaning.  Yaw outside -18000..18000 is an error.
- IMAGE: an ROI needs X0 < X1 and Y0 < Y1 (all four zero means none);
  BUDGET above 8189 is an error (an object is at most 8191 bytes).
- Reserved order codes 5–15 decode to `ReservedOrder` with whatever body
  follows: the ROV must answer such a poll and ignore the order.
- Reply: LEN 15 or 16 (image header without a trunk byte) is an error;
  FIRST must equal OFFSET == 0 and LAST must not be set without a trunk;
  angles outside -18000..18000 centidegrees and MODE 8–15 are errors.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass, field
from typing import ClassVar, Union

NO_IMAGE_DATA = 8191  # OFFSET that asks for no image data
MAX_OBJECT = 8191  # bytes in an image object: [N:uint16][N bytes]
MAX_BUDGET = MAX_OBJECT - 2
SIZE_CLASS_BYTES = (24, 48, 96, 239)
REPLY_HEADER = 14  # reply payload bytes without image data
REPLY_IMAGE_HEADER = 16  # reply payload bytes before the trunk


class ProtocolError(ValueError):
    """A payload or a field value that the protocol does not allow."""


class Arm(enum.IntEnum):
    NONE = 0
    ARM = 1
    DISARM = 2


class Mode(enum.IntEnum):
    """Flight modes as the protocol numbers them (requested and reported).

    In a request 0 means "keep"; in a reply 0 means "unknown" and 7 "other".
    """

    KEEP = 0
    MANUAL = 1
    STABILIZE = 2
    DEPTH_HOLD = 3
    POS_HOLD = 4
    GUIDED = 5
    SURFACE = 6
    OTHER = 7

    UNKNOWN = 0  # alias of KEEP, for replies


class OrderCode(enum.IntEnum):
    NONE = 0
    VELOCITY = 1
    POSITION = 2
    IMAGE = 3
    STOP = 4


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
            _check_int(f"VELOCITY {name.upper()}", getattr(self, name), -127, 127)
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
    def decode_body(cls, body: bytes) -> "Velocity":
        if len(body) != 5:
            raise ProtocolError(f"VELOCITY body must be 5 bytes, got {len(body)}")
        flags, vx, vy, vz, vyaw = struct.unpack(">Bbbbb", body)
        arm, reserved, mode = flags >> 6, (flags >> 3) & 0x7, flags & 0x7
        if arm == 3:
            raise ProtocolError("VELOCITY ARM 3 is invalid")
        if reserved:
            raise ProtocolError("VELOCITY byte 0 bits 5-3 are reserved and must be 0")
        if mode == 7:
            raise ProtocolError("VELOCITY MODE 7 is reserved")
        for name, v in (("VX", vx), ("VY", vy), ("VZ", vz), ("VYAW", vyaw)):
            if v == -128:
                raise ProtocolError(f"VELOCITY {name} -128 is invalid")
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
            _check_int(f"POSITION {name}", getattr(self, name), -32768, 32767)
        _check_int("POSITION yaw_cdeg", self.yaw_cdeg, -18000, 18000)
        _check_bool("POSITION relative", self.relative)
        _check_bool("POSITION body", self.body)
        if self.body and not self.relative:
            raise ProtocolError("POSITION BODY is only allowed with RELATIVE")

    def encode_body(self) -> bytes:
        flags = (self.relative << 7) | (self.body << 6)
        return struct.pack(">Bhhhh", flags, self.x_cm, self.y_cm, self.z_cm, self.yaw_cdeg)

    @classmethod
    def decode_body(cls, body: bytes) -> "Position":
        if len(body) != 9:
            raise ProtocolError(f"POSITION body must be 9 bytes, got {len(body)}")
        flags, x, y, z, yaw = struct.unpack(">Bhhhh", body)
        if flags & 0x3F:
            raise ProtocolError("POSITION flags bits 5-0 are reserved and must be 0")
        return cls(x, y, z, yaw, bool(flags & 0x80), bool(flags & 0x40))


@dataclass(frozen=True)
class ImageSettings:
    """One-shot DEBT settings: ROI (x0, y0, x1, y1) or None, SHIFT, MONO, BUDGET."""

    roi: tuple[int, int, int, int] | None = None
    shift: int = 0
    mono: bool = False
    budget_bytes: int = 2000

    code: ClassVar[int] = OrderCode.IMAGE
    one_shot: ClassVar[bool] = True

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
    def decode_body(cls, body: bytes) -> "ImageSettings":
        if len(body) != 8:
            raise ProtocolError(f"IMAGE body must be 8 bytes, got {len(body)}")
        packed = int.from_bytes(body[:5], "big")
        roi = ((packed >> 30) & 0x3FF, (packed >> 20) & 0x3FF, (packed >> 10) & 0x3FF, packed & 0x3FF)
        flags, budget = struct.unpack(">BH", body[5:])
        if flags & 0x07:
            raise ProtocolError("IMAGE byte 5 bits 2-0 are reserved and must be 0")
        return cls(roi, flags >> 4, bool(flags & 0x08), budget)


@dataclass(frozen=True)
class Stop:
    code: ClassVar[int] = OrderCode.STOP
    one_shot: ClassVar[bool] = True

    def encode_body(self) -> bytes:
        return b""

    @classmethod
    def decode_body(cls, body: bytes) -> "Stop":
        if body:
            raise ProtocolError(f"STOP takes no body, got {len(body)} bytes")
        return cls()


@dataclass(frozen=True)
class ReservedOrder:
    """An order code 5..15: answered and ignored by the ROV."""

    order_code: int
    body: bytes = b""

    one_shot: ClassVar[bool] = False

    def __post_init__(self) -> None:
        _check_int("reserved ORDER", self.order_code, 5, 15)

    @property
    def code(self) -> int:  # type: ignore[override]
        return self.order_code

    def encode_body(self) -> bytes:
        return bytes(self.body)


Order = Union[NoOrder, Velocity, Position, ImageSettings, Stop, ReservedOrder]
ONE_SHOT_ORDERS = (Position, ImageSettings, Stop)

_ORDER_CLASSES = {c.code: c for c in (NoOrder, Velocity, Position, ImageSettings, Stop)}


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
        if not isinstance(self.order, (NoOrder, Velocity, Position, ImageSettings, Stop, ReservedOrder)):
            raise ProtocolError(f"poll order must be an order dataclass, got {self.order!r}")

    @property
    def wants_image(self) -> bool:
        return self.offset != NO_IMAGE_DATA

    def encode(self) -> bytes:
        head = (self.seq << 7) | (self.size << 4) | self.order.code
        return bytes((head,)) + ((self.img << 13) | self.offset).to_bytes(2, "big") + self.order.encode_body()

    @classmethod
    def decode(cls, payload: bytes) -> "Poll":
        seq, size, code, img, offset = cls.decode_header(payload)
        body = bytes(payload[3:])
        if code in _ORDER_CLASSES:
            order: Order = _ORDER_CLASSES[code].decode_body(body)
        else:
            order = ReservedOrder(code, body)
        return cls(seq, size, order, img, offset)

    @staticmethod
    def decode_header(payload: bytes) -> tuple[int, int, int, int, int]:
        """(SEQ, SIZE, ORDER code, IMG, OFFSET) of a poll, without its body.

        Lets the ROV answer a poll whose order body is invalid (it must answer
        and ignore such an order) while refusing a poll whose header is bad.
        """
        if len(payload) < 3:
            raise ProtocolError(f"poll payload must be at least 3 bytes, got {len(payload)}")
        head = payload[0]
        if head & 0x40:
            raise ProtocolError("poll byte 0 bit 6 is reserved and must be 0")
        request = (payload[1] << 8) | payload[2]
        return head >> 7, (head >> 4) & 0x3, head & 0xF, request >> 13, request & 0x1FFF


# --------------------------------------------------------------------------
# Reply
# --------------------------------------------------------------------------


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

    def __post_init__(self) -> None:
        _check_int("reply ACK", self.ack, 0, 1)
        _check_bool("reply ARMED", self.armed)
        _check_int("reply MODE", self.mode, 0, 7)
        for name in ("x_cm", "y_cm", "z_cm"):
            _check_int(f"reply {name}", getattr(self, name), -32768, 32767)
        for name in ("roll_cdeg", "pitch_cdeg", "yaw_cdeg"):
            _check_int(f"reply {name}", getattr(self, name), -18000, 18000)
        for name in ("autopilot", "failsafe", "position_valid", "last"):
            _check_bool(f"reply {name}", getattr(self, name))
        if not isinstance(self.trunk, (bytes, bytearray)):
            raise ProtocolError("reply trunk must be bytes")
        object.__setattr__(self, "trunk", bytes(self.trunk))
        if self.trunk:
            _check_int("reply IMG", self.img, 0, 7)
            _check_int("reply OFFSET", self.offset, 0, MAX_OBJECT - 1)
            if self.offset + len(self.trunk) > MAX_OBJECT:
                raise ProtocolError(
                    f"reply trunk of {len(self.trunk)} bytes at OFFSET {self.offset} runs past the "
                    f"{MAX_OBJECT}-byte object limit"
                )
            if len(self.trunk) > 255 - REPLY_IMAGE_HEADER:
                raise ProtocolError(f"reply trunk must be at most {255 - REPLY_IMAGE_HEADER} bytes")
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

    def encode(self) -> bytes:
        head = (self.first << 7) | (self.last << 6) | (self.ack << 5) | (self.armed << 4) | self.mode
        status = (self.autopilot << 7) | (self.failsafe << 6) | (self.position_valid << 5)
        out = bytes((head,)) + struct.pack(
            ">hhhhhhB", self.x_cm, self.y_cm, self.z_cm, self.roll_cdeg, self.pitch_cdeg, self.yaw_cdeg, status
        )
        if self.trunk:
            out += ((self.img << 13) | self.offset).to_bytes(2, "big") + self.trunk
        return out

    @classmethod
    def decode(cls, payload: bytes) -> "Reply":
        n = len(payload)
        if n < REPLY_HEADER:
            raise ProtocolError(f"reply payload must be at least {REPLY_HEADER} bytes, got {n}")
        if REPLY_HEADER < n <= REPLY_IMAGE_HEADER:
            raise ProtocolError(f"reply of {n} bytes has an image header but no trunk byte")
        head = payload[0]
        first, last, ack, armed, mode = head >> 7, (head >> 6) & 1, (head >> 5) & 1, (head >> 4) & 1, head & 0xF
        if mode > 7:
            raise ProtocolError(f"reply MODE {mode} is reserved")
        x, y, z, roll, pitch, yaw, status = struct.unpack(">hhhhhhB", payload[1:14])
        if status & 0x1F:
            raise ProtocolError("reply byte 13 bits 4-0 are reserved and must be 0")
        img = offset = None
        trunk = b""
        if n > REPLY_HEADER:
            request = (payload[14] << 8) | payload[15]
            img, offset = request >> 13, request & 0x1FFF
            trunk = bytes(payload[16:])
            if bool(first) != (offset == 0):
                raise ProtocolError(f"reply FIRST={first} disagrees with OFFSET {offset}")
        elif first:
            raise ProtocolError("reply FIRST needs a trunk")
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
            img=img,
            offset=offset,
            trunk=trunk,
            last=bool(last),
        )


def size_class_for(trunk_bytes: int) -> int:
    """The smallest SIZE class whose trunk holds `trunk_bytes` (3 if none does)."""
    for size, cap in enumerate(SIZE_CLASS_BYTES):
        if trunk_bytes <= cap:
            return size
    return 3
