"""What the ROV measured of the world, in the bytes both profiles carry (docs/PROTOCOL.md §11):
its altitude above the seabed, and the objects it recognised.

Goal: a few bytes each, SI on either side of them.  The altitude is one byte (ALT: 5 cm
steps to 10 m, then 0.5 m steps to 37 m, 0 unknown); an object is one record of at most
9 bytes (new or changed) or 2 (removed).  The radio profile puts them in the reply's annex
(§11.1, link/radio/wire2.py), the acoustic one in its SCENE frame (§11.2).

A record that decodes but whose values are out of range (a reserved class, a length or
width of 0, a width above the length) is counted and ignored by the receiver, never
raised: `decode_records` says how many it dropped.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

# Classes, by their number on the wire; rov/seabed.py's CLASSES is the same list.
OBJECT_CLASSES = ("unknown", "amphora", "pipe", "timber", "ladder")

OP_NEW, OP_CHANGED, OP_REMOVED = 1, 2, 3  # OP 0: no record (the acoustic body's padding)
RECORD_BYTES = 9  # a new or changed object
REMOVED_BYTES = 2
POSITION_STEP_M = 0.05
LENGTH_STEP_M = 0.05
WIDTH_STEP_M = 0.02
HEADING_STEP_DEG = 180.0 / 256  # the long axis: 0 .. 180 degrees, clockwise from north
CONFIDENCE_LEVELS = 8

ALT_UNKNOWN = 0
ALT_FINE_STEP_M, ALT_FINE_TOP = 0.05, 200  # 1..200: 0.05 .. 10.00 m
ALT_COARSE_STEP_M = 0.5  # 201..254: 10.5 .. 37.0 m
ALT_TOP = 254  # 255: beyond 37 m, shown as unknown (no floor to draw)
ALT_BEYOND = 255


def altitude_code(altitude_m: float | None) -> int:
    """The ALT byte for an altitude in metres (None or not finite: unknown, 0)."""
    if altitude_m is None or not math.isfinite(altitude_m) or altitude_m < 0:
        return ALT_UNKNOWN
    if altitude_m < ALT_FINE_TOP * ALT_FINE_STEP_M + ALT_COARSE_STEP_M / 2:
        return max(1, min(ALT_FINE_TOP, round(altitude_m / ALT_FINE_STEP_M)))
    coarse = ALT_FINE_TOP + round((altitude_m - ALT_FINE_TOP * ALT_FINE_STEP_M) / ALT_COARSE_STEP_M)
    return coarse if coarse <= ALT_TOP else ALT_BEYOND


def altitude_from_code(code: int) -> float | None:
    """Metres above the seabed, None for unknown (0) and beyond 37 m (255)."""
    if code == ALT_UNKNOWN or code >= ALT_BEYOND:
        return None
    if code <= ALT_FINE_TOP:
        return round(code * ALT_FINE_STEP_M, 2)
    return ALT_FINE_TOP * ALT_FINE_STEP_M + (code - ALT_FINE_TOP) * ALT_COARSE_STEP_M


@dataclass(frozen=True)
class ObjectRecord:
    """One §11 record in wire units.  `op`: OP_NEW, OP_CHANGED or OP_REMOVED (the rest is
    0 for a removal)."""

    op: int
    object_id: int  # 0..255
    cls: int = 0  # OBJECT_CLASSES's index
    confidence: int = 0  # 0..7: (n + 1) / 8
    north: int = 0  # 5 cm steps, int16
    east: int = 0
    length: int = 0  # 5 cm steps, 1..255
    width: int = 0  # 2 cm steps, 1..255
    heading: int = 0  # 180/256 degree steps, 0..255

    def encode(self) -> bytes:
        if not OP_NEW <= self.op <= OP_REMOVED or not 0 <= self.object_id <= 255:
            raise ValueError(f"no such record: OP {self.op}, ID {self.object_id}")
        if self.op == OP_REMOVED:
            return bytes((self.op << 6, self.object_id))
        return struct.pack(">BBhhBBB", self.op << 6 | (self.cls & 7) << 3 | (self.confidence & 7), self.object_id,
                           self.north, self.east, self.length, self.width, self.heading)

    def out_of_range(self) -> str | None:
        """Why a decoded record cannot be shown (None: it can)."""
        if self.op == OP_REMOVED:
            return None
        if self.cls >= len(OBJECT_CLASSES):
            return f"class {self.cls} is reserved"
        if self.length == 0 or self.width == 0:
            return "a length or width of 0"
        if self.width * WIDTH_STEP_M > self.length * LENGTH_STEP_M + LENGTH_STEP_M:
            return "a width above the length"
        return None

    # SI, for the ROV's map and the operator's events

    @classmethod
    def from_si(cls, op: int, object_id: int, class_name: str, confidence: float, north_m: float, east_m: float,
                length_m: float, width_m: float, heading_deg: float) -> "ObjectRecord":
        """Rounded and clamped into the record's ranges (a longer object is sent at 12.75 m)."""
        def clamp(v: float, lo: int, hi: int) -> int:
            return max(lo, min(hi, round(v)))

        return cls(op, object_id & 0xFF, OBJECT_CLASSES.index(class_name) if class_name in OBJECT_CLASSES else 0,
                   clamp(confidence * CONFIDENCE_LEVELS - 1, 0, 7),
                   clamp(north_m / POSITION_STEP_M, -32768, 32767), clamp(east_m / POSITION_STEP_M, -32768, 32767),
                   clamp(length_m / LENGTH_STEP_M, 1, 255), clamp(width_m / WIDTH_STEP_M, 1, 255),
                   round((heading_deg % 180.0) / HEADING_STEP_DEG) % 256)

    @property
    def class_name(self) -> str:
        return OBJECT_CLASSES[self.cls] if self.cls < len(OBJECT_CLASSES) else "unknown"

    @property
    def north_m(self) -> float:
        return round(self.north * POSITION_STEP_M, 3)

    @property
    def east_m(self) -> float:
        return round(self.east * POSITION_STEP_M, 3)

    @property
    def length_m(self) -> float:
        return round(self.length * LENGTH_STEP_M, 3)

    @property
    def width_m(self) -> float:
        return round(self.width * WIDTH_STEP_M, 3)

    @property
    def heading_deg(self) -> float:
        return self.heading * HEADING_STEP_DEG

    @property
    def confidence_fraction(self) -> float:
        return (self.confidence + 1) / CONFIDENCE_LEVELS


