"""ArduSub's vocabulary, taken from pymavlink's generated dialect, and the one map
between the protocol's modes and ArduSub's.

Goals
- No hand-typed MAVLink numbers anywhere in rov/: every message id, command,
  flag, frame and result comes from the generated `ardupilotmega` dialect (the one
  `rov.mavurl.open_mavlink` speaks), and ArduSub's custom modes from
  `mavutil.mode_mapping_sub`.
- The protocol's mode list is `link.messages.Mode`; this module is the only place
  in rov/ that says which ArduSub mode each protocol mode is.

Decisions
- `mavlink` is the dialect module itself (pymavlink.dialects.v20.ardupilotmega),
  not `mavutil.mavlink`: the latter is whatever dialect some other code last
  selected with `mavutil.set_dialect`, and the numbers must not depend on that.
- The protocol says DEPTH_HOLD and POS_HOLD where ArduSub says ALT_HOLD and
  POSHOLD; every other protocol mode has ArduSub's own name.  The table is built
  by name, so a mode that pymavlink does not know fails at import, loudly.
"""

from __future__ import annotations

from enum import IntEnum

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from rovlink.link.radio.messages import Mode

# ArduSub's custom modes (HEARTBEAT.custom_mode), as pymavlink knows them.
SubMode = IntEnum("SubMode", {name: number for number, name in sorted(mavutil.mode_mapping_sub.items())})
SubMode.__doc__ = "ArduSub's custom mode numbers (HEARTBEAT.custom_mode), from pymavlink's mode_mapping_sub."

# Protocol names that ArduSub spells differently.
_ARDUSUB_NAME = {"DEPTH_HOLD": "ALT_HOLD", "POS_HOLD": "POSHOLD"}

# Protocol MODE (docs/PROTOCOL.md §2 VELOCITY, §5 reply) -> ArduSub's mode, for 1..6.
PROTOCOL_TO_SUB: dict[int, SubMode] = {
    int(mode): SubMode[_ARDUSUB_NAME.get(mode.name, mode.name)]
    for mode in Mode
    if mode not in (Mode.KEEP, Mode.OTHER)
}
SUB_TO_PROTOCOL: dict[int, int] = {int(sub): proto for proto, sub in PROTOCOL_TO_SUB.items()}
PROTOCOL_MODE_UNKNOWN = int(Mode.UNKNOWN)
PROTOCOL_MODE_OTHER = int(Mode.OTHER)

# Names a caller may use: the protocol's and ArduSub's.
MODE_NAMES: dict[str, SubMode] = {Mode(p).name: s for p, s in PROTOCOL_TO_SUB.items()}
MODE_NAMES.update({s.name: s for s in PROTOCOL_TO_SUB.values()})

MAV_RESULT_NAMES = {
    mavlink.MAV_RESULT_ACCEPTED: "accepted",
    mavlink.MAV_RESULT_TEMPORARILY_REJECTED: "temporarily rejected",
    mavlink.MAV_RESULT_DENIED: "denied",
    mavlink.MAV_RESULT_UNSUPPORTED: "unsupported",
    mavlink.MAV_RESULT_FAILED: "failed",
    mavlink.MAV_RESULT_IN_PROGRESS: "in progress",
}

# SET_POSITION_TARGET_LOCAL_NED: position (and yaw) only.
TYPEMASK_POSITION_AND_YAW = (
    mavlink.POSITION_TARGET_TYPEMASK_VX_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_VY_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_VZ_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
)
TYPEMASK_POSITION_IGNORE = (
    mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_Y_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE
)
TYPEMASK_YAW_IGNORE = mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE


def protocol_mode(custom_mode: int | None) -> int:
    """The protocol's reported MODE for an ArduSub custom mode (None: unknown)."""
    if custom_mode is None:
        return PROTOCOL_MODE_UNKNOWN
    return SUB_TO_PROTOCOL.get(int(custom_mode), PROTOCOL_MODE_OTHER)


def sub_mode(mode: str | int | SubMode) -> SubMode:
    """ArduSub's mode for a protocol name, a protocol number (1..6) or a SubMode."""
    if isinstance(mode, SubMode):
        return mode
    if isinstance(mode, str):
        key = mode.strip().upper().replace("-", "_").replace(" ", "_")
        if key in MODE_NAMES:
            return MODE_NAMES[key]
        raise ValueError(f"unknown mode name {mode!r}; expected one of {', '.join(MODE_NAMES)}")
    if isinstance(mode, int) and not isinstance(mode, bool) and mode in PROTOCOL_TO_SUB:
        return PROTOCOL_TO_SUB[mode]
    raise ValueError(f"unknown mode {mode!r}; expected a protocol mode 1..6 or a name")


def mode_name(custom_mode: int | None) -> str:
    if custom_mode is None:
        return "unknown"
    try:
        return SubMode(custom_mode).name
    except ValueError:
        return str(custom_mode)
