"""What each end of the acoustic profile tells its caller (h11's way: one module,
a base class, frozen dataclasses; names unique across both profiles)."""

from __future__ import annotations

from dataclasses import dataclass

from ..scene import SeenObject
from .bodies import GoToBody, StatusBody, ThumbRequest


class AcousticEvent:
    """Base of every event an end of the acoustic profile hands its caller."""


# -- the ROV's end: what its node must do -------------------------------------


@dataclass(frozen=True)
class StopWanted(AcousticEvent):
    stop_no: int | None  # None: the brake at start
    new: bool = True  # False: a repeat of the STOP last taken (brake again, idempotent)


@dataclass(frozen=True)
class HoldWanted(AcousticEvent):
    oid: int


@dataclass(frozen=True)
class SurfaceWanted(AcousticEvent):
    oid: int


@dataclass(frozen=True)
class ArmWanted(AcousticEvent):
    oid: int


@dataclass(frozen=True)
class DisarmWanted(AcousticEvent):
    oid: int


@dataclass(frozen=True)
class ModeWanted(AcousticEvent):
    oid: int
    mode: int


@dataclass(frozen=True)
class GoToWanted(AcousticEvent):
    oid: int
    target: GoToBody


@dataclass(frozen=True)
class ThumbnailWanted(AcousticEvent):
    oid: int
    settings: ThumbRequest


@dataclass(frozen=True)
class FailsafeStarted(AcousticEvent):
    action: int  # FAILSAFE_HOLD or FAILSAFE_SURFACE


@dataclass(frozen=True)
class FailsafeEnded(AcousticEvent):
    pass


@dataclass(frozen=True)
class SessionStarted(AcousticEvent):
    challenge: bytes


# -- the operator's end: what the console shows ------------------------------


@dataclass(frozen=True)
class SessionSynced(AcousticEvent):
    boot: bytes
    restarted: bool  # a BOOT unlike the last one: pending order fates unknown
    failsafe_s: int
    failsafe_action: int


@dataclass(frozen=True)
class StatusReceived(AcousticEvent):
    status: StatusBody
    at: float  # when it was made, as the operator estimates it (arrival - STATUS_TRANSIT_S or SAME_TRANSIT_S)
    ctr: int


@dataclass(frozen=True)
class OrderFate(AcousticEvent):
    oid: int
    state: str  # taken, done, rejected, cancelled, aborted, unknown, not sent
    reason: str = ""


@dataclass(frozen=True)
class StopTaken(AcousticEvent):
    stop_no: int
    pressed_at: float


@dataclass(frozen=True)
class StopImpossible(AcousticEvent):
    stop_no: int


@dataclass(frozen=True)
class ThumbnailProgress(AcousticEvent):
    oid: int
    prefix: bytes  # the contiguous prefix of the object held (from its [N:2])
    verified: bool = False


@dataclass(frozen=True)
class ThumbnailComplete(AcousticEvent):
    oid: int
    object: bytes
    verified: bool = True


@dataclass(frozen=True)
class ThumbnailRejected(AcousticEvent):
    oid: int  # the object MAC did not hold: discarded, asked for again


@dataclass(frozen=True)
class InauthenticPacket(AcousticEvent):
    alert: bool  # they persist while no authentic frame comes


@dataclass(frozen=True)
class Resyncing(AcousticEvent):
    why: str


# -- the operator's end: the scene (§11.2) -------------------------------------


@dataclass(frozen=True)
class SceneAltitude(AcousticEvent):
    """A SCENE's ALT: the vehicle's altitude above the seabed when the SCENE was made
    (`made`, dated as a STATUS is); None: unknown or beyond 37 m."""

    altitude_m: float | None
    made: float
    code: int


@dataclass(frozen=True)
class SceneObjectReported(AcousticEvent):
    """An object the ROV recognised, new or changed (`obj.new`); a CHANGED for an id not
    held is shown as new (the ROV tells every object again every 30 s)."""

    obj: SeenObject
    made: float
    record_bytes: int


@dataclass(frozen=True)
class SceneObjectRemoved(AcousticEvent):
    object_id: int
    made: float


@dataclass(frozen=True)
class SceneRecordIgnored(AcousticEvent):
    """A record out of range (a reserved class, a size of 0): counted and ignored."""

    record_hex: str
