"""The acoustic profile's wire constants (docs/PROTOCOL.md §9), each once: sizes, KINDs,
ORDER ops, STATUS RESULTs, the timers both ends keep."""

from __future__ import annotations

from ..vocabulary import Mode

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
DOWN_SYNC, DOWN_STATUS, DOWN_THUMB_END, DOWN_STATUS_SAME, DOWN_SCENE = 0, 1, 2, 3, 4
UP_PACKETS = {UP_HELLO: 1, UP_POLL: 1, UP_STOP: 1, UP_ORDER: 1, UP_GOTO: 2, UP_THUMB: 2}
DOWN_PACKETS = {DOWN_SYNC: 2, DOWN_STATUS: 2, DOWN_THUMB_END: 1, DOWN_STATUS_SAME: 1, DOWN_SCENE: 2}
# §11.2: a SCENE (ALT and object records) goes between STATUSes, ahead of thumbnail data;
# an altitude alone is told when it moved 0.25 m (5 ALT steps near the seabed) or 20 s passed.
SCENE_ALT_STEPS = 5
SCENE_ALT_REPEAT_S = 20.0
# No acknowledgement: a told object is told again (CHANGED) when it was last told this long ago,
# one at a time and at most one every SCENE_REFRESH_GAP_S, so that mending takes a sliver of the downlink.
SCENE_REFRESH_S = 120.0
SCENE_REFRESH_GAP_S = 20.0

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

# The results that say the ROV never took the order (its fate: rejected or cancelled).
NEVER_TAKEN = (R_INVALID, R_IMPOSSIBLE, R_REFUSED, R_CANCELLED)

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


def header(kind: int, ctr: int) -> int:
    return kind << 4 | ctr & 15


def _split(frame: bytes) -> list[bytes]:
    return [frame[i:i + PACKET_BYTES] for i in range(0, len(frame), PACKET_BYTES)]
