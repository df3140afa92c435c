"""The acoustic profile (docs/PROTOCOL.md §9): supervisory control over a
Water Linked Modem-M64, 8-byte packets, one a second each way, without I/O.

Goals: STOP reaches the ROV at the first slot the modem gives, ahead of
anything queued, every time; each order runs exactly once and its fate is
shown; the pilot's status is a few seconds old and says how old; a DEBT
thumbnail refines as it comes and is shown verified only once its object
MAC holds; every control frame is authenticated (a 3-byte tag) and a
replayed or held-back one is refused; a silent uplink brings the vehicle to
a hold (or the surface).

Plan: two sans-I/O machines over the same packet layer.

- `AcousticRov` (the ROV's end): `receive(packet, now) -> events`,
  `next_packet(now) -> bytes | None` (call it when the modem's transmit
  queue is empty; flush the modem first when `wants_flush`), `tick(now) ->
  events` (failsafe), `update_status(VehicleState)`, `order_outcome(oid,
  result)`, `thumbnail_ready(oid, object)`.  Events: `Stop`, `Hold`,
  `Surface`, `Arm`, `Disarm`, `SetMode`, `GoToWanted`, `ThumbnailWanted`,
  `FailsafeEntered`, `FailsafeCleared`, `SessionStarted`.
- `AcousticOperator` (the console's end): `stop(now) -> STOP number`,
  `cancel_stop()`, `send_order(body, now) -> OID`, `next_packet(now)`,
  `wants_flush`, `receive(packet, now) -> events`, `tick(now) -> events`,
  `next_status_at`.  Events: `Synced`, `StatusReceived`, `OrderFate`,
  `StopConfirmed`, `StopNotCarriedOut`, `ThumbnailProgress`,
  `ThumbnailComplete`, `ThumbnailRejected`, `InauthenticPacket`,
  `Resyncing`.

Packets: a control frame is 1 packet (header, 4-byte BODY, 3-byte TAG) or 2
(header, 12-byte BODY, TAG: 16 bytes split 8/8), the number fixed by KIND
and direction; a thumbnail data packet (ROV -> operator) is `[1][T][IDX:6]`
and 7 object bytes.  The second packet of a frame carries no marker: a
receiver holding a first half tries the pair, and when its tag fails takes
the new packet as a start (so a lost first half costs one frame, never two).

Decisions where the brief was silent (all written into §9):
- The operator's HELLO every 8 s until a SYNC (a HELLO/SYNC round takes up
  to about 7 s on the M64), counted from when it left the modem (issue 33:
  a second HELLO crossed the first SYNC); the ROV flushes its queue for a SYNC.
- FLAGS bit 0 of STATUS is UPLINK: the ROV took an authentic frame of this
  session within 10 s.  An operator that hears UPLINK 0 re-HELLOs: a gap of
  16 lost uplink frames cannot otherwise be noticed while the downlink works.
- The ROV fills every slot it has nothing else for with a STATUS (the turns
  pass anyway; the air is free); the 5 s period applies while a thumbnail is
  being sent.
- Consecutive THUMB orders never share T: the operator skips one OID when
  the next one has the previous thumbnail's low bit.
- The operator keeps up to 3 distinct candidates for each thumbnail slot (a
  lost first half makes its continuation look like data) and tries their
  combinations (at most 64) against THUMB_END's MAC.
- A frame whose packet would be all zero is sealed again with the next
  counter.
- STATUS_SAME (issue 24): a STATUS whose position, heading and battery are
  those of a full STATUS the operator's POLL says it holds goes as one packet
  naming it; the operator takes it only naming a full STATUS it kept.  The ROV
  never names a full STATUS a flush may have cut short (issue 33).
- Issue 33: no failsafe before a session's first frame (the start's brake
  holds); after a new STOP or the failsafe the STATUS waits up to 1.5 s for the
  vehicle to report the brake's mode, and GOING is never set beside HOLD; a
  first half whose pair fails counts as an inauthentic packet.
"""

from __future__ import annotations

import collections
import hmac
import itertools
import os
import struct
from dataclasses import dataclass, field, replace
from typing import Callable

from .auth import mac
from .messages import Mode

PACKET_BYTES = 8
TAG_BYTES = 3
CHALLENGE_BYTES = 4
BOOT_BYTES = 4
NONCE_BYTES = 4
SHORT_BODY = 4  # a 1-packet frame's BODY
LONG_BODY = 12  # a 2-packet frame's BODY
DATA_BYTES = 7  # object bytes in a thumbnail data packet
MAX_SLOTS = 63  # IDX 0..62; LOWEST_MISSING 63 means "all" for a full object
MAX_OBJECT = MAX_SLOTS * DATA_BYTES  # 441 bytes: [N:2] + at most 439 bytes of DEBT
MAX_BUDGET = MAX_OBJECT - 2
MIN_BUDGET = 10  # a DEBT header with an ROI (5 without)
THUMB_W, THUMB_H = 80, 60
CTR_WINDOW = 16
BITMAP_BITS = 19  # a POLL's bitmap: IDX LOWEST_MISSING+1 .. LOWEST_MISSING+19
SAME_REACH = 15  # a STATUS_SAME names a full STATUS at most this many counters below its own

LABEL_HELLO, LABEL_SYNC, LABEL_UP, LABEL_DOWN, LABEL_THUMB = b"AH", b"AS", b"AU", b"AD", b"AT"

# KINDs by direction, and how many packets each frame takes.
UP_HELLO, UP_POLL, UP_STOP, UP_ORDER, UP_GOTO, UP_THUMB = 0, 1, 2, 3, 4, 5
DOWN_SYNC, DOWN_STATUS, DOWN_THUMB_END, DOWN_STATUS_SAME = 0, 1, 2, 3
UP_PACKETS = {UP_HELLO: 1, UP_POLL: 1, UP_STOP: 1, UP_ORDER: 1, UP_GOTO: 2, UP_THUMB: 2}
DOWN_PACKETS = {DOWN_SYNC: 2, DOWN_STATUS: 2, DOWN_THUMB_END: 1, DOWN_STATUS_SAME: 1}

# ORDER ops.
OP_HOLD, OP_SURFACE, OP_ARM, OP_DISARM, OP_MODE = 1, 2, 3, 4, 5
OP_NAMES = {OP_HOLD: "hold", OP_SURFACE: "surface", OP_ARM: "arm", OP_DISARM: "disarm", OP_MODE: "mode"}

