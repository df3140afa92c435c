"""The acoustic profile (docs/PROTOCOL.md §9): supervisory control over a
Water Linked Modem-M64, 8-byte packets, one a second each way, without I/O.

Goals: STOP reaches the ROV at the first slot the modem gives, ahead of
anything queued, every time; each order runs exactly once and its fate is
shown; the pilot's status is a few seconds old and says how old; a DEBT
thumbnail refines as it comes and is shown verified only once its object
MAC holds; every control frame is authenticated (a 3-byte tag) and a
replayed or held-back one is refused; a silent uplink brings the vehicle to
a hold (or the surface).

Plan: two sans-I/O machines over the same packet layer, a package of its own:
`wire` (every constant once, the header and packet split), `bodies` (each
frame's body, as on the wire), `sealing` (tags and the thumbnail MAC),
`packets` (the packet layer both ends share), `events` (what each end tells
its caller: one base class, names unique across both profiles), `rov` and
`operator` (the two ends), `sim` and `bench` (simulated time over the modem's
model).  The names below are the package's public ones.

- `AcousticRov` (the ROV's end): `receive(packet, now) -> events`,
  `next_packet(now) -> bytes | None` (call it when the modem's transmit
  queue is empty; flush the modem first when `wants_flush`), `tick(now) ->
  events` (failsafe), `update_status(VehicleState)`, `order_outcome(oid,
  result)`, `thumbnail_ready(oid, object)`.  Events: `StopWanted`, `HoldWanted`,
  `SurfaceWanted`, `ArmWanted`, `DisarmWanted`, `ModeWanted`, `GoToWanted`, `ThumbnailWanted`,
  `FailsafeStarted`, `FailsafeEnded`, `SessionStarted`.
- `AcousticOperator` (the console's end): `stop(now) -> STOP number`,
  `cancel_stop()`, `send_order(body, now) -> OID`, `next_packet(now)`,
  `wants_flush`, `receive(packet, now) -> events`, `tick(now) -> events`,
  `next_status_at`.  Events: `SessionSynced`, `StatusReceived`, `OrderFate`,
  `StopTaken`, `StopImpossible`, `ThumbnailProgress`,
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

from .bodies import GoToBody, OrderBody, PollBody, StatusBody, StopBody, SyncBody, ThumbEnd, ThumbRequest, same_body, thumbnail_object
from .events import (
    AcousticEvent,
    ArmWanted,
    DisarmWanted,
    FailsafeEnded,
    FailsafeStarted,
    GoToWanted,
    HoldWanted,
    InauthenticPacket,
    ModeWanted,
    OrderFate,
    Resyncing,
    SceneAltitude,
    SceneObjectRemoved,
    SceneObjectReported,
    SceneRecordIgnored,
    SessionStarted,
    SessionSynced,
    StatusReceived,
    StopImpossible,
    StopTaken,
    StopWanted,
    SurfaceWanted,
    ThumbnailComplete,
    ThumbnailProgress,
    ThumbnailRejected,
    ThumbnailWanted,
)
from .operator import AcousticOperator, modem_idle
from .packets import data_packet
from .rov import AcousticRov, VehicleState
from .sealing import object_mac, seal_control, seal_hello, seal_sync
from .wire import (
    BITMAP_BITS,
    BRAKE_SHOWN_S,
    DOWN_PACKETS,
    DOWN_SCENE,
    DOWN_STATUS,
    DOWN_STATUS_SAME,
    DOWN_THUMB_END,
    FAILSAFE_HOLD,
    FAILSAFE_S,
    FAILSAFE_SURFACE,
    LABEL_DOWN,
    LABEL_UP,
    LONG_BODY,
    MAX_BUDGET,
    MAX_OBJECT,
    MAX_SLOTS,
    MIN_BUDGET,
    OP_ARM,
    OP_DISARM,
    OP_HOLD,
    OP_MODE,
    OP_SURFACE,
    PACKET_BYTES,
    R_ABORTED,
    R_DONE,
    R_IMPOSSIBLE,
    R_REFUSED,
    R_TAKEN,
    SAME_TRANSIT_S,
    SHORT_BODY,
    SILENCE_RESYNC_S,
    STATUS_IDLE_S,
    STATUS_TRANSIT_S,
    THUMB_H,
    THUMB_W,
    UP_GOTO,
    UP_ORDER,
    UP_PACKETS,
    UP_POLL,
    UP_STOP,
    UP_THUMB,
    OrderRefused,
)

__all__ = [
    "AcousticEvent", "AcousticOperator", "AcousticRov", "ArmWanted", "BITMAP_BITS", "BRAKE_SHOWN_S", "DOWN_PACKETS",
    "DOWN_SCENE", "DOWN_STATUS", "DOWN_STATUS_SAME", "SceneAltitude", "SceneObjectRemoved", "SceneObjectReported",
    "SceneRecordIgnored", "DOWN_THUMB_END", "DisarmWanted", "FAILSAFE_HOLD", "FAILSAFE_S",
    "FAILSAFE_SURFACE", "FailsafeEnded", "FailsafeStarted", "GoToBody", "GoToWanted", "HoldWanted",
    "InauthenticPacket", "LABEL_DOWN", "LABEL_UP", "LONG_BODY", "MAX_BUDGET", "MAX_OBJECT", "MAX_SLOTS",
    "MIN_BUDGET", "ModeWanted", "OP_ARM", "OP_DISARM", "OP_HOLD", "OP_MODE", "OP_SURFACE", "OrderBody", "OrderFate",
    "OrderRefused", "PACKET_BYTES", "PollBody", "R_ABORTED", "R_DONE", "R_IMPOSSIBLE", "R_REFUSED", "R_TAKEN",
    "Resyncing", "SAME_TRANSIT_S", "SHORT_BODY", "SILENCE_RESYNC_S", "STATUS_IDLE_S", "STATUS_TRANSIT_S",
    "SessionStarted", "SessionSynced", "StatusBody", "StatusReceived", "StopBody", "StopImpossible", "StopTaken",
    "StopWanted", "SurfaceWanted", "SyncBody", "THUMB_H", "THUMB_W", "ThumbEnd", "ThumbRequest",
    "ThumbnailComplete", "ThumbnailProgress", "ThumbnailRejected", "ThumbnailWanted", "UP_GOTO", "UP_ORDER",
    "UP_PACKETS", "UP_POLL", "UP_STOP", "UP_THUMB", "VehicleState", "data_packet", "modem_idle", "object_mac",
    "same_body", "seal_control", "seal_hello", "seal_sync", "thumbnail_object",
]
