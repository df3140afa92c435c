"""The bodies of the acoustic profile's frames (§9.3, §9.4), as on the wire: each
encodes and decodes itself and says what is invalid in it."""

from __future__ import annotations

import struct
from dataclasses import dataclass

from ..vocabulary import Mode
from .wire import BITMAP_BITS, FAILSAFE_HOLD, FAILSAFE_S, MAX_BUDGET, MAX_SLOTS, MIN_BUDGET, OP_MODE, OP_NAMES, THUMB_H, THUMB_W

# ---------------------------------------------------------------------------
# Bodies
# ---------------------------------------------------------------------------


def _bit(value: int, n: int) -> bool:
    return bool(value >> n & 1)


@dataclass(frozen=True)
class PollBody:
    """Uplink KIND 1: keepalive, the thumbnail receiver's state and the STATUS
    the operator holds."""

    t: int = 0
    lowest_missing: int = MAX_SLOTS
    have_end: bool = True
    bitmap: int = 0  # bit 18 = IDX lowest+1 ... bit 0 = IDX lowest+19
    have_status: bool = False  # HELD names the full STATUS of this session the operator holds
    held: int = 0  # its counter's low 4 bits

    def encode(self) -> bytes:
        rest = self.have_status << 23 | self.held << BITMAP_BITS | self.bitmap
        return bytes([self.t << 7 | self.lowest_missing << 1 | int(self.have_end)]) + rest.to_bytes(3, "big")

    @classmethod
    def decode(cls, body: bytes) -> PollBody:
        rest = int.from_bytes(body[1:4], "big")
        return cls(body[0] >> 7, body[0] >> 1 & 63, bool(body[0] & 1), rest & (1 << BITMAP_BITS) - 1,
                   bool(rest >> 23), rest >> BITMAP_BITS & 15)

    def window_end(self) -> int:
        """The first IDX past what this POLL tells."""
        return self.lowest_missing + 1 + BITMAP_BITS

    def held_packets(self, count: int) -> set[int]:
        held = set(range(min(self.lowest_missing, count)))
        for k in range(BITMAP_BITS):
            i = self.lowest_missing + 1 + k
            if i < count and self.bitmap >> (BITMAP_BITS - 1 - k) & 1:
                held.add(i)
        return held


@dataclass(frozen=True)
class StopBody:
    """Uplink KIND 2."""

    stop_no: int
    last_oid_issued: int

    def encode(self) -> bytes:
        return bytes([self.stop_no, self.last_oid_issued, 0, 0])

    @classmethod
    def decode(cls, body: bytes) -> StopBody:
        return cls(body[0], body[1])  # reserved bytes ignored: a STOP is a STOP


@dataclass(frozen=True)
class OrderBody:
    """Uplink KIND 3: HOLD, SURFACE, ARM, DISARM or MODE (ARG = §2's mode number)."""

    oid: int
    op: int
    arg: int = 0

    def encode(self) -> bytes:
        return struct.pack(">BBH", self.oid, self.op, self.arg)

    @classmethod
    def decode(cls, body: bytes) -> OrderBody:
        return cls(*struct.unpack(">BBH", body))

    def invalid(self) -> str | None:
        if self.op not in OP_NAMES:
            return f"unknown op {self.op}"
        if self.op == OP_MODE:
            if not Mode.MANUAL <= self.arg <= Mode.SURFACE:
                return f"mode {self.arg} is no mode to ask for"
        elif self.arg:
            return "ARG set on an op without one"
        return None


@dataclass(frozen=True)
class GoToBody:
    """Uplink KIND 4 (2 packets): a target, absolute in local NED or relative."""

    oid: int
    x_dm: int
    y_dm: int
    z_dm: int
    yaw_cdeg: int = 0
    relative: bool = False
    body_frame: bool = False
    yaw_set: bool = False
    reserved: int = 0  # the 5 low FLAGS bits and the last 2 bytes, as received

    def encode(self) -> bytes:
        flags = self.relative << 7 | self.body_frame << 6 | self.yaw_set << 5
        return struct.pack(">BBhhhh", self.oid, flags, self.x_dm, self.y_dm, self.z_dm, self.yaw_cdeg) + b"\0\0"

    @classmethod
    def decode(cls, body: bytes) -> GoToBody:
        oid, flags, x, y, z, yaw = struct.unpack(">BBhhhh", body[:10])
        reserved = (flags & 0x1F) | int.from_bytes(body[10:12], "big")
        return cls(oid, x, y, z, yaw, _bit(flags, 7), _bit(flags, 6), _bit(flags, 5), reserved)

    def invalid(self) -> str | None:
        if self.reserved:
            return "reserved bits set"
        if self.body_frame and not self.relative:
            return "BODY without RELATIVE"
        if not -18000 <= self.yaw_cdeg <= 18000:
            return "yaw out of range"
        if self.yaw_cdeg and not self.yaw_set:
            return "yaw given without YAW_SET"
        return None