# STATUS RESULT for the OID it names.
R_NONE, R_TAKEN, R_DONE, R_INVALID, R_IMPOSSIBLE, R_REFUSED, R_CANCELLED, R_ABORTED = range(8)
RESULT_STATE = {
    R_NONE: ("unknown", "the ROV has no outcome for it"),
    R_TAKEN: ("taken", "running"),
    R_DONE: ("done", ""),
    R_INVALID: ("rejected", "invalid"),
    R_IMPOSSIBLE: ("rejected", "impossible now"),
    R_REFUSED: ("rejected", "refused by the autopilot"),
    R_CANCELLED: ("cancelled", "cancelled by STOP (never taken)"),
    R_ABORTED: ("aborted", "aborted"),
}

FAILSAFE_HOLD, FAILSAFE_SURFACE = 0, 1
FAILSAFE_S = 60
HELLO_EVERY_S = 8.0  # the operator's re-HELLO while no SYNC comes
SILENCE_RESYNC_S = 20.0  # nothing heard this long (no authentic frame, no data for the thumbnail wanted): HELLO again
AUTHENTIC_RESYNC_S = 40.0  # no authentic frame this long, data or not: HELLO again
UPLINK_FRESH_S = 10.0  # STATUS UPLINK: an authentic uplink frame taken this recently
STATUS_IDLE_S = 4.0  # at least this often with no thumbnail being sent (in fact every free slot)
STATUS_THUMB_S = 5.0  # at least this often while a thumbnail is being sent: the status first (issue 24: under 10 s old)
STATUS_REPEAT_S = 3.0  # a repeated order/STOP gets a prompt STATUS if none started this long ago
IN_FLIGHT_S = 4.5  # a data packet handed this long before a POLL arrived is reflected in it
STATUS_TRANSIT_S = 3.0  # the operator dates a STATUS this long before its arrival
SAME_TRANSIT_S = 2.5  # ... and a STATUS_SAME (one packet) this long
KEEP_HELLOS = 4
BRAKE_SHOWN_S = 1.5  # a STATUS after a STOP or the failsafe waits this long at most for the brake to show
HOLD_MODES = (Mode.POS_HOLD, Mode.DEPTH_HOLD)
CHALLENGES_SEEN = 4096
SLOT_CANDIDATES = 3
MAX_COMBINATIONS = 64
ALERT_COUNT, ALERT_WINDOW_S, ALERT_QUIET_S = 4, 30.0, 10.0


class OrderRefused(ValueError):
    """An order the operator cannot send now (no status yet, a STOP unconfirmed)."""


# ---------------------------------------------------------------------------
# Bodies
# ---------------------------------------------------------------------------


def _bit(value: int, n: int) -> bool:
    return bool(value >> n & 1)


@dataclass(frozen=True)
class Poll:
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
    def decode(cls, body: bytes) -> Poll:
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
class Order:
    """Uplink KIND 3: HOLD, SURFACE, ARM, DISARM or MODE (ARG = §2's mode number)."""

    oid: int
    op: int
    arg: int = 0

    def encode(self) -> bytes:
        return struct.pack(">BBH", self.oid, self.op, self.arg)

    @classmethod
    def decode(cls, body: bytes) -> Order:
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
class GoTo:
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
    def decode(cls, body: bytes) -> GoTo:
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
    """Uplink KIND 5 (2 packets): the DEBT settings of one 80x60 thumbnail."""

    oid: int
    budget: int = 198
    roi: tuple[int, int, int, int] = (0, 0, 0, 0)  # thumbnail pixels, (x1, y1) exclusive; all 0: none
    shift: int = 0
    mono: bool = True
    reserved: int = 0

    def encode(self) -> bytes:
        return struct.pack(">B4BBH", self.oid, *self.roi, self.shift << 4 | self.mono << 3, self.budget) + bytes(4)

    @classmethod
    def decode(cls, body: bytes) -> ThumbRequest:
        oid, x0, y0, x1, y1, sm, budget = struct.unpack(">B4BBH", body[:8])
        reserved = (sm & 7) | int.from_bytes(body[8:12], "big")
        return cls(oid, budget, (x0, y0, x1, y1), sm >> 4, _bit(sm, 3), reserved)

    def invalid(self) -> str | None:
        if self.reserved:
            return "reserved bits set"
        if not MIN_BUDGET <= self.budget <= MAX_BUDGET:
            return f"BUDGET outside {MIN_BUDGET}..{MAX_BUDGET}"
        x0, y0, x1, y1 = self.roi
        if any(self.roi) and (x1 <= x0 or y1 <= y0 or x0 >= THUMB_W or y0 >= THUMB_H):
            return "empty ROI"
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
class Status:
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
    def decode(cls, body: bytes) -> Status:
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


# ---------------------------------------------------------------------------
# Packets
# ---------------------------------------------------------------------------


def header(kind: int, ctr: int) -> int:
    return kind << 4 | ctr & 15


def _split(frame: bytes) -> list[bytes]:
    return [frame[i:i + PACKET_BYTES] for i in range(0, len(frame), PACKET_BYTES)]


def control_tag(key: bytes, label: bytes, session: bytes, ctr: int, hdr: int, body: bytes) -> bytes:
    return mac(key, label, session, ctr.to_bytes(4, "big") + bytes([hdr]) + body)[:TAG_BYTES]


def seal_control(key: bytes, label: bytes, session: bytes, ctr: int, kind: int, body: bytes) -> list[bytes]:
    hdr = header(kind, ctr)
    return _split(bytes([hdr]) + body + control_tag(key, label, session, ctr, hdr, body))


def seal_hello(key: bytes, challenge: bytes) -> bytes:
    return bytes([0]) + challenge + mac(key, LABEL_HELLO, b"", bytes([0]) + challenge)[:TAG_BYTES]


def seal_sync(key: bytes, challenge: bytes, body: SyncBody) -> list[bytes]:
    raw = body.encode()
    return _split(bytes([0]) + raw + mac(key, LABEL_SYNC, challenge, bytes([0]) + raw)[:TAG_BYTES])


def data_packet(t: int, idx: int, chunk: bytes) -> bytes:
    return bytes([0x80 | t << 6 | idx]) + chunk.ljust(DATA_BYTES, b"\0")


def object_mac(key: bytes, session: bytes, oid: int, obj: bytes) -> bytes:
    return mac(key, LABEL_THUMB, session, bytes([oid]) + obj)[:TAG_BYTES]