def record_length(first_byte: int) -> int:
    """Bytes of the record that starts with this byte (0: OP 0, no record)."""
    op = first_byte >> 6
    return 0 if op == 0 else REMOVED_BYTES if op == OP_REMOVED else RECORD_BYTES


def decode_records(data: bytes, *, padded: bool = False) -> tuple[list[ObjectRecord], int]:
    """(records, out of range dropped) of a run of records.  `padded`: an OP of 0 ends the
    run (the acoustic body's zeros).  A record cut short is a structural fault: ValueError."""
    records: list[ObjectRecord] = []
    dropped = 0
    i = 0
    while i < len(data):
        n = record_length(data[i])
        if n == 0:
            if padded:
                break
            raise ValueError("a record with OP 0")
        if i + n > len(data):
            raise ValueError("an object record cut short")
        head = data[i]
        if n == REMOVED_BYTES:
            if head & 0x3F:
                raise ValueError("a removal's reserved bits set")
            record = ObjectRecord(OP_REMOVED, data[i + 1])
        else:
            _, oid, north, east, length, width, heading = struct.unpack(">BBhhBBB", data[i:i + n])
            record = ObjectRecord(head >> 6, oid, head >> 3 & 7, head & 7, north, east, length, width, heading)
        i += n
        if record.out_of_range():
            dropped += 1
            continue
        records.append(record)
    return records, dropped


# -- the sender's side: what is still to tell -------------------------------------

ALT_REPEAT_S = 2.0  # an unchanged altitude is told again this often (a reply or SCENE carrying it may be lost)


