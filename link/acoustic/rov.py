"""The ROV's end of the acoustic profile (§9): `AcousticRov`."""

from __future__ import annotations

import collections
import hmac
import os
from dataclasses import dataclass, field
from typing import Callable

from ..radio.auth import mac
from ..scene import SceneOutbox, altitude_code
from ..vocabulary import Mode
from .bodies import GoToBody, OrderBody, PollBody, StatusBody, StopBody, SyncBody, ThumbEnd, ThumbRequest, same_body, steady_bytes
from .events import (
    ArmWanted,
    DisarmWanted,
    FailsafeEnded,
    FailsafeStarted,
    GoToWanted,
    HoldWanted,
    ModeWanted,
    SessionStarted,
    StopWanted,
    SurfaceWanted,
    ThumbnailWanted,
)
from .packets import _ahead, _End, data_packet, slot_count
from .sealing import object_mac, seal_sync
from .wire import (
    BOOT_BYTES,
    BRAKE_SHOWN_S,
    CHALLENGE_BYTES,
    CHALLENGES_SEEN,
    CTR_WINDOW,
    DATA_BYTES,
    DOWN_SCENE,
    DOWN_STATUS,
    DOWN_STATUS_SAME,
    DOWN_THUMB_END,
    FAILSAFE_HOLD,
    FAILSAFE_S,
    FAILSAFE_SURFACE,
    HOLD_MODES,
    IN_FLIGHT_S,
    LABEL_DOWN,
    LABEL_HELLO,
    LABEL_UP,
    LONG_BODY,
    MAX_OBJECT,
    MAX_SLOTS,
    NONCE_BYTES,
    OP_ARM,
    OP_DISARM,
    OP_HOLD,
    OP_MODE,
    OP_SURFACE,
    R_ABORTED,
    R_CANCELLED,
    R_DONE,
    R_IMPOSSIBLE,
    R_INVALID,
    R_NONE,
    R_TAKEN,
    SAME_REACH,
    SCENE_ALT_REPEAT_S,
    SCENE_ALT_STEPS,
    SCENE_REFRESH_GAP_S,
    SCENE_REFRESH_S,
    STATUS_REPEAT_S,
    STATUS_THUMB_S,
    TAG_BYTES,
    UP_GOTO,
    UP_ORDER,
    UP_PACKETS,
    UP_POLL,
    UP_STOP,
    UP_THUMB,
    UPLINK_FRESH_S,
)


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
        # §11.2: what the ROV tells of its scene (altitude, objects) in SCENE frames.
        self.scene = SceneOutbox()
        self._status_since_scene = False  # a SCENE goes only after a STATUS: they alternate at most
        self.follows = False  # the node has a tracker: a THUMB with FOLLOW can be taken
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

    def status(self, now: float) -> StatusBody:
        v = self.vehicle
        since = max(t for t in (self._heard_at, self._session_at, -1e18) if t is not None)
        uplink = now - since < UPLINK_FRESH_S  # a session's start counts: its HELLO was heard
        return StatusBody(
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
            events.append(StopWanted(None))
        # §9.4 (decided): no failsafe before a session's first frame: the start's brake holds.
        if not self.failsafe and self._heard_at is not None and now - self._heard_at >= self.failsafe_s:
            self.failsafe = True
            self._failsafe_unreported = True
            self.hold = True
            self._abort_motion()
            self.counters.failsafes += 1
            self._prompt()
            self._brake_asked = (now, (Mode.SURFACE,) if self.failsafe_action == FAILSAFE_SURFACE else HOLD_MODES)
            events.append(FailsafeStarted(self.failsafe_action))
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
        self.scene.forget_operator()  # a new session's operator holds none of the scene
        self._status_since_scene = False
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
            events.append(FailsafeEnded())
        if kind == UP_POLL:
            self._poll(PollBody.decode(body), now)
        elif kind == UP_STOP:
            self._stop(StopBody.decode(body), now, events)
        elif kind == UP_ORDER:
            self._order(OrderBody.decode(body), now, events)
        elif kind == UP_GOTO:
            self._order(GoToBody.decode(body), now, events)
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
        events.append(StopWanted(stop.stop_no, new))

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

    def _order(self, order: OrderBody | GoToBody | ThumbRequest, now: float, events: list) -> None:
        d = _ahead(order.oid, self.last_oid)
        if not 1 <= d <= 127:
            self.counters.orders_stale += 1
            if d == 0 and now - self._status_at >= STATUS_REPEAT_S:
                self._status_asap = True  # its confirmation may have been lost
            return
        self.counters.orders_taken += 1
        self.last_oid = order.oid
        self._prompt()
        if isinstance(order, GoToBody):
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
        if isinstance(order, GoToBody):
            impossible |= not v.armed or not v.position_valid
        elif isinstance(order, OrderBody) and order.op == OP_MODE:
            impossible |= order.arg in (Mode.POS_HOLD, Mode.GUIDED) and not v.position_valid
        elif isinstance(order, ThumbRequest):
            impossible = order.follow and not self.follows  # FOLLOW needs a tracker on this ROV
        if impossible:
            self.result = R_IMPOSSIBLE
            return
        self.result = R_TAKEN
        if isinstance(order, GoToBody):
            self.hold = False
            events.append(GoToWanted(order.oid, order))
        elif isinstance(order, ThumbRequest):
            self.thumb = _Thumb(order.oid)
            events.append(ThumbnailWanted(order.oid, order))
        else:
            if order.op in (OP_SURFACE, OP_MODE):
                self.hold = False
            events.append({OP_HOLD: lambda: HoldWanted(order.oid), OP_SURFACE: lambda: SurfaceWanted(order.oid),
                           OP_ARM: lambda: ArmWanted(order.oid), OP_DISARM: lambda: DisarmWanted(order.oid),
                           OP_MODE: lambda: ModeWanted(order.oid, order.arg)}[order.op]())

    def _poll(self, poll: PollBody, now: float) -> None:
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
        if not self._status_asap and self._status_since_scene:
            scene = self._scene_packet(now)  # after STOP and the status, ahead of thumbnail data
            if scene is not None:
                return scene
        if sending and not self._status_asap and now - self._status_at < self.status_thumb_s:
            packet = self._data_packet(now)
            if packet is not None:
                return packet
        return self._status_packet(now)  # due, asked for, or a free slot (the turns pass anyway)

    def _scene_packet(self, now: float) -> bytes | None:
        """A SCENE frame (§11.2) when there are records to tell or the altitude moved; its
        records count as told once handed (nothing acknowledges them: SCENE_REFRESH_S mends)."""
        self.scene.refresh(now, SCENE_REFRESH_S, SCENE_REFRESH_GAP_S)
        alt = self.scene.altitude_due(now, SCENE_ALT_REPEAT_S, SCENE_ALT_STEPS)
        if not self.scene.pending() and alt is None:
            return None
        code = alt if alt is not None else altitude_code(self.scene.altitude_m)
        records = b""
        while True:
            record = self.scene.next_record(LONG_BODY - 1 - len(records))
            if record is None:
                break
            records += record.encode()
            self.scene.delivered(record, now)
        self.scene.altitude_delivered(code, now)
        self._status_since_scene = False
        body = bytes((code,)) + records + bytes(LONG_BODY - 1 - len(records))
        self.counters.scenes += 1
        return self._emit_frame(self._seal(DOWN_SCENE, body)[1], "scene")

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
        self._status_since_scene = True
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