def slot_count(obj_len: int) -> int:
    return -(-obj_len // DATA_BYTES)


def _next_counter(last: int, low: int) -> int:
    """The one counter in (last, last + 16] whose low 4 bits are `low`."""
    return last + 1 + ((low - (last + 1)) % CTR_WINDOW)


def _ahead(a: int, b: int) -> int:
    """How far OID a is ahead of b (mod 256)."""
    return (a - b) % 256


@dataclass
class Counters:
    packets: int = 0
    frames_taken: int = 0
    bad_size: int = 0
    all_zero: int = 0
    bad_kind: int = 0  # a KIND this direction does not use, or data in the uplink
    inauthentic: int = 0  # no counter in the window (or no session) makes its tag hold
    unpaired: int = 0  # a first half whose pair failed (its second half lost, or noise): inauthentic too
    hellos: int = 0
    replayed_hellos: int = 0
    stale_syncs: int = 0
    data_packets: int = 0
    data_ignored: int = 0  # not for the thumbnail wanted
    thumbnails_verified: int = 0
    thumbnail_mismatches: int = 0
    statuses_same: int = 0  # STATUS_SAME sent (ROV) or taken (operator)
    same_unmatched: int = 0  # a STATUS_SAME naming a full STATUS the operator does not hold
    fulls_flushed: int = 0  # (ROV) full STATUSes a flush may have cut short: never named by a STATUS_SAME
    orders_taken: int = 0
    orders_stale: int = 0  # not 1..127 ahead of the last OID (repeats among them)
    stops_taken: int = 0
    failsafes: int = 0
    resyncs: int = 0


class _End:
    """What both ends share: a session, counters each way, and the pairing of halves."""

    direction_in: dict[int, int]
    label_in: bytes
    label_out: bytes

    def __init__(self, key: bytes, random_bytes: Callable[[int], bytes]) -> None:
        if len(key) != 32:
            raise ValueError("a link key is 32 bytes")
        self.key = bytes(key)
        self._random = random_bytes
        self.session: bytes | None = None
        self.rx_last = -1
        self.tx_ctr = 0
        self._half: bytes | None = None
        self._out: list[bytes] = []  # packets of a frame still to hand the modem
        self._last_handed = ""  # what the last frame handed was
        self.counters = Counters()

    def _nonzero_random(self, n: int) -> bytes:
        while True:
            value = self._random(n)
            if any(value):
                return value

    def _new_session(self, session: bytes) -> None:
        self.session = session
        self.rx_last = -1
        self.tx_ctr = 0
        self._half = None
        self._out = []

    def _seal(self, kind: int, body: bytes) -> tuple[int, list[bytes]]:
        assert self.session is not None
        while True:
            ctr = self.tx_ctr
            self.tx_ctr += 1
            packets = seal_control(self.key, self.label_out, self.session, ctr, kind, body)
            if all(any(p) for p in packets):  # never an all-zero packet: seal with the next counter
                return ctr, packets

    def _emit_frame(self, packets: list[bytes], what: str = "") -> bytes:
        self._out = packets[1:]
        self._last_handed = what
        return packets[0]

    def receive(self, packet: bytes, now: float) -> list:
        """Take one packet from the modem; returns the events it causes."""
        events: list = self._drain()
        self.counters.packets += 1
        if len(packet) != PACKET_BYTES:
            self.counters.bad_size += 1
            return events
        packet = bytes(packet)
        if not any(packet):
            self.counters.all_zero += 1
            return events
        if self._half is not None:
            first, self._half = self._half, None
            if self._open(first + packet, now, events):
                return events
            self.counters.unpaired += 1
            self._inauthentic(now, events)  # §9.1 (decided): a first half dropped is an inauthentic packet
        if packet[0] & 0x80:
            self._data(packet, now, events)
            return events
        kind = packet[0] >> 4 & 7
        n = self.direction_in.get(kind)
        if n is None:
            self.counters.bad_kind += 1
        elif n == 2:
            self._half = packet
        elif not self._open(packet, now, events):
            self._inauthentic(now, events)
        return events

    def _open(self, frame: bytes, now: float, events: list) -> bool:
        hdr, body, tag = frame[0], frame[1:-TAG_BYTES], frame[-TAG_BYTES:]
        kind = hdr >> 4 & 7
        if kind == 0:
            return self._open_session_frame(hdr, body, tag, now, events)
        if self.session is None:
            return False
        ctr = _next_counter(self.rx_last, hdr & 15)
        if not hmac.compare_digest(control_tag(self.key, self.label_in, self.session, ctr, hdr, body), tag):
            return False
        self.rx_last = ctr
        self.counters.frames_taken += 1
        self._frame(kind, body, ctr, now, events)
        return True

    def _inauthentic(self, now: float, events: list) -> None:
        self.counters.inauthentic += 1

    # Subclasses.
    def _drain(self) -> list:
        return []

    def _data(self, packet: bytes, now: float, events: list) -> None:
        self.counters.bad_kind += 1

    def _open_session_frame(self, hdr: int, body: bytes, tag: bytes, now: float, events: list) -> bool:
        raise NotImplementedError

    def _frame(self, kind: int, body: bytes, ctr: int, now: float, events: list) -> None:
        raise NotImplementedError


# ---------------------------------------------------------------------------
# The ROV's end
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class VehicleState:
    """What the node knows of the vehicle (update_status)."""

    x_m: float = 0.0
    y_m: float = 0.0
    z_m: float = 0.0
    heading_deg: float = 0.0
    armed: bool = False
    mode: int = Mode.UNKNOWN
    position_valid: bool = False
    attitude_valid: bool = False
    autopilot: bool = False
    going: bool = False  # a go-to is being flown
    battery_v: float = 0.0  # 0: unknown


@dataclass(frozen=True)
class Stop:
    stop_no: int | None  # None: the brake at start
    new: bool = True  # False: a repeat of the STOP last taken (brake again, idempotent)


@dataclass(frozen=True)
class Hold:
    oid: int


@dataclass(frozen=True)
class Surface:
    oid: int


@dataclass(frozen=True)
class Arm:
    oid: int


@dataclass(frozen=True)
class Disarm:
    oid: int


@dataclass(frozen=True)
class SetMode:
    oid: int
    mode: int


@dataclass(frozen=True)
class GoToWanted:
    oid: int
    target: GoTo


@dataclass(frozen=True)
class ThumbnailWanted:
    oid: int
    settings: ThumbRequest


@dataclass(frozen=True)
class FailsafeEntered:
    action: int  # FAILSAFE_HOLD or FAILSAFE_SURFACE


@dataclass(frozen=True)
class FailsafeCleared:
    pass


@dataclass(frozen=True)
class SessionStarted:
    challenge: bytes


MOTION_OPS = (OP_HOLD, OP_SURFACE, OP_MODE)


@dataclass
class _Thumb:
    oid: int
    obj: bytes | None = None
    sent_at: dict[int, float] = field(default_factory=dict)
    acked: set[int] = field(default_factory=set)
    poll_at: float = -1e9
    end_sent_at: float | None = None
    operator_has_end: bool = False
    done: bool = False
    window_end: int = MAX_SLOTS  # the last POLL told of IDX below this

    @property
    def t(self) -> int:
        return self.oid & 1

    @property
    def count(self) -> int:
        return slot_count(len(self.obj)) if self.obj is not None else 0


class AcousticRov(_End):
    direction_in = UP_PACKETS
    label_in = LABEL_UP
    label_out = LABEL_DOWN

    def __init__(self, key: bytes, *, failsafe_s: int = FAILSAFE_S, failsafe_action: int = FAILSAFE_HOLD,
                 boot: bytes | None = None, random_bytes: Callable[[int], bytes] = os.urandom,
                 status_thumb_s: float = STATUS_THUMB_S) -> None:
        super().__init__(key, random_bytes)
        if not 1 <= failsafe_s <= 65535:
            raise ValueError("FAILSAFE_S is 1..65535 seconds")
        if failsafe_action not in (FAILSAFE_HOLD, FAILSAFE_SURFACE):
            raise ValueError("the failsafe action is 0 (hold) or 1 (surface)")
        self.failsafe_s = failsafe_s
        self.failsafe_action = failsafe_action
        self.status_thumb_s = status_thumb_s
        self.boot = boot if boot is not None else self._nonzero_random(BOOT_BYTES)
        if len(self.boot) != BOOT_BYTES or not any(self.boot):
            raise ValueError("BOOT is 4 bytes, not all zero")
        self.vehicle = VehicleState()
        self.challenge: bytes | None = None
        self._seen: collections.deque[bytes] = collections.deque()
        self._seen_set: set[bytes] = set()
        self._sync_due: SyncBody | None = None
        self._sync_taken = True
        self.wants_flush = False
        self.last_oid = 0
        self.result = R_NONE
        self._last_op: int | None = None  # what the last OID was (op number, or the KIND for GOTO/THUMB)
        self.last_stop_no = 0
        self.hold = True  # braked at start
        self.failsafe = False
        self._failsafe_unreported = False
        self._heard_at: float | None = None  # last authentic frame of a session taken: the failsafe's timer
        # A STOP or the failsafe braked at this time: its STATUS waits for the vehicle
        # to report one of these modes (or BRAKE_SHOWN_S), so that it tells the brake.
        self._brake_asked: tuple[float, tuple[int, ...]] | None = None
        self._session_at: float | None = None
        self._started = False
        self._status_asap = False
        self._status_at = -1e9  # when the last STATUS's first packet was handed
        self.status_sent: dict[int, float] = {}  # CTR -> when made (the last 64), for diagnostics and the bench
        self._fulls: dict[int, bytes] = {}  # full STATUSes sealed lately: CTR -> BODY
        # The full STATUS whose packets were the last handed: until another packet is
        # handed (the modem's queue was then empty) one of them may still wait there.
        self._full_leaving: int | None = None
        self._operator_holds: tuple[int, float] | None = None  # the last POLL's HELD (with HAVE_STATUS), when taken
        self.thumb: _Thumb | None = None
        self._events: list = []

    # -- the node's side -------------------------------------------------------

    def update_status(self, state: VehicleState) -> None:
        self.vehicle = state

    def order_outcome(self, oid: int, result: int) -> None:
        """The vehicle's answer for order `oid`: R_DONE, R_IMPOSSIBLE, R_REFUSED or R_ABORTED."""
        if oid == self.last_oid and self.result == R_TAKEN and result != R_TAKEN:
            self.result = result
            self._prompt()

    def thumbnail_ready(self, oid: int, obj: bytes) -> None:
        if len(obj) > MAX_OBJECT or len(obj) < 2:
            raise ValueError(f"a thumbnail object is 2..{MAX_OBJECT} bytes")
        if self.thumb is not None and self.thumb.oid == oid and self.thumb.obj is None:
            self.thumb.obj = bytes(obj)

    def status(self, now: float) -> Status:
        v = self.vehicle
        since = max(t for t in (self._heard_at, self._session_at, -1e18) if t is not None)
        uplink = now - since < UPLINK_FRESH_S  # a session's start counts: its HELLO was heard
        return Status(
            x_dm=_clamp16(v.x_m * 10), y_dm=_clamp16(v.y_m * 10), z_dm=_clamp16(v.z_m * 10),
            heading_cdeg=int(round(v.heading_deg * 100)) % 36000,
            armed=v.armed, hold=self.hold, failsafe=self.failsafe or self._failsafe_unreported,
            position_valid=v.position_valid, attitude_valid=v.attitude_valid, autopilot=v.autopilot,
            going=v.going and not self.hold, uplink=uplink, mode=int(v.mode) & 7, result=self.result, stop_no2=self.last_stop_no & 3,
            battery_dv=max(0, min(255, int(round(v.battery_v * 10)))), oid=self.last_oid)

    # -- time ------------------------------------------------------------------

    def tick(self, now: float) -> list:
        events = self._drain()
        if not self._started:
            self._started = True
            events.append(Stop(None))
        # §9.4 (decided): no failsafe before a session's first frame: the start's brake holds.
        if not self.failsafe and self._heard_at is not None and now - self._heard_at >= self.failsafe_s:
            self.failsafe = True
            self._failsafe_unreported = True
            self.hold = True
            self._abort_motion()
            self.counters.failsafes += 1
            self._prompt()
            self._brake_asked = (now, (Mode.SURFACE,) if self.failsafe_action == FAILSAFE_SURFACE else HOLD_MODES)
            events.append(FailsafeEntered(self.failsafe_action))
        return events

    @property
    def failsafe_at(self) -> float | None:
        if self.failsafe or self._heard_at is None:
            return None
        return self._heard_at + self.failsafe_s

    def _drain(self) -> list:
        events, self._events = self._events, []
        return events

    # -- receiving -------------------------------------------------------------

    def _open_session_frame(self, hdr: int, body: bytes, tag: bytes, now: float, events: list) -> bool:
        if hdr != 0 or len(body) != CHALLENGE_BYTES or not any(body):
            return False
        if not hmac.compare_digest(mac(self.key, LABEL_HELLO, b"", bytes([0]) + body)[:TAG_BYTES], tag):
            return False
        challenge = bytes(body)
        if challenge in self._seen_set:
            self.counters.replayed_hellos += 1
            return True  # authentic, answered once already: nothing more
        self._seen.append(challenge)
        self._seen_set.add(challenge)
        if len(self._seen) > CHALLENGES_SEEN:
            self._seen_set.discard(self._seen.popleft())
        self.counters.hellos += 1
        nonce = self._nonzero_random(NONCE_BYTES)
        self.challenge = challenge
        self._session_at = now
        self._new_session(challenge + self.boot + nonce)
        self.status_sent = {}  # counters start again
        self._fulls = {}
        self._full_leaving = None
        self._operator_holds = None
        self._sync_due = SyncBody(self.boot, nonce, self.failsafe_s, self.failsafe_action)
        self._sync_taken = False  # repeated in every slot until a frame of the session is taken
        self.wants_flush = True
        events.append(SessionStarted(challenge))
        return True

    def _frame(self, kind: int, body: bytes, ctr: int, now: float, events: list) -> None:
        self._heard_at = now
        self._sync_taken = True
        if self.failsafe:
            self.failsafe = False
            events.append(FailsafeCleared())
        if kind == UP_POLL:
            self._poll(Poll.decode(body), now)
        elif kind == UP_STOP:
            self._stop(StopBody.decode(body), now, events)
        elif kind == UP_ORDER:
            self._order(Order.decode(body), now, events)
        elif kind == UP_GOTO:
            self._order(GoTo.decode(body), now, events)
        elif kind == UP_THUMB:
            self._order(ThumbRequest.decode(body), now, events)

    def _stop(self, stop: StopBody, now: float, events: list) -> None:
        self.counters.stops_taken += 1
        new = stop.stop_no != self.last_stop_no
        self.last_stop_no = stop.stop_no
        self.hold = True
        if 1 <= _ahead(stop.last_oid_issued, self.last_oid) <= 127:
            self.last_oid = stop.last_oid_issued  # an order held back can never run after the STOP
            self.result = R_CANCELLED
            self._last_op = None
        else:
            self._abort_motion()
        if new:
            self._prompt()  # the confirming STATUS goes first
            self._brake_asked = (now, HOLD_MODES)
        elif now - self._status_at >= STATUS_REPEAT_S:
            self._status_asap = True
        events.append(Stop(stop.stop_no, new))

    def _prompt(self) -> None:
        """A STATUS at once: a half-sent one (older news) and whatever waits in the
        modem are dropped, unless it is a SYNC."""
        self._status_asap = True
        if self._last_handed != "sync":
            self._out = []
            self.wants_flush = True
            if self._full_leaving is not None:
                # §9.4 (decided): a STATUS_SAME never names a STATUS whose packets did not all leave.
                self._fulls.pop(self._full_leaving, None)
                self._full_leaving = None
                self.counters.fulls_flushed += 1

    def _abort_motion(self) -> None:
        if self.result == R_TAKEN and self._last_op in (*MOTION_OPS, UP_GOTO):
            self.result = R_ABORTED

    def _order(self, order: Order | GoTo | ThumbRequest, now: float, events: list) -> None:
        d = _ahead(order.oid, self.last_oid)
        if not 1 <= d <= 127:
            self.counters.orders_stale += 1
            if d == 0 and now - self._status_at >= STATUS_REPEAT_S:
                self._status_asap = True  # its confirmation may have been lost
            return
        self.counters.orders_taken += 1
        self.last_oid = order.oid
        self._prompt()
        if isinstance(order, GoTo):
            self._last_op = UP_GOTO
        elif isinstance(order, ThumbRequest):
            self._last_op = UP_THUMB
        else:
            self._last_op = order.op
        if order.invalid() is not None:
            self.result = R_INVALID
            return
        v = self.vehicle
        impossible = not v.autopilot
        if isinstance(order, GoTo):
            impossible |= not v.armed or not v.position_valid
        elif isinstance(order, Order) and order.op == OP_MODE:
            impossible |= order.arg in (Mode.POS_HOLD, Mode.GUIDED) and not v.position_valid
        elif isinstance(order, ThumbRequest):
            impossible = False
        if impossible:
            self.result = R_IMPOSSIBLE
            return
        self.result = R_TAKEN
        if isinstance(order, GoTo):
            self.hold = False
            events.append(GoToWanted(order.oid, order))
        elif isinstance(order, ThumbRequest):
            self.thumb = _Thumb(order.oid)
            events.append(ThumbnailWanted(order.oid, order))
        else:
            if order.op in (OP_SURFACE, OP_MODE):
                self.hold = False
            events.append({OP_HOLD: lambda: Hold(order.oid), OP_SURFACE: lambda: Surface(order.oid),
                           OP_ARM: lambda: Arm(order.oid), OP_DISARM: lambda: Disarm(order.oid),
                           OP_MODE: lambda: SetMode(order.oid, order.arg)}[order.op]())

    def _poll(self, poll: Poll, now: float) -> None:
        self._operator_holds = (poll.held, now) if poll.have_status else None
        th = self.thumb
        if th is None or th.obj is None or poll.t != th.t:
            return
        th.acked = poll.held_packets(th.count)
        th.window_end = poll.window_end()
        th.operator_has_end = poll.have_end
        th.poll_at = now
        if poll.have_end and len(th.acked) == th.count and not th.done:
            th.done = True
            if self.last_oid == th.oid and self.result == R_TAKEN:
                self.result = R_DONE
                self._status_asap = True

    # -- sending ---------------------------------------------------------------

    def next_packet(self, now: float) -> bytes | None:
        """The next packet to hand the modem (its queue is empty), or None."""
        self.wants_flush = False
        if self._out:
            return self._out.pop(0)
        self._full_leaving = None  # the queue is empty: the last frame handed has left
        if self._sync_due is not None and not self._sync_taken:
            return self._emit_frame(seal_sync(self.key, self.challenge, self._sync_due), "sync")
        if self.session is None or self._awaiting_brake(now):
            return None
        th = self.thumb
        sending = th is not None and th.obj is not None and not th.done
        if sending and not self._status_asap and now - self._status_at < self.status_thumb_s:
            packet = self._data_packet(now)
            if packet is not None:
                return packet
        return self._status_packet(now)  # due, asked for, or a free slot (the turns pass anyway)

    def _awaiting_brake(self, now: float) -> bool:
        """Whether the STATUS due after a STOP or the failsafe waits (nothing is handed)
        until the vehicle reports the brake's mode: a STATUS that still said GUIDED
        would confirm no STOP, and the next comes a turn later."""
        if self._brake_asked is None or not self._status_asap:
            return False
        at, modes = self._brake_asked
        v = self.vehicle
        if v.mode in modes or not v.autopilot or now - at >= BRAKE_SHOWN_S:
            self._brake_asked = None
            return False
        return True

    def _status_packet(self, now: float) -> bytes:
        self._status_asap = False
        self._status_at = now
        status = self.status(now)
        if self._failsafe_unreported and not self.failsafe:
            self._failsafe_unreported = False  # the FAILSAFE of a spell now over has been reported once
        body = status.encode()
        self._fulls = {c: b for c, b in self._fulls.items() if self.tx_ctr - c <= SAME_REACH}
        ref = self._named_full(body)
        if ref is not None:
            ctr, packets = self._seal(DOWN_STATUS_SAME, same_body(ref, body))
            self.counters.statuses_same += 1
        else:
            ctr, packets = self._seal(DOWN_STATUS, body)
            self._fulls[ctr] = body
            self._full_leaving = ctr
        self.status_sent[ctr] = now
        if len(self.status_sent) > 64:
            del self.status_sent[min(self.status_sent)]
        return self._emit_frame(packets, "status")

    def _named_full(self, body: bytes) -> int | None:
        """The counter of the full STATUS the operator's last POLL names, when it was
        made before that POLL came and says what `body` says of the position,
        heading and battery (§9.4 STATUS_SAME); else None."""
        if self._operator_holds is None:
            return None
        held, poll_at = self._operator_holds
        for ctr, full in self._fulls.items():
            if ctr % CTR_WINDOW == held and self.status_sent.get(ctr, poll_at) < poll_at:
                return ctr if steady_bytes(full) == steady_bytes(body) else None
        return None

    def _data_packet(self, now: float) -> bytes | None:
        th = self.thumb
        assert th is not None and th.obj is not None
        cutoff = th.poll_at - IN_FLIGHT_S
        for i in range(th.count):
            if i in th.acked:
                continue
            sent = th.sent_at.get(i)
            if sent is None or (sent <= cutoff and i < th.window_end):  # past the POLL's window: not known lost
                th.sent_at[i] = now
                self._last_handed = "data"
                return data_packet(th.t, i, th.obj[i * DATA_BYTES:(i + 1) * DATA_BYTES])
        if th.operator_has_end:
            return None
        if th.end_sent_at is None or th.end_sent_at <= cutoff:
            th.end_sent_at = now
            end = ThumbEnd(th.oid, object_mac(self.key, self.session, th.oid, th.obj))
            return self._emit_frame(self._seal(DOWN_THUMB_END, end.encode())[1], "end")
        return None


def _clamp16(value: float) -> int:
    return max(-32768, min(32767, int(round(value))))


def modem_idle(endpoint, now: float, last_sent: float, pace_s: float) -> bool:
    """May the next packet go to `endpoint` now (§9 Queues: one packet in the
    modem at a time)?  A modem that tells its queue (link.wlmodem): when that is
    empty (unknown: no).  Another endpoint (a pty or socket to the emulator):
    `pace_s` after the last packet handed at `last_sent`."""
    queue_length = getattr(endpoint, "queue_length", None)
    if queue_length is not None:
        return queue_length() == 0
    return now - last_sent >= pace_s


# ---------------------------------------------------------------------------
# The operator's end
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Synced:
    boot: bytes
    restarted: bool  # a BOOT unlike the last one: pending order fates unknown
    failsafe_s: int
    failsafe_action: int


@dataclass(frozen=True)
class StatusReceived:
    status: Status
    at: float  # when it was made, as the operator estimates it (arrival - STATUS_TRANSIT_S or SAME_TRANSIT_S)
    ctr: int


@dataclass(frozen=True)
class OrderFate:
    oid: int
    state: str  # taken, done, rejected, cancelled, aborted, unknown, not sent
    reason: str = ""


@dataclass(frozen=True)
class StopConfirmed:
    stop_no: int
    pressed_at: float


@dataclass(frozen=True)
class StopNotCarriedOut:
    stop_no: int


@dataclass(frozen=True)
class ThumbnailProgress:
    oid: int
    prefix: bytes  # the contiguous prefix of the object held (from its [N:2])
    verified: bool = False


@dataclass(frozen=True)
class ThumbnailComplete:
    oid: int
    object: bytes
    verified: bool = True


@dataclass(frozen=True)
class ThumbnailRejected:
    oid: int  # the object MAC did not hold: discarded, asked for again


@dataclass(frozen=True)
class InauthenticPacket:
    alert: bool  # they persist while no authentic frame comes


@dataclass(frozen=True)
class Resyncing:
    why: str


@dataclass
class _Wanted:
    oid: int
    slots: dict[int, list[bytes]] = field(default_factory=dict)
    end: tuple[bytes, bytes] | None = None  # (object MAC, the session it was made in)
    prefix_len: int = 0
    verified: bool = False

    @property
    def t(self) -> int:
        return self.oid & 1

    def count(self) -> int | None:
        first = self.slots.get(0)
        if not first:
            return None
        return min(MAX_SLOTS, slot_count(2 + int.from_bytes(first[0][:2], "big")))


class AcousticOperator(_End):
    direction_in = DOWN_PACKETS
    label_in = LABEL_DOWN
    label_out = LABEL_UP

    def __init__(self, key: bytes, *, random_bytes: Callable[[int], bytes] = os.urandom,
                 hello_every_s: float = HELLO_EVERY_S) -> None:
        super().__init__(key, random_bytes)
        self.hello_every_s = hello_every_s
        self._hellos: collections.deque[tuple[int, bytes]] = collections.deque(maxlen=KEEP_HELLOS)
        self._hello_no = 0
        self._session_hello = -1
        self._hello_at: float | None = None
        self.resyncing = True
        self.boot: bytes | None = None
        self.failsafe_s: int | None = None
        self.failsafe_action: int | None = None
        self.last_authentic_at: float | None = None
        self.last_status: Status | None = None
        self.last_status_arrival: float | None = None
        self._held: dict[int, bytes] = {}  # full STATUSes of the session within 16 counters of the newest frame
        self._ready = False  # a STATUS in this session: the ROV's last OID is known
        self._next_oid = 1
        self._issued = 0  # the highest OID put on the air
        self._last_thumb_oid: int | None = None
        self._outstanding: tuple[int, int, bytes] | None = None  # (oid, kind, body)
        self._queue: collections.deque[tuple[int, int, bytes]] = collections.deque()
        self._watch: dict[int, int] = {}  # OID -> RESULT last reported (orders settled, still watched)
        self._order_slot = False  # the last slot carried the outstanding order
        self.stop_no = 0
        self.stop_active = False
        self._stop_pressed_at = 0.0
        self._stop_reported_off = False
        self.wants_flush = False
        self.thumb: _Wanted | None = None
        self._inauthentic_at: collections.deque[float] = collections.deque()
        self._data_at = -1e18  # the last data packet for the thumbnail wanted
        self._events: list = []

    # -- the pilot's side ------------------------------------------------------

    def stop(self, now: float) -> int:
        """STOP: flush the modem, STOP in every slot until confirmed; returns its number."""
        self.wants_flush = True
        self._out = []
        if self.stop_active:
            return self.stop_no  # a press while one is being sent joins it
        self.stop_no = (self.stop_no + 1) % 256
        self.stop_active = True
        self._stop_pressed_at = now
        self._stop_reported_off = False
        if self._outstanding is not None:
            oid = self._outstanding[0]
            self._outstanding = None
            self._watch[oid] = -1  # its fate is what the next STATUS shows (cancelled, or taken)
        for oid, _, _ in self._queue:
            self._events.append(OrderFate(oid, "not sent", "a STOP cancelled it"))
        self._queue.clear()
        self._next_oid = (self._issued + 1) % 256
        return self.stop_no

    def cancel_stop(self) -> bool:
        """Give up a STOP the ROV cannot carry out (its STATUS shows no autopilot)."""
        if not (self.stop_active and self._stop_reported_off):
            return False
        self.stop_active = False
        return True

    @property
    def ready(self) -> bool:
        return self._ready and not self.stop_active

    @property
    def sending_oid(self) -> int | None:
        """The OID of the order on the air (sent and resent until a STATUS names
        it), or None."""
        return None if self._outstanding is None else self._outstanding[0]

    @property
    def orders_waiting(self) -> int:
        """Orders given and not yet settled: the one on the air and those queued
        behind it."""
        return (self._outstanding is not None) + len(self._queue)

    def send_order(self, body: Order | GoTo | ThumbRequest, now: float) -> int:
        """Queue an order (its `oid` is replaced); returns the OID it carries."""
        if not self._ready:
            raise OrderRefused("no STATUS from the ROV yet in this session")
        if self.stop_active:
            raise OrderRefused("a STOP is not confirmed yet")
        oid = self._next_oid or 1  # OID 0 is never used: LAST_OID_ISSUED 0 says none
        if isinstance(body, ThumbRequest) and self._last_thumb_oid is not None and (oid & 1) == (self._last_thumb_oid & 1):
            oid = oid % 255 + 1  # two thumbnails in a row never share T
        if isinstance(body, ThumbRequest):
            self._last_thumb_oid = oid
        self._next_oid = (oid + 1) % 256
        body = replace(body, oid=oid)
        kind = UP_GOTO if isinstance(body, GoTo) else UP_THUMB if isinstance(body, ThumbRequest) else UP_ORDER
        self._queue.append((oid, kind, body.encode()))
        self._promote()
        return oid

    def _promote(self) -> None:
        if self._outstanding is None and self._queue:
            self._outstanding = self._queue.popleft()
            oid, kind, _ = self._outstanding
            self._issued = oid
            self._order_slot = False
            if self._last_handed == "poll" and not self._out:
                self.wants_flush = True  # a POLL waiting in the modem gives way to the order
            if kind == UP_THUMB:
                self.thumb = _Wanted(oid)

    @property
    def next_status_at(self) -> float | None:
        """When the next STATUS is due at the latest (if not lost)."""
        if self.last_status_arrival is None:
            return None
        sending = self.thumb is not None and not self.thumb.verified
        return self.last_status_arrival + (STATUS_THUMB_S if sending else STATUS_IDLE_S) + 1.0

    # -- time ------------------------------------------------------------------

    def tick(self, now: float) -> list:
        events = self._drain()
        if not self.resyncing and self.session is not None and self.last_authentic_at is not None:
            alive = max(self.last_authentic_at, self._data_at)
            if now - alive >= SILENCE_RESYNC_S:
                self._resync("nothing heard for 20 s", events)
            elif now - self.last_authentic_at >= AUTHENTIC_RESYNC_S:
                self._resync("no authentic frame for 40 s", events)
        return events

    def _resync(self, why: str, events: list) -> None:
        self.resyncing = True
        self._hello_at = None
        self.counters.resyncs += 1
        events.append(Resyncing(why))

    def _drain(self) -> list:
        events, self._events = self._events, []
        return events

    # -- sending ---------------------------------------------------------------

    def next_packet(self, now: float) -> bytes | None:
        """The next packet to hand the modem (its queue is empty, flushed first when
        `wants_flush`), or None."""
        self.wants_flush = False
        if self._out:
            return self._out.pop(0)
        if self._last_handed == "hello":
            # §9.2 (decided): a HELLO's 8 s count from when it left the modem (its queue is
            # empty now), not from when it was handed: a modem that waits for its turn, or
            # its start, would otherwise have the next HELLO cross the SYNC under way.
            self._hello_at = now
            self._last_handed = "hello left"
        if self.resyncing and (self._hello_at is None or now - self._hello_at >= self.hello_every_s):
            self._hello_at = now
            self._hello_no += 1
            challenge = self._nonzero_random(CHALLENGE_BYTES)
            self._hellos.append((self._hello_no, challenge))
            self._last_handed = "hello"
            return seal_hello(self.key, challenge)
        if self.session is None:
            return None
        if self.stop_active:
            return self._emit_frame(self._seal(UP_STOP, StopBody(self.stop_no, self._issued).encode())[1], "stop")
        if self._outstanding is not None and not self._order_slot:
            self._order_slot = True
            _, kind, body = self._outstanding
            return self._emit_frame(self._seal(kind, body)[1], "order")
        self._order_slot = False
        return self._emit_frame(self._seal(UP_POLL, self._poll().encode())[1], "poll")

    def _poll(self) -> Poll:
        held = {"have_status": True, "held": max(self._held) % CTR_WINDOW} if self._held else {}
        w = self.thumb
        if w is None or w.verified:
            t = w.t if w is not None else (self._last_thumb_oid or 0) & 1
            return Poll(t, MAX_SLOTS, True, 0, **held)
        count = w.count()
        limit = count if count is not None else MAX_SLOTS
        lowest = next((i for i in range(limit) if i not in w.slots), limit)
        bitmap = 0
        for k in range(BITMAP_BITS):
            if lowest + 1 + k in w.slots:
                bitmap |= 1 << (BITMAP_BITS - 1 - k)
        return Poll(w.t, min(lowest, MAX_SLOTS), w.end is not None, bitmap, **held)

    # -- receiving -------------------------------------------------------------

    def _heard(self, now: float) -> None:
        self.last_authentic_at = now
        self._inauthentic_at.clear()

    def _inauthentic(self, now: float, events: list) -> None:
        self.counters.inauthentic += 1
        self._inauthentic_at.append(now)
        while self._inauthentic_at and now - self._inauthentic_at[0] > ALERT_WINDOW_S:
            self._inauthentic_at.popleft()
        quiet = self.last_authentic_at is None or now - self.last_authentic_at >= ALERT_QUIET_S
        events.append(InauthenticPacket(len(self._inauthentic_at) >= ALERT_COUNT and quiet))

    def _open_session_frame(self, hdr: int, body: bytes, tag: bytes, now: float, events: list) -> bool:
        if hdr != 0 or len(body) != LONG_BODY:
            return False
        raw = bytes([0]) + body
        found = next(((n, c) for n, c in reversed(self._hellos)
                      if hmac.compare_digest(mac(self.key, LABEL_SYNC, c, raw)[:TAG_BYTES], tag)), None)
        if found is None:
            return False
        number, challenge = found
        if number <= self._session_hello:
            self.counters.stale_syncs += 1  # a SYNC for an older HELLO, or one taken already
            return True
        sync = SyncBody.decode(body)
        self._session_hello = number
        self._held = {}
        self._new_session(challenge + sync.boot + sync.nonce)
        self._heard(now)
        self.resyncing = False
        self._ready = False
        restarted = self.boot is not None and sync.boot != self.boot
        self.boot = sync.boot
        self.failsafe_s, self.failsafe_action = sync.failsafe_s, sync.failsafe_action
        events.append(Synced(sync.boot, restarted, sync.failsafe_s, sync.failsafe_action))
        if restarted:
            pending = [self._outstanding] if self._outstanding else []
            for oid, _, _ in pending:
                events.append(OrderFate(oid, "unknown", "the ROV restarted"))
            for oid, _, _ in self._queue:
                events.append(OrderFate(oid, "not sent", "the ROV restarted"))
            for oid in self._watch:
                events.append(OrderFate(oid, "unknown", "the ROV restarted"))
            self._outstanding = None
            self._queue.clear()
            self._watch.clear()
            self.thumb = None
        return True

    def _frame(self, kind: int, body: bytes, ctr: int, now: float, events: list) -> None:
        self._heard(now)
        self._held = {c: b for c, b in self._held.items() if ctr - c <= SAME_REACH + 1}
        if kind == DOWN_STATUS:
            self._held[ctr] = bytes(body)
            self._status(Status.decode(body), ctr, now - STATUS_TRANSIT_S, now, events)
        elif kind == DOWN_STATUS_SAME:
            full = next((b for c, b in self._held.items() if c % 256 == body[0]), None)
            if full is None:
                self.counters.same_unmatched += 1  # names a full STATUS we lack: our POLLs ask for one
                self._held = {}
                return
            self.counters.statuses_same += 1
            self._status(Status.decode(renewed_body(full, body)), ctr, now - SAME_TRANSIT_S, now, events)
        elif kind == DOWN_THUMB_END:
            end = ThumbEnd.decode(body)
            w = self.thumb
            if w is not None and w.oid == end.oid and not w.verified:
                w.end = (end.object_mac, self.session)
                self._try_verify(w, events)

    def _status(self, st: Status, ctr: int, made: float, now: float, events: list) -> None:
        self.last_status = st
        self.last_status_arrival = now
        events.append(StatusReceived(st, made, ctr))
        if not st.uplink and not self.resyncing:
            self._resync("the ROV has taken nothing from us for 10 s", events)
        if not self._ready:
            self._ready = True
            if self._outstanding is None and not self._queue:
                self._next_oid = (st.oid + 1) % 256
                self._issued = st.oid
        # The outstanding order: settled once the ROV's last OID is at or past it.
        if self._outstanding is not None:
            oid = self._outstanding[0]
            if _ahead(st.oid, oid) < 128:
                self._outstanding = None
                self._watch[oid] = -1
                if not self._queue and _ahead(st.oid, self._issued) < 128:
                    self._next_oid = (st.oid + 1) % 256
                self._promote()
        for oid in list(self._watch):
            d = _ahead(st.oid, oid)
            if d >= 128:
                continue  # the ROV is not there yet
            if d > 0:  # the ROV's last OID moved past it: STATUS names one OID only
                if self._watch[oid] == -1:
                    events.append(OrderFate(oid, "unknown", "the ROV moved past it before reporting it"))
                else:
                    events.append(OrderFate(oid, "untracked", "a later order took its place in STATUS"))
                del self._watch[oid]
                continue
            if st.result != self._watch[oid]:
                state, reason = RESULT_STATE.get(st.result, ("unknown", ""))
                events.append(OrderFate(oid, state, reason))
                if state in ("rejected", "cancelled") and self.thumb is not None and self.thumb.oid == oid:
                    self.thumb = None
            self._watch[oid] = st.result
            if st.result != R_TAKEN:
                del self._watch[oid]  # final
        if self.stop_active and st.stop_no2 == self.stop_no & 3:
            if st.autopilot and st.hold and st.mode in (Mode.POS_HOLD, Mode.DEPTH_HOLD):
                self.stop_active = False
                events.append(StopConfirmed(self.stop_no, self._stop_pressed_at))
            elif not st.autopilot and not self._stop_reported_off:
                self._stop_reported_off = True
                events.append(StopNotCarriedOut(self.stop_no))

    def _data(self, packet: bytes, now: float, events: list) -> None:
        self.counters.data_packets += 1
        w = self.thumb
        t, idx = packet[0] >> 6 & 1, packet[0] & 63
        if w is None or w.verified or t != w.t or idx >= MAX_SLOTS:
            self.counters.data_ignored += 1
            return
        chunk = packet[1:]
        self._data_at = now
        slot = w.slots.setdefault(idx, [])
        if chunk not in slot and len(slot) < SLOT_CANDIDATES:
            slot.append(chunk)
        count = w.count()
        have = 0
        while have in w.slots and (count is None or have < count):
            have += 1
        if have > 0:
            obj_len = 2 + int.from_bytes(w.slots[0][0][:2], "big")
            prefix = b"".join(w.slots[i][0] for i in range(have))[:obj_len]
            if len(prefix) > w.prefix_len:
                w.prefix_len = len(prefix)
                events.append(ThumbnailProgress(w.oid, prefix))
        self._try_verify(w, events)

    def _try_verify(self, w: _Wanted, events: list) -> None:
        count = w.count()
        if w.end is None or count is None or any(i not in w.slots for i in range(count)):
            return
        want, session = w.end
        tried = 0
        for first in w.slots[0]:
            n = min(MAX_OBJECT, 2 + int.from_bytes(first[:2], "big"))
            k = slot_count(n)
            if any(i not in w.slots for i in range(k)):
                continue
            for combo in itertools.product([first], *(w.slots[i] for i in range(1, k))):
                tried += 1
                if tried > MAX_COMBINATIONS:
                    break
                obj = b"".join(combo)[:n]
                if hmac.compare_digest(object_mac(self.key, session, w.oid, obj), want):
                    w.verified = True
                    self.counters.thumbnails_verified += 1
                    events.append(ThumbnailComplete(w.oid, obj))
                    return
        self.counters.thumbnail_mismatches += 1
        events.append(ThumbnailRejected(w.oid))
        self.thumb = _Wanted(w.oid)  # discarded: the POLLs ask for it all again