class SceneOutbox:
    """What the ROV still has to tell of its scene, whatever the profile: the altitude
    (told when it changed from what the operator was last known to hold, or ALT_REPEAT_S
    after it was last told) and one pending record per object, the newest (a change
    to an object whose NEW was never delivered stays a NEW; a removal of one never
    delivered is dropped with it).  A carrier takes `next_record()`, and says
    `delivered(record)` when it knows the operator has it (the radio: a poll chained to
    the reply that carried it; the acoustic profile: when the SCENE frame was handed,
    as it knows no more).  Thread-safe: the detector's thread puts, the link takes."""

    def __init__(self) -> None:
        import threading

        self._lock = threading.Lock()
        self._pending: dict[int, ObjectRecord] = {}  # object id -> the record to send, in order of first put
        self._known: set[int] = set()  # ids whose NEW the operator has
        self._offered: set[int] = set()  # ids a carrier took a record of (the operator may have it)
        self._told: dict[int, tuple[ObjectRecord, float]] = {}  # the live objects told, and when
        self._refreshed_at = -math.inf
        self.altitude_m: float | None = None
        # (code, when) last known delivered; a new session's operator holds "unknown".
        self._alt_told: tuple[int, float] = (ALT_UNKNOWN, -math.inf)

    def put(self, record: ObjectRecord) -> None:
        with self._lock:
            oid = record.object_id
            if record.op == OP_REMOVED and oid not in self._known | self._offered:
                self._pending.pop(oid, None)  # never told: nothing to take back
                return
            if record.op == OP_CHANGED and oid not in self._known:
                record = ObjectRecord(OP_NEW, *(getattr(record, f) for f in (
                    "object_id", "cls", "confidence", "north", "east", "length", "width", "heading")))
            self._pending.pop(oid, None)
            self._pending[oid] = record

    def pending(self) -> int:
        with self._lock:
            return len(self._pending)

    def next_record(self, room: int = RECORD_BYTES) -> ObjectRecord | None:
        """The next record to send, of at most `room` bytes (None: none that fits)."""
        with self._lock:
            for record in self._pending.values():
                if len(record.encode()) <= room:
                    self._offered.add(record.object_id)
                    return record
            return None

    def refresh(self, now: float, every_s: float, gap_s: float = 0.0) -> None:
        """With nothing pending, put again (as CHANGED) the told object told longest ago, once it
        is `every_s` old: a carrier that never learns what arrived (the acoustic one) mends a
        lost record so."""
        with self._lock:
            if self._pending or not self._told or now - self._refreshed_at < gap_s:
                return
            oid, (record, at) = min(self._told.items(), key=lambda item: item[1][1])
            if now - at >= every_s:
                self._refreshed_at = now
                self._told[oid] = (record, now)
                self._pending[oid] = ObjectRecord(OP_CHANGED, *(getattr(record, f) for f in (
                    "object_id", "cls", "confidence", "north", "east", "length", "width", "heading")))

    def delivered(self, record: ObjectRecord, now: float = 0.0) -> None:
        with self._lock:
            if record.op == OP_REMOVED:
                self._told.pop(record.object_id, None)
            else:
                self._told[record.object_id] = (record, now)
            if self._pending.get(record.object_id) == record:
                del self._pending[record.object_id]
            if record.op == OP_REMOVED:
                self._known.discard(record.object_id)
                self._offered.discard(record.object_id)
            else:
                self._known.add(record.object_id)

    def altitude_due(self, now: float, repeat_s: float = ALT_REPEAT_S, min_steps: int = 1) -> int | None:
        """The ALT byte to tell now, or None when the operator holds it: told, and (a known
        altitude) told within ALT_REPEAT_S.  An unknown one is told only when it changes, so
        a ROV without a rangefinder sends no ALT at all."""
        code = altitude_code(self.altitude_m)
        told_code, told_at = self._alt_told
        moved = code != told_code and (ALT_UNKNOWN in (code, told_code) or abs(code - told_code) >= min_steps)
        if moved or (code != ALT_UNKNOWN and now - told_at >= repeat_s):
            return code
        return None

    def altitude_delivered(self, code: int, now: float) -> None:
        self._alt_told = (code, now)

    def forget_operator(self) -> None:
        """A new session (the acoustic SYNC, a ROV restart seen by the operator): it holds
        nothing, so every live object goes again as NEW."""
        with self._lock:
            self._known.clear()
            self._offered.clear()
            self._told.clear()
            self._alt_told = (ALT_UNKNOWN, -math.inf)


@dataclass(frozen=True)
class SeenObject:
    """An object as the operator is told it, in SI (the record's resolution)."""

    object_id: int
    class_name: str
    confidence: float  # 0.125 .. 1
    north_m: float
    east_m: float
    length_m: float
    width_m: float
    heading_deg: float  # of the long axis, 0 .. 180, clockwise from north
    new: bool  # OP NEW (else CHANGED)

    @classmethod
    def from_record(cls, record: ObjectRecord) -> "SeenObject":
        return cls(record.object_id, record.class_name, record.confidence_fraction, record.north_m, record.east_m,
                   record.length_m, record.width_m, record.heading_deg, record.op == OP_NEW)
