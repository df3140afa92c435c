"""The operator's end of the acoustic profile (§9): `AcousticOperator`, and when the
modem may take the next packet."""

from __future__ import annotations

import collections
import hmac
import itertools
import os
from dataclasses import dataclass, field, replace
from typing import Callable

from ..radio.auth import mac
from ..scene import OP_REMOVED, SeenObject, altitude_from_code, decode_records
from ..vocabulary import Mode
from .bodies import GoToBody, OrderBody, PollBody, StatusBody, StopBody, SyncBody, ThumbEnd, ThumbRequest, renewed_body
from .events import (
    InauthenticPacket,
    OrderFate,
    Resyncing,
    SceneAltitude,
    SceneObjectRemoved,
    SceneObjectReported,
    SceneRecordIgnored,
    SessionSynced,
    StatusReceived,
    StopImpossible,
    StopTaken,
    ThumbnailComplete,
    ThumbnailProgress,
    ThumbnailRejected,
)
from .packets import _ahead, _End, slot_count
from .sealing import object_mac, seal_hello
from .wire import (
    ALERT_COUNT,
    ALERT_QUIET_S,
    ALERT_WINDOW_S,
    AUTHENTIC_RESYNC_S,
    BITMAP_BITS,
    CHALLENGE_BYTES,
    CTR_WINDOW,
    DOWN_PACKETS,
    DOWN_SCENE,
    DOWN_STATUS,
    DOWN_STATUS_SAME,
    DOWN_THUMB_END,
    HELLO_EVERY_S,
    KEEP_HELLOS,
    LABEL_DOWN,
    LABEL_SYNC,
    LABEL_UP,
    LONG_BODY,
    MAX_COMBINATIONS,
    MAX_OBJECT,
    MAX_SLOTS,
    NEVER_TAKEN,
    R_TAKEN,
    RESULT_STATE,
    SAME_REACH,
    SAME_TRANSIT_S,
    SILENCE_RESYNC_S,
    SLOT_CANDIDATES,
    STATUS_IDLE_S,
    STATUS_THUMB_S,
    STATUS_TRANSIT_S,
    TAG_BYTES,
    UP_GOTO,
    UP_ORDER,
    UP_POLL,
    UP_STOP,
    UP_THUMB,
    OrderRefused,
)


def modem_idle(endpoint, now: float, last_sent: float, pace_s: float) -> bool:
    """May the next packet go to `endpoint` now (§9 Queues: one packet in the
    modem at a time)?  A modem that tells its queue (link.wlmodem): when that is
    empty (unknown: no).  Another endpoint (a pty or socket to the emulator):
    `pace_s` after the last packet handed at `last_sent`."""
    queue_length = getattr(endpoint, "queue_length", None)
    if queue_length is not None:
        return queue_length() == 0
    return now - last_sent >= pace_s


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
        self.last_status: StatusBody | None = None
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

    def send_order(self, body: OrderBody | GoToBody | ThumbRequest, now: float) -> int:
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
        kind = UP_GOTO if isinstance(body, GoToBody) else UP_THUMB if isinstance(body, ThumbRequest) else UP_ORDER
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

    def _poll(self) -> PollBody:
        held = {"have_status": True, "held": max(self._held) % CTR_WINDOW} if self._held else {}
        w = self.thumb
        if w is None or w.verified:
            t = w.t if w is not None else (self._last_thumb_oid or 0) & 1
            return PollBody(t, MAX_SLOTS, True, 0, **held)
        count = w.count()
        limit = count if count is not None else MAX_SLOTS
        lowest = next((i for i in range(limit) if i not in w.slots), limit)
        bitmap = 0
        for k in range(BITMAP_BITS):
            if lowest + 1 + k in w.slots:
                bitmap |= 1 << (BITMAP_BITS - 1 - k)
        return PollBody(w.t, min(lowest, MAX_SLOTS), w.end is not None, bitmap, **held)

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
        events.append(SessionSynced(sync.boot, restarted, sync.failsafe_s, sync.failsafe_action))
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
            self._status(StatusBody.decode(body), ctr, now - STATUS_TRANSIT_S, now, events)
        elif kind == DOWN_STATUS_SAME:
            full = next((b for c, b in self._held.items() if c % 256 == body[0]), None)
            if full is None:
                self.counters.same_unmatched += 1  # names a full STATUS we lack: our POLLs ask for one
                self._held = {}
                return
            self.counters.statuses_same += 1
            self._status(StatusBody.decode(renewed_body(full, body)), ctr, now - SAME_TRANSIT_S, now, events)
        elif kind == DOWN_SCENE:
            self._scene(body, now - STATUS_TRANSIT_S, events)
        elif kind == DOWN_THUMB_END:
            end = ThumbEnd.decode(body)
            w = self.thumb
            if w is not None and w.oid == end.oid and not w.verified:
                w.end = (end.object_mac, self.session)
                self._try_verify(w, events)

    def _scene(self, body: bytes, made: float, events: list) -> None:
        """§11.2: ALT, then records up to the zero padding."""
        self.counters.scenes += 1
        events.append(SceneAltitude(altitude_from_code(body[0]), made, body[0]))
        try:
            records, dropped = decode_records(body[1:], padded=True)
        except ValueError:
            records, dropped = [], 1  # a record cut short by the body's end: authentic, but nothing to show
        for r in records:
            events.append(SceneObjectRemoved(r.object_id, made) if r.op == OP_REMOVED
                          else SceneObjectReported(SeenObject.from_record(r), made, len(r.encode())))
        if dropped:
            self.counters.records_ignored += dropped
            events.append(SceneRecordIgnored(bytes(body[1:]).hex(" ")))

    def _status(self, st: StatusBody, ctr: int, made: float, now: float, events: list) -> None:
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
                if st.result in NEVER_TAKEN and self.thumb is not None and self.thumb.oid == oid:
                    self.thumb = None
            self._watch[oid] = st.result
            if st.result != R_TAKEN:
                del self._watch[oid]  # final
        if self.stop_active and st.stop_no2 == self.stop_no & 3:
            if st.autopilot and st.hold and st.mode in (Mode.POS_HOLD, Mode.DEPTH_HOLD):
                self.stop_active = False
                events.append(StopTaken(self.stop_no, self._stop_pressed_at))
            elif not st.autopilot and not self._stop_reported_off:
                self._stop_reported_off = True
                events.append(StopImpossible(self.stop_no))

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
