"""The packet layer both ends share (§9.1): headers and counters, a frame split into
8-byte packets, the pairing of a two-packet frame's halves, thumbnail data packets."""

from __future__ import annotations

import hmac
from dataclasses import dataclass
from typing import Callable

from .sealing import control_tag, seal_control
from .wire import CTR_WINDOW, DATA_BYTES, PACKET_BYTES, TAG_BYTES

# ---------------------------------------------------------------------------
# Packets
# ---------------------------------------------------------------------------


def data_packet(t: int, idx: int, chunk: bytes) -> bytes:
    return bytes([0x80 | t << 6 | idx]) + chunk.ljust(DATA_BYTES, b"\0")


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
    scenes: int = 0  # SCENE frames sent (ROV) or taken (operator), §11.2
    records_ignored: int = 0  # (operator) §11 object records out of range: counted and ignored
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
