"""What the radio profile's machines tell their callers (h11's way: one module,
a base class, frozen dataclasses; names unique across both profiles): the
master's events to the console, version 2's own, the slave's to the ROV node."""

from __future__ import annotations

from dataclasses import dataclass

# The picture events are both profiles' (link/pictures.py): the master hands them on.
from ..pictures import PILOT_SKIPPED, ImageAbandoned, ImageComplete, ImageProgress  # noqa: F401
from ..report import VehicleReport
from ..scene import SeenObject
from .messages import REASON_TEXT, ImageSettings, Mode, Poll, Position, Reason, Reply, Velocity


class RadioEvent:
    """Base of every event the radio profile's machines hand their callers."""


# ---------------------------------------------------------------------------
# Events handed to the console
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class PollSent(RadioEvent):
    """A poll (or, in version 2, a HELLO) went out: what it carried, so that no one
    decodes the master's bytes again.  `order_ids`: the master's ids of the one-shot
    order or the STOP it carried (a STOP pressed twice: both), else empty."""

    at: float
    frame: bytes  # as sent (version 2: sealed)
    poll: Poll | None  # None for a HELLO
    order_ids: tuple[int, ...] = ()

    @property
    def hello(self) -> bool:
        return self.poll is None


@dataclass(frozen=True)
class AltitudeReported(RadioEvent):
    """A reply's ALT (§11.1): the vehicle's altitude above the seabed when it answered;
    None: unknown (no rangefinder reports) or beyond 37 m.  Replies that leave it out
    leave it as it was (the ROV tells it again within 2 s)."""

    at: float
    altitude_m: float | None
    code: int  # the ALT byte as carried


@dataclass(frozen=True)
class ObjectReported(RadioEvent):
    """An object the ROV recognised, new or changed (§11): `obj.new` tells which; a
    CHANGED for an id not held is shown as new."""

    at: float
    obj: SeenObject
    record_bytes: int


@dataclass(frozen=True)
class ObjectRemoved(RadioEvent):
    """The ROV no longer holds object `object_id` (merged into another, or a false one)."""

    at: float
    object_id: int


@dataclass(frozen=True)
class ObjectRecordIgnored(RadioEvent):
    """An object record whose values are out of range (a reserved class, a size of 0):
    counted and ignored (`SecureStats.records_ignored`)."""

    at: float
    record_hex: str


@dataclass(frozen=True)
class PoseReceived(RadioEvent):
    reply: Reply
    at: float
    round_trip_s: float | None
    # The same in SI, with when the ROV sampled it (link/report.py): what the console reads.
    report: VehicleReport | None = None


@dataclass(frozen=True)
class OrderAcknowledged(RadioEvent):
    order_id: int
    order: object
    at: float


@dataclass(frozen=True)
class OrderRejected(RadioEvent):
    """The ROV took the order (ACK flipped) and rejected it: docs/PROTOCOL.md §3 REASON."""

    order_id: int
    order: object
    reason: int  # 0 invalid, 1 impossible now / abandoned, 2 refused by the autopilot, 3 unknown
    at: float

    @property
    def reason_text(self) -> str:
        return REASON_TEXT[Reason(self.reason)]


@dataclass(frozen=True)
class OrderCancelled(RadioEvent):
    order_id: int
    order: object
    reason: str


@dataclass(frozen=True)
class OrderNotSent(RadioEvent):
    """A queued order a STOP cancelled before it went out."""

    order_id: int
    order: object
    reason: str


@dataclass(frozen=True)
class OrderFateUnknown(RadioEvent):
    """Version 2 (§8): the ROV restarted (a new BOOT) before the answer to this
    sent order came; the old ROV may have run it, so it is not sent again."""

    order_id: int
    order: object
    at: float


@dataclass(frozen=True)
class StopConfirmed(RadioEvent):
    order_id: int
    mode: int  # POS_HOLD or DEPTH_HOLD
    at: float


@dataclass(frozen=True)
class StopNotCarriedOut(RadioEvent):
    """A reply to a STOP poll shows no autopilot: nothing holds the vehicle."""

    order_id: int
    at: float




@dataclass(frozen=True)
class ReplyLost(RadioEvent):
    poll_sent_at: float
    at: float


@dataclass(frozen=True)
class RequestExpired(RadioEvent):
    what: str  # "arm" or "mode"


# -- version 2 (link/radio/secure.py) ------------------------------------------


@dataclass(frozen=True)
class InauthenticFrame(RadioEvent):
    """A frame whose CRC held but whose tag no kept chain value makes (counted, dropped)."""

    side: str  # "reply" (operator) or "poll" (ROV)


@dataclass(frozen=True)
class LateReply(RadioEvent):
    """An authentic reply to a poll already answered, older than one answered, or past its timeout."""

    sync: bool


@dataclass(frozen=True)
class Synced(RadioEvent):
    """A SYNC taken: the chain is (re)started; `restarted` when the ROV's BOOT changed."""

    boot: bytes
    restarted: bool
    first: bool


# ---------------------------------------------------------------------------
# Events handed to the ROV node
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class VelocityCommanded(RadioEvent):
    velocity: Velocity  # the axes to apply now (ARM/MODE come as their own events)
    replaces_target: bool = False  # a standing POSITION target or brake ends here


@dataclass(frozen=True)
class ArmRequested(RadioEvent):
    arm: bool  # True arm, False disarm


@dataclass(frozen=True)
class ModeRequested(RadioEvent):
    mode: Mode


@dataclass(frozen=True)
class WishInvalid(RadioEvent):
    why: str


@dataclass(frozen=True)
class OrderStarted(RadioEvent):
    """A one-shot order that needs the autopilot's answer: call `Slave.order_outcome(token, ...)`."""

    token: int
    order: Position


@dataclass(frozen=True)
class OrderExecuted(RadioEvent):
    order: Position | ImageSettings


@dataclass(frozen=True)
class OrderDeclined(RadioEvent):
    code: int
    reason: int  # docs/PROTOCOL.md §3 REASON
    why: str


@dataclass(frozen=True)
class OrderAbandoned(RadioEvent):
    token: int
    why: str


@dataclass(frozen=True)
class BrakeRequested(RadioEvent):
    why: str  # "start", "STOP", "late accept"
    hold: bool


@dataclass(frozen=True)
class ImageWanted(RadioEvent):
    img: int
    settings: ImageSettings


@dataclass(frozen=True)
class ImageDelivered(RadioEvent):
    """The reply carries the LAST trunk of image `img` (it may still be lost)."""

    img: int


@dataclass(frozen=True)
class FailsafeEntered(RadioEvent):
    silent_s: float


@dataclass(frozen=True)
class FailsafeCleared(RadioEvent):
    pass
