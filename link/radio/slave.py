"""The ROV's end of the link (docs/PROTOCOL.md §2–5, version 1.1), without I/O.

Goals: answer every valid poll at once and no corrupted one; run each
one-shot order at most once and report its outcome (ACK flips when it is
known, with REJECTED/REASON); never let image encoding delay a reply; know
when the operator has gone silent so the vehicle can stop; never move the
vehicle on a stale or held wish.

Plan: `receive(payload, now)` (or `receive_bytes(data, now)` through the
slave's own FrameDecoder) consumes a poll and returns a `SlaveOutput`: the
reply frame to send (None when there is nothing to answer) and the events for
the ROV node.  The node keeps the status current with `update_status`, hands
finished images in with `image_ready`, answers `OrderStarted` with
`order_outcome(token, accepted, reason, now)` once the autopilot has
answered, and calls `tick(now)` (at least every 0.1 s) for the failsafe, the
velocity lapse and the 2 s autopilot wait.

Events for the node:
- `VelocityCommanded(velocity, replaces_target)`: the velocity to apply now
  (axes only; neutral when held, invalid or lapsed).  `replaces_target`: a
  standing POSITION target or brake is replaced by this wish (§2).
- `ArmRequested(arm)`, `ModeRequested(mode)`: an ARM/MODE request acted on (§2).
- `OrderStarted(token, order)`: a POSITION the autopilot must answer.
- `OrderExecuted(order)`: IMAGE settings taken, or a POSITION the autopilot
  accepted; `OrderDeclined(code, reason, why)`: ACK flipped with REJECTED.
- `OrderAbandoned(token, why)`: an order in progress given up (STOP, failsafe,
  superseded, no answer within 2 s).  The node keeps watching its ticket: a
  late accept is still reported with `order_outcome`.
- `BrakeRequested(why, hold)`: brake as for STOP (POS_HOLD with a position
  estimate, else DEPTH_HOLD): at start, on every STOP poll, and on a late
  accept of an abandoned order (`hold` False).  The failsafe brakes through
  `FailsafeEntered` instead.
- `WishInvalid(why)`: a VELOCITY with -128, ARM 3 or MODE 7 (applied as neutral).
- `ImageWanted`, `ImageDelivered`, `FailsafeEntered`, `FailsafeCleared`.

Decisions where docs/PROTOCOL.md is silent:
- A structural fault (§1) is counted and not answered.  A reserved order
  code (5–15) is handled like an invalid order: rejected with REASON 0 and its
  poll does not feed the failsafe timer (it did not decode to an order this
  ROV knows).  A repeated poll of an invalid one-shot (SEQ = ACK) does not
  feed it either.
- An invalid VELOCITY or one-shot poll while the failsafe is active does not
  clear it (it does not feed the timer); only a poll that does clears it.
- A POSITION is rejected by the slave itself (REASON 1) when the status the
  node last set shows no autopilot, no position estimate or a disarmed
  vehicle; the bridge checks again (its refusal also comes back as REASON 1).
- A POSITION's target stands from the autopilot's accept; while the order is
  in progress the wish is applied as usual.  A cancelled autopilot request
  (another mode requested, the bridge stopping) is reported by the node as
  REASON 1.
- While HOLD is set, a non-zero wish is applied as neutral; the zero wish
  that clears HOLD is itself applied (neutral).
- FAILSAFE in a reply reports the state the poll found: the first reply
  after a link loss still says FAILSAFE, so the operator learns of it; the
  failsafe clears right after (HOLD stays until a neutral wish).
- The held image is kept through a failsafe (§4 (1.1)); an operator that
  starts asks for two images and shows the second.
- Image settings before any IMAGE order: `default_settings` (mono, 2000
  bytes, no ROI).  BUDGET 0 turns images off: requests get no image data
  and start no capture.
- A fresh capture is sent from offset 0 first, whatever OFFSET the poll that
  started it asked for (§4 (1.1)); after that first trunk, the requested OFFSET.
- The trunk is the smaller of the SIZE class, the link's frame limit
  (`max_frame`) and `trunk_cap` (the paper's fixed 40-byte trunks).
- The receive LEN cap (§1 (1.1)) is the largest poll: 12 payload bytes.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable, Optional

from .events import (
    ArmRequested,
    BrakeRequested,
    FailsafeCleared,
    FailsafeEntered,
    ImageDelivered,
    ImageWanted,
    ModeRequested,
    OrderAbandoned,
    OrderDeclined,
    OrderExecuted,
    OrderStarted,
    VelocityCommanded,
    WishInvalid,
)
from .frame import MAX_FRAME, OVERHEAD, FrameDecoder, encode_frame
from .messages import (
    ANGLE_CDEG,
    FAILSAFE_S,
    MAX_OBJECT,
    MAX_POLL_PAYLOAD,
    MIN_FRAME,
    NO_IMAGE_DATA,
    OBJECT_LENGTH_BYTES,
    REPLY_IMAGE_HEADER,
    SIZE_CLASS_BYTES,
    VELOCITY_LAPSE_S,
    XYZ_CM,
    Arm,
    ImageSettings,
    InvalidOrder,
    Mode,
    NoOrder,
    Poll,
    Position,
    ProtocolError,
    Reason,
    Reply,
    ReservedOrder,
    Stop,
    Velocity,
)


@dataclass(frozen=True)
class Status:
    """What the reply reports besides the image and the order state (set by the ROV node)."""

    armed: bool = False
    mode: int = Mode.UNKNOWN
    x_cm: int = 0
    y_cm: int = 0
    z_cm: int = 0
    roll_cdeg: int = 0
    pitch_cdeg: int = 0
    yaw_cdeg: int = 0
    autopilot: bool = False
    position_valid: bool = False
    attitude_valid: bool = False


@dataclass
class SlaveOutput:
    reply: bytes | None = None
    events: list[object] = field(default_factory=list)


@dataclass
class SlaveStats:
    polls: int = 0
    protocol_errors: int = 0
    orders_executed: int = 0
    orders_repeated: int = 0
    orders_rejected: int = 0
    orders_abandoned: int = 0
    invalid_wishes: int = 0
    velocity_lapses: int = 0
    trunk_bytes_sent: int = 0
    replies_sent: int = 0


@dataclass
class _Running:
    """A one-shot order waiting for the autopilot's answer."""

    token: int
    seq: int
    key: tuple[int, bytes]
    order: Position
    started_at: float


