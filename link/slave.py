"""The ROV's end of the link (PROTOCOL.md §2–5), without I/O.

Goals: answer every valid poll at once and no corrupted one; run each
one-shot order exactly once; never let image encoding delay a reply; know
when the operator has gone silent so the vehicle can stop.

Plan: `receive(payload, now)` (or `receive_bytes(data, now)` through the
slave's own FrameDecoder) consumes a poll and returns a `SlaveOutput`: the
reply frame to send (None when there is nothing to answer) and the events for
the ROV node (velocity wish, orders to execute, image wanted, failsafe).
The node keeps the status current with `update_status` and hands finished
images in with `image_ready`; `tick(now)` reports the failsafe when polls stop.

Decisions where PROTOCOL.md is silent:
- A poll whose header is valid but whose order body is not (out-of-range
  value, reserved bits) is answered, its order ignored and reported as
  `OrderRejected`; ACK is not flipped, since nothing was executed.  A poll
  whose header is invalid is not answered (it cannot be trusted at all).
- FAILSAFE in a reply reports the state the poll found: the first reply
  after a link loss still says FAILSAFE, so the operator learns of it; the
  failsafe clears right after.
- The held image is dropped on failsafe, so an operator that comes back asks
  for, and gets, a fresh picture rather than one from before the loss.
- Image settings before any IMAGE order: `default_settings` (mono, 2000
  bytes, no ROI).  BUDGET 0 turns images off: requests get no image data.
- The trunk is the smaller of the SIZE class, the link's frame limit
  (`max_frame`) and `trunk_cap` (the paper's fixed 40-byte trunks).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable, Optional

from .frame import OVERHEAD, FrameDecoder, encode_frame
from .messages import (
    MAX_OBJECT,
    NO_IMAGE_DATA,
    REPLY_IMAGE_HEADER,
    SIZE_CLASS_BYTES,
    ImageSettings,
    Mode,
    NoOrder,
    Poll,
    Position,
    ProtocolError,
    Reply,
    ReservedOrder,
    Stop,
    Velocity,
)

# ---------------------------------------------------------------------------
# Events handed to the ROV node
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class VelocityCommanded:
    velocity: Velocity  # includes ARM and MODE requests


@dataclass(frozen=True)
class OrderExecuted:
    order: Position | ImageSettings | Stop


@dataclass(frozen=True)
class OrderRejected:
    code: int
    reason: str


@dataclass(frozen=True)
class ImageWanted:
    img: int
    settings: ImageSettings


@dataclass(frozen=True)
class ImageDelivered:
    """The reply carries the LAST trunk of image `img` (it may still be lost)."""

    img: int


@dataclass(frozen=True)
class FailsafeEntered:
    silent_s: float


@dataclass(frozen=True)
class FailsafeCleared:
    pass


@dataclass(frozen=True)
class Status:
    """What the reply reports besides the image (set by the ROV node)."""

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
    trunk_bytes_sent: int = 0
    replies_sent: int = 0


ImageSource = Callable[[int, ImageSettings], Optional[bytes]]


def clamp_int(value: float, lo: int, hi: int) -> int:
    return max(lo, min(hi, int(round(value))))


class Slave:
    """ROV-side protocol state machine (sans I/O)."""

    def __init__(
        self,
        *,
        image_source: ImageSource | None = None,
        failsafe_s: float = 3.0,
        max_frame: int = 259,
        trunk_cap: int | None = None,
        default_settings: ImageSettings | None = None,
        now: float = 0.0,
    ) -> None:
        if max_frame < OVERHEAD + REPLY_IMAGE_HEADER + 1:
            raise ValueError(f"max_frame must be at least {OVERHEAD + REPLY_IMAGE_HEADER + 1} bytes")
        self.image_source = image_source
        self.failsafe_s = failsafe_s
        self.max_frame = min(max_frame, 259)
        self.trunk_cap = trunk_cap
        self.settings = default_settings or ImageSettings(mono=True, budget_bytes=2000)
        self.ack = 0
        self.status = Status()
        self.stats = SlaveStats()
        self.decoder = FrameDecoder()
        self.velocity = Velocity()
        self._last_poll_at = now
        self._failsafe = False
        self._held_img: int | None = None
        self._held_object: bytes | None = None
        self._pending_events: list[object] = []

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

    @property
    def failsafe(self) -> bool:
        return self._failsafe

    @property
    def held_img(self) -> int | None:
        return self._held_img

    def silent_for(self, now: float) -> float:
        return now - self._last_poll_at

    def tick(self, now: float) -> list[object]:
        """Check the link-loss failsafe; returns FailsafeEntered when it trips."""
        events, self._pending_events = self._pending_events, []
        if not self._failsafe and self.silent_for(now) >= self.failsafe_s:
            self._failsafe = True
            self.velocity = Velocity()
            self._held_img = None
            self._held_object = None
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
            seq, size, code, img, offset = Poll.decode_header(payload)
        except ProtocolError:
            self.stats.protocol_errors += 1
            return out
        try:
            poll: Poll | None = Poll.decode(payload)
        except ProtocolError as exc:
            poll = None
            self.stats.orders_rejected += 1
            out.events.append(OrderRejected(code, str(exc)))
        self.stats.polls += 1
        self._last_poll_at = now
        failsafe_seen = self._failsafe
        if self._failsafe:
            self._failsafe = False
            out.events.append(FailsafeCleared())

        if poll is not None:
            out.events.extend(self._apply_order(poll))
        trunk_img, trunk_offset, trunk = self._serve_image(img, offset, size, out.events)
        reply = Reply(
            **dataclasses.asdict(self.status),  # odometry and flags, named as in the reply
            ack=self.ack,
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

    def _apply_order(self, poll: Poll) -> list[object]:
        order = poll.order
        if isinstance(order, Velocity):
            self.velocity = order
            return [VelocityCommanded(order)]
        if isinstance(order, ReservedOrder):
            self.stats.orders_rejected += 1
            return [OrderRejected(order.code, f"reserved order code {order.code}")]
        if isinstance(order, NoOrder):
            return []
        # One-shot: run only when SEQ differs from ACK (§3).
        if poll.seq == self.ack:
            self.stats.orders_repeated += 1
            return []
        self.ack = poll.seq
        self.stats.orders_executed += 1
        if isinstance(order, ImageSettings):
            self.settings = order
        elif isinstance(order, (Stop, Position)):
            self.velocity = Velocity()  # a STOP or a position target replaces the wish
        return [OrderExecuted(order)]

    def _serve_image(self, img: int, offset: int, size: int, events: list[object]):
        if offset == NO_IMAGE_DATA or self.settings.budget_bytes == 0:
            return None, None, b""
        if img != self._held_img:
            self._held_img = img
            self._held_object = None
            settings = self.settings
            stream = self.image_source(img, settings) if self.image_source else None
            if stream is not None:
                self._held_object = self._wrap(stream)
            else:
                events.append(ImageWanted(img, settings))
        obj = self._held_object
        if obj is None or offset >= len(obj):
            return None, None, b""
        limit = min(SIZE_CLASS_BYTES[size], self.max_frame - OVERHEAD - REPLY_IMAGE_HEADER)
        if self.trunk_cap is not None:
            limit = min(limit, self.trunk_cap)
        trunk = obj[offset : offset + limit]
        return img, offset, trunk

    @staticmethod
    def _wrap(stream: bytes) -> bytes:
        stream = bytes(stream)[: MAX_OBJECT - 2]
        return len(stream).to_bytes(2, "big") + stream


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
) -> Status:
    """Build a Status from SI units, clamping to what the reply can carry."""

    def wrap_deg(a: float) -> float:
        return (a + 180.0) % 360.0 - 180.0

    return Status(
        armed=armed,
        mode=mode,
        x_cm=clamp_int(x_m * 100, -32768, 32767),
        y_cm=clamp_int(y_m * 100, -32768, 32767),
        z_cm=clamp_int(z_m * 100, -32768, 32767),
        roll_cdeg=clamp_int(wrap_deg(roll_deg) * 100, -18000, 18000),
        pitch_cdeg=clamp_int(wrap_deg(pitch_deg) * 100, -18000, 18000),
        yaw_cdeg=clamp_int(wrap_deg(yaw_deg) * 100, -18000, 18000),
        autopilot=autopilot,
        position_valid=position_valid,
    )