@dataclass(frozen=True)
class ThumbRequest:
    """Uplink KIND 5 (2 packets): the DEBT settings of one 80x60 thumbnail, and
    whether its ROI follows its object (FOLLOW, §10's over this profile)."""

    oid: int
    budget: int = 198
    roi: tuple[int, int, int, int] = (0, 0, 0, 0)  # thumbnail pixels, (x1, y1) exclusive; all 0: none
    shift: int = 0
    mono: bool = True
    reserved: int = 0
    follow: bool = False  # the ROI follows what it framed in thumbnail DRAWN_ON
    keep: bool = False  # while the track is lost: the last ROI (1) or none (0)
    drawn_on: int = 0  # the OID of the THUMB whose thumbnail the ROI was drawn on; 0: none

    def encode(self) -> bytes:
        flags = self.shift << 4 | self.mono << 3 | self.follow << 2 | self.keep << 1
        return struct.pack(">B4BBHB", self.oid, *self.roi, flags, self.budget, self.drawn_on) + bytes(3)

    @classmethod
    def decode(cls, body: bytes) -> ThumbRequest:
        oid, x0, y0, x1, y1, sm, budget, drawn_on = struct.unpack(">B4BBHB", body[:9])
        reserved = (sm & 1) | int.from_bytes(body[9:12], "big")
        return cls(oid, budget, (x0, y0, x1, y1), sm >> 4, _bit(sm, 3), reserved, _bit(sm, 2), _bit(sm, 1), drawn_on)

    def invalid(self) -> str | None:
        if self.reserved:
            return "reserved bits set"
        if not MIN_BUDGET <= self.budget <= MAX_BUDGET:
            return f"BUDGET outside {MIN_BUDGET}..{MAX_BUDGET}"
        x0, y0, x1, y1 = self.roi
        if any(self.roi) and (x1 <= x0 or y1 <= y0 or x0 >= THUMB_W or y0 >= THUMB_H):
            return "empty ROI"
        if self.follow and not any(self.roi):
            return "FOLLOW without an ROI"
        if not self.follow and (self.keep or self.drawn_on):
            return "KEEP or DRAWN_ON without FOLLOW"
        return None

    def clipped_roi(self) -> tuple[int, int, int, int] | None:
        if not any(self.roi):
            return None
        x0, y0, x1, y1 = self.roi
        return (x0, y0, min(x1, THUMB_W), min(y1, THUMB_H))


@dataclass(frozen=True)
class SyncBody:
    """Downlink KIND 0 (2 packets): the answer to a fresh HELLO."""

    boot: bytes
    nonce: bytes
    failsafe_s: int = FAILSAFE_S
    failsafe_action: int = FAILSAFE_HOLD

    def encode(self) -> bytes:
        return self.boot + self.nonce + struct.pack(">HBB", self.failsafe_s, self.failsafe_action, 0)

    @classmethod
    def decode(cls, body: bytes) -> SyncBody:
        fs, action, _ = struct.unpack(">HBB", body[8:12])
        return cls(bytes(body[0:4]), bytes(body[4:8]), fs, action)


@dataclass(frozen=True)
class StatusBody:
    """Downlink KIND 1 (2 packets), as on the wire."""

    x_dm: int = 0
    y_dm: int = 0
    z_dm: int = 0
    heading_cdeg: int = 0
    armed: bool = False
    hold: bool = False
    failsafe: bool = False
    position_valid: bool = False
    attitude_valid: bool = False
    autopilot: bool = False
    going: bool = False
    uplink: bool = False
    mode: int = 0
    result: int = 0
    stop_no2: int = 0
    battery_dv: int = 0
    oid: int = 0

    def encode(self) -> bytes:
        flags = (self.armed << 7 | self.hold << 6 | self.failsafe << 5 | self.position_valid << 4
                 | self.attitude_valid << 3 | self.autopilot << 2 | self.going << 1 | self.uplink)
        return struct.pack(">hhhHBBBB", self.x_dm, self.y_dm, self.z_dm, self.heading_cdeg, flags,
                           self.mode << 5 | self.result << 2 | self.stop_no2, self.battery_dv, self.oid)

    @classmethod
    def decode(cls, body: bytes) -> StatusBody:
        x, y, z, heading, f, m, battery, oid = struct.unpack(">hhhHBBBB", body)
        attitude_valid = _bit(f, 3)
        if heading > 35999:  # a value out of its range: the heading is unknown
            heading, attitude_valid = 0, False
        return cls(x, y, z, heading, _bit(f, 7), _bit(f, 6), _bit(f, 5), _bit(f, 4), attitude_valid, _bit(f, 2),
                   _bit(f, 1), _bit(f, 0), m >> 5, m >> 2 & 7, m & 3, battery, oid)


def same_body(ref: int, status_body: bytes) -> bytes:
    """STATUS_SAME's BODY: REF, then the STATUS bytes 8, 9 and 11 (flags, mode,
    result, STOP_NO, OID) as they are now."""
    return bytes([ref & 255, status_body[8], status_body[9], status_body[11]])


def steady_bytes(status_body: bytes) -> bytes:
    """What STATUS_SAME says is unchanged: X, Y, Z, HEADING and BATTERY."""
    return status_body[0:8] + status_body[10:11]


def renewed_body(full_body: bytes, same: bytes) -> bytes:
    """The STATUS a STATUS_SAME stands for, given the full one it names."""
    return full_body[0:8] + same[1:3] + full_body[10:11] + same[3:4]


@dataclass(frozen=True)
class ThumbEnd:
    """Downlink KIND 2: the thumbnail's object MAC."""

    oid: int
    object_mac: bytes

    def encode(self) -> bytes:
        return bytes([self.oid]) + self.object_mac

    @classmethod
    def decode(cls, body: bytes) -> ThumbEnd:
        return cls(body[0], bytes(body[1:4]))


def thumbnail_object(obj: bytes) -> tuple[int, bytes] | None:
    """A thumbnail object as it came (§9.3: `[N:2]` then N bytes of its stream, a TRACK
    record first under FOLLOW): (N, the stream so far), or None before N is in."""
    if len(obj) < 2:
        return None
    return int.from_bytes(obj[:2], "big"), bytes(obj[2:])