ImageSource = Callable[[int, ImageSettings], Optional[bytes]]


def clamp_int(value: float, lo: int, hi: int) -> int:
    return max(lo, min(hi, int(round(value))))


class Slave:
    """ROV-side protocol state machine (sans I/O)."""

    def __init__(
        self,
        *,
        image_source: ImageSource | None = None,
        failsafe_s: float = FAILSAFE_S,
        velocity_lapse_s: float = VELOCITY_LAPSE_S,
        autopilot_wait_s: float = 2.0,
        max_frame: int = MAX_FRAME,
        trunk_cap: int | None = None,
        default_settings: ImageSettings | None = None,
        now: float = 0.0,
    ) -> None:
        if max_frame < MIN_FRAME:
            raise ValueError(f"max_frame must be at least {MIN_FRAME} bytes")
        self.image_source = image_source
        self.failsafe_s = failsafe_s
        self.velocity_lapse_s = velocity_lapse_s
        self.autopilot_wait_s = autopilot_wait_s
        self.max_frame = min(max_frame, MAX_FRAME)
        self.trunk_cap = trunk_cap
        # SIZE -> trunk bytes; None: version 1.1's classes within max_frame
        # (version 2 sizes its trunks itself: link.secure).
        self.trunk_room: Callable[[int], int] | None = None
        self.settings = default_settings or ImageSettings(mono=True, budget_bytes=2000)
        self.follows = False  # §10: the ROV has a tracker for FOLLOW (its node says so)
        self.ack = 0
        self.rejected = False  # REJECTED/REASON describe the order named by ACK
        self.reason = 0
        self.hold = True  # at start: brake and HOLD (§2 STOP)
        self.status = Status()
        self.stats = SlaveStats()
        self.decoder = FrameDecoder(max_len=min(MAX_POLL_PAYLOAD, self.max_frame - OVERHEAD))
        self.velocity = Velocity()  # the wish applied now (axes only)
        self.standing: str | None = "brake"  # "brake" or "position": a target that stands (§2)
        self._reference: tuple[Arm, Mode] | None = None  # ARM/MODE of the last valid VELOCITY
        self._velocity_at: float | None = None  # last valid VELOCITY poll, for the lapse
        self._last_poll_at = now
        self._failsafe = False
        self._running: _Running | None = None
        self._next_token = 1
        self._positions_taken = 0
        self._abandoned: dict[int, int] = {}  # token -> POSITIONs taken when it was abandoned
        self._held_img: int | None = None
        self._held_object: bytes | None = None
        self._fresh = False  # the held image has not yet been sent from offset 0
        self._pending_events: list[object] = [BrakeRequested("start", hold=True)]

    # ------------------------------------------------------------------
    # Node-facing
    # ------------------------------------------------------------------

    def update_status(self, status: Status) -> None:
        self.status = status

    def image_ready(self, img: int, stream: bytes) -> bool:
        """Hand in the DEBT stream encoded for `img`; False if no longer wanted."""
        if img != self._held_img or self._held_object is not None:
            return False
        self._held_object = self._wrap(stream)
        return True

    def order_outcome(self, token: int, accepted: bool, reason: int | None = None, now: float = 0.0) -> list[object]:
        """The autopilot's answer to the order of `OrderStarted(token)`.

        For the order in progress ACK flips now (REJECTED with `reason`, 2 by
        default, when not accepted).  For an abandoned one nothing flips; if the
        autopilot accepted it and no newer POSITION has been taken since, the
        vehicle brakes as for STOP, without HOLD (§3).
        """
        running = self._running
        if running is not None and running.token == token:
            self._running = None
            if accepted:
                self._flip(running.seq, None)
                self.standing = "position"
                self.stats.orders_executed += 1
                return [OrderExecuted(running.order)]
            why_reason = Reason.REFUSED if reason is None else int(reason)
            self._flip(running.seq, why_reason)
            self.stats.orders_rejected += 1
            return [OrderDeclined(running.order.code, why_reason, "refused by the autopilot")]
        taken = self._abandoned.pop(token, None)
        if taken is not None and accepted and taken == self._positions_taken:
            self.standing = "brake"
            return [BrakeRequested("late accept", hold=False)]
        return []

    @property
    def failsafe(self) -> bool:
        return self._failsafe

    @property
    def failsafe_at(self) -> float | None:
        """When the failsafe starts unless a valid poll comes first; None while in it."""
        return None if self._failsafe else self._last_poll_at + self.failsafe_s

    @property
    def held_img(self) -> int | None:
        return self._held_img

    @property
    def order_in_progress(self) -> Position | None:
        return self._running.order if self._running else None

    def silent_for(self, now: float) -> float:
        return now - self._last_poll_at

    def tick(self, now: float) -> list[object]:
        """The timers: the 2 s autopilot wait, the velocity lapse, the link-loss failsafe."""
        events, self._pending_events = self._pending_events, []
        running = self._running
        if running is not None and now - running.started_at >= self.autopilot_wait_s:
            events += self._abandon(Reason.REFUSED, "no answer from the autopilot within 2 s")
        if self._velocity_at is not None and now - self._velocity_at >= self.velocity_lapse_s:
            self._velocity_at = None  # the reference is kept (§2)
            self.stats.velocity_lapses += 1
            if not self.velocity.is_neutral:
                self.velocity = Velocity()
                events.append(VelocityCommanded(Velocity()))
        if not self._failsafe and self.silent_for(now) >= self.failsafe_s:
            self._failsafe = True
            events += self._abandon(Reason.IMPOSSIBLE, "failsafe")
            self._brake()
            events.append(FailsafeEntered(self.silent_for(now)))
        return events

    # ------------------------------------------------------------------
    # Polls in, replies out
    # ------------------------------------------------------------------

    def receive_bytes(self, data: bytes, now: float) -> SlaveOutput:
        """Feed raw bytes; returns the replies (concatenated) and events."""
        out = SlaveOutput(events=self.tick(now))
        replies = []
        for payload in self.decoder.feed(data):
            one = self.receive(payload, now)
            out.events.extend(one.events)
            if one.reply:
                replies.append(one.reply)
        out.reply = b"".join(replies) or None
        return out

    def receive(self, payload: bytes, now: float) -> SlaveOutput:
        """Consume one poll payload (a frame whose CRC held)."""
        out = SlaveOutput(events=self.tick(now))
        try:
            poll = Poll.decode(payload)
        except ProtocolError:
            self.stats.protocol_errors += 1  # a structural fault: never answered
            return out
        self.stats.polls += 1
        order = poll.order
        valid = not isinstance(order, (InvalidOrder, ReservedOrder))
        failsafe_seen = self._failsafe
        if valid:
            self._last_poll_at = now  # only a completely decodable poll feeds the failsafe (§5)
            if self._failsafe:
                self._failsafe = False
                out.events.append(FailsafeCleared())
        out.events.extend(self._apply_order(poll, now))
        trunk_img, trunk_offset, trunk = self._serve_image(poll.img, poll.offset, poll.size, out.events)
        reply = Reply(
            **dataclasses.asdict(self.status),  # odometry and flags, named as in the reply
            ack=self.ack,
            hold=self.hold,
            rejected=self.rejected,
            reason=self.reason,
            failsafe=failsafe_seen,
            img=trunk_img,
            offset=trunk_offset,
            trunk=trunk,
            last=bool(trunk) and trunk_offset + len(trunk) == len(self._held_object or b""),
        )
        out.reply = encode_frame(reply.encode())
        if reply.last:
            out.events.append(ImageDelivered(trunk_img))
        self.stats.replies_sent += 1
        self.stats.trunk_bytes_sent += len(trunk)
        return out

    # -- orders -----------------------------------------------------------

    def _apply_order(self, poll: Poll, now: float) -> list[object]:
        order = poll.order
        if isinstance(order, Velocity):
            return self._wish(order, now)
        if isinstance(order, InvalidOrder) and not order.one_shot:
            self.stats.invalid_wishes += 1
            events: list[object] = [WishInvalid(order.why)]
            if not self.velocity.is_neutral:  # neutral instead; a standing target stays
                self.velocity = Velocity()
                events.append(VelocityCommanded(Velocity()))
            return events
        if isinstance(order, Stop):
            events = self._abandon(Reason.IMPOSSIBLE, "STOP")
            self._brake()
            events.append(BrakeRequested("STOP", hold=True))
            return events
        if isinstance(order, NoOrder):
            return []
        return self._one_shot(poll, now)

    def _wish(self, v: Velocity, now: float) -> list[object]:
        events: list[object] = []
        self._velocity_at = now
        ref = self._reference
        if ref is None:
            # The first VELOCITY after start, a failsafe or a STOP only sets the
            # reference; a disarm acts whenever it arrives.
            if v.arm == Arm.DISARM:
                events.append(ArmRequested(False))
        else:
            if v.arm == Arm.DISARM or (v.arm == Arm.ARM and ref[0] != Arm.ARM):
                events.append(ArmRequested(v.arm == Arm.ARM))
            if v.mode != Mode.KEEP and v.mode != ref[1]:
                events.append(ModeRequested(v.mode))
                self.standing = None  # the autopilot leaves GUIDED or the hold: the target is gone
        self._reference = (v.arm, v.mode)
        axes = Velocity(v.vx, v.vy, v.vz, v.vyaw)
        if self.hold:
            if axes.is_neutral:
                self.hold = False  # re-centred
            else:
                axes = Velocity()  # ignored until the sticks are re-centred
        replaces = self.standing is not None and not axes.is_neutral
        if replaces:
            self.standing = None
        self.velocity = axes
        events.append(VelocityCommanded(axes, replaces_target=replaces))
        return events

    def _one_shot(self, poll: Poll, now: float) -> list[object]:
        key = poll.order_key
        running = self._running
        if running is not None and poll.seq == running.seq:
            if key == running.key:
                self.stats.orders_repeated += 1  # still waiting: never started twice
                return []
            # Same SEQ, another order: an operator that restarted; the new one
            # takes its place without a flip of its own (§3).
            events = self._abandon(None, "superseded by another order with the same SEQ")
            return events + self._take(poll, now)
        if running is None and poll.seq == self.ack:
            self.stats.orders_repeated += 1  # already taken: answered, not run again
            return []
        if running is not None:
            return []  # SEQ = ACK while an order is in progress: an old repeat
        return self._take(poll, now)

    def _take(self, poll: Poll, now: float) -> list[object]:
        order = poll.order
        if isinstance(order, (InvalidOrder, ReservedOrder)):
            why = order.why if isinstance(order, InvalidOrder) else f"reserved order code {order.code}"
            return self._reject_now(poll.seq, order.code, Reason.INVALID, why)
        if isinstance(order, ImageSettings):
            if order.follow and not self.follows:
                return self._reject_now(poll.seq, order.code, Reason.IMPOSSIBLE, "FOLLOW: this ROV has no tracker")
            self._flip(poll.seq, None)
            self.settings = order
            self.stats.orders_executed += 1
            return [OrderExecuted(order)]
        assert isinstance(order, Position)
        st = self.status
        if not st.autopilot:
            return self._reject_now(poll.seq, order.code, Reason.IMPOSSIBLE, "no autopilot")
        if not st.position_valid:
            return self._reject_now(poll.seq, order.code, Reason.IMPOSSIBLE, "no position estimate")
        if not st.armed:
            return self._reject_now(poll.seq, order.code, Reason.IMPOSSIBLE, "disarmed")
        token = self._next_token
        self._next_token += 1
        self._positions_taken += 1
        self._running = _Running(token, poll.seq, poll.order_key, order, now)
        self.velocity = Velocity()  # a position order replaces the wish
        return [OrderStarted(token, order)]

    def _reject_now(self, seq: int, code: int, reason: int, why: str) -> list[object]:
        self._flip(seq, reason)
        self.stats.orders_rejected += 1
        return [OrderDeclined(code, reason, why)]

    def _flip(self, seq: int, reason: int | None) -> None:
        self.ack = seq
        self.rejected = reason is not None
        self.reason = 0 if reason is None else int(reason)

    def _abandon(self, reason: int | None, why: str) -> list[object]:
        """Give up the order in progress; `reason` None: no flip (superseded)."""
        running = self._running
        if running is None:
            return []
        self._running = None
        self._abandoned[running.token] = self._positions_taken
        if len(self._abandoned) > 64:  # tickets that never answer
            del self._abandoned[next(iter(self._abandoned))]
        self.stats.orders_abandoned += 1
        events: list[object] = [OrderAbandoned(running.token, why)]
        if reason is not None:
            self._flip(running.seq, reason)
            self.stats.orders_rejected += 1
            events.append(OrderDeclined(running.order.code, reason, why))
        return events

    def _brake(self) -> None:
        """STOP and failsafe: neutral, target replaced by the brake, HOLD, reference reset."""
        self.velocity = Velocity()
        self._velocity_at = None
        self.standing = "brake"
        self.hold = True
        self._reference = None

    # -- images -----------------------------------------------------------

    def _serve_image(self, img: int, offset: int, size: int, events: list[object]):
        if offset == NO_IMAGE_DATA or self.settings.budget_bytes == 0:
            return None, None, b""  # no image data and no capture (§4)
        obj = self._held_object
        # A fresh capture answers from offset 0 whatever OFFSET is asked for.
        held = img == self._held_img and (obj is None or self._fresh or offset < len(obj))
        if not held:
            # Another IMG, or an OFFSET at or past the end of the one held: a
            # new capture under this IMG, sent from offset 0 first (§4 (1.1)).
            self._held_img = img
            self._held_object = None
            settings = self.settings
            stream = self.image_source(img, settings) if self.image_source else None
            if stream is not None:
                self._held_object = self._wrap(stream)
            else:
                events.append(ImageWanted(img, settings))
            self._fresh = True
        obj = self._held_object
        if obj is None:
            return None, None, b""  # still encoding: answer without image data
        if self.trunk_room is not None:
            limit = self.trunk_room(size)
        else:
            limit = min(SIZE_CLASS_BYTES[size], self.max_frame - OVERHEAD - REPLY_IMAGE_HEADER)
        if limit <= 0:
            return None, None, b""  # no room in this reply (a version 2 pose that filled it)
        if self._fresh:
            offset = 0
            self._fresh = False
        if offset >= len(obj):
            return None, None, b""
        if self.trunk_cap is not None:
            limit = min(limit, self.trunk_cap)
        trunk = obj[offset : offset + limit]
        return img, offset, trunk

    @staticmethod
    def _wrap(stream: bytes) -> bytes:
        stream = bytes(stream)[: MAX_OBJECT - OBJECT_LENGTH_BYTES]
        return len(stream).to_bytes(OBJECT_LENGTH_BYTES, "big") + stream


def status_from_pose(
    *,
    x_m: float,
    y_m: float,
    z_m: float,
    roll_deg: float,
    pitch_deg: float,
    yaw_deg: float,
    armed: bool,
    mode: int,
    autopilot: bool,
    position_valid: bool,
    attitude_valid: bool = False,
) -> Status:
    """Build a Status from SI units, clamping to what the reply can carry."""

    def wrap_deg(a: float) -> float:
        return (a + 180.0) % 360.0 - 180.0

    return Status(
        armed=armed,
        mode=mode,
        x_cm=clamp_int(x_m * 100, *XYZ_CM),
        y_cm=clamp_int(y_m * 100, *XYZ_CM),
        z_cm=clamp_int(z_m * 100, *XYZ_CM),
        roll_cdeg=clamp_int(wrap_deg(roll_deg) * 100, *ANGLE_CDEG),
        pitch_cdeg=clamp_int(wrap_deg(pitch_deg) * 100, *ANGLE_CDEG),
        yaw_cdeg=clamp_int(wrap_deg(yaw_deg) * 100, *ANGLE_CDEG),
        autopilot=autopilot,
        position_valid=position_valid,
        attitude_valid=attitude_valid,
    )
