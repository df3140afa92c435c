"""What the autopilot last told us, and how fresh it is, without I/O.

Goals
- One frozen `AutopilotSnapshot` for the node's reply, with every field's validity
  as docs/PROTOCOL.md §5 defines it: AUTOPILOT = a HEARTBEAT within 3 s;
  POSITION_VALID = a LOCAL_POSITION_NED received in the last second;
  ATTITUDE_VALID = an ATTITUDE from the autopilot less than 1 s old.
- After an autopilot loss, or when an autopilot is (re)found, values from before
  are never reported valid: the new vehicle's own messages have to arrive first.

Plan
- `Telemetry` takes decoded values and `now` (`on_heartbeat`, `on_attitude`, ...)
  and builds `snapshot(now)`.  The bridge calls it under its lock; tests drive it
  with a fake clock.
- The mode and the armed state are taken from the HEARTBEAT, and also from an
  accepted DO_SET_MODE's or ARM_DISARM's COMMAND_ACK at once (`on_mode_accepted`,
  `on_armed_accepted`): ArduSub acknowledges after the change took effect, and the
  next 1 Hz heartbeat could be a second away.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from rovlink.rov.ardusub import PROTOCOL_MODE_UNKNOWN, protocol_mode

HEARTBEAT_TIMEOUT_S = 3.0
POSITION_TIMEOUT_S = 1.0
ATTITUDE_TIMEOUT_S = 1.0
# ArduSub streams RANGEFINDER and DISTANCE_SENSOR at 3 Hz unasked (docs: shared ARDUSUB.md):
# three missed in a row and the altitude is unknown.
RANGE_TIMEOUT_S = 1.0


@dataclass(frozen=True)
class AutopilotSnapshot:
    """What the node reports: the autopilot's own view, never the bridge's wishes."""

    x_m: float = 0.0  # local NED: north
    y_m: float = 0.0  # east
    z_m: float = 0.0  # down (depth)
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    yaw_rad: float = 0.0  # 0 north, clockwise positive
    vx_mps: float = 0.0  # NED velocities from LOCAL_POSITION_NED
    vy_mps: float = 0.0
    vz_mps: float = 0.0
    yaw_rate_radps: float = 0.0
    armed: bool = False  # HEARTBEAT base_mode SAFETY_ARMED; False while the autopilot is lost
    custom_mode: int | None = None  # ArduSub's mode number, None until known
    mode: int = PROTOCOL_MODE_UNKNOWN  # the protocol's MODE 0..7
    autopilot_alive: bool = False  # a HEARTBEAT within the last 3 s
    position_valid: bool = False  # LOCAL_POSITION_NED from this autopilot within the last 1 s
    attitude_valid: bool = False  # ATTITUDE from this autopilot within the last 1 s
    position_age_s: float | None = None  # since the last LOCAL_POSITION_NED (None: none from this autopilot)
    attitude_age_s: float | None = None  # since the last ATTITUDE (None: none from this autopilot)
    connected: bool = False  # the MAVLink connection is open
    failsafe: bool = False  # failsafe(True) in force
    battery_v: float | None = None
    # Above the seabed, from a downward rangefinder (an echosounder such as a Ping2) less than
    # RANGE_TIMEOUT_S old, tilt-compensated with the attitude; None: no rangefinder reports.
    altitude_m: float | None = None
    updated_s: float = 0.0  # time.monotonic() of the last telemetry received
    status_text: str = ""  # the autopilot's last STATUSTEXT


class Telemetry:
    def __init__(self) -> None:
        self.values = AutopilotSnapshot()
        self.last_heartbeat_s = -math.inf
        self.last_attitude_s = -math.inf
        self.last_position_s = -math.inf
        self.last_text_s = -math.inf
        self.last_range_s = -math.inf
        self.range_m: float | None = None
        self.system: int | None = None

    def alive(self, now: float) -> bool:
        return now - self.last_heartbeat_s < HEARTBEAT_TIMEOUT_S

    def on_heartbeat(self, system: int, armed: bool, custom_mode: int | None, now: float) -> bool:
        """A HEARTBEAT from the autopilot; True when it is (re)found (new, or after a loss)."""
        found = not self.alive(now) or system != self.system
        if found:
            self.forget()  # nothing from before is this vehicle's
        self.system = system
        self.last_heartbeat_s = now
        self._set(armed=armed, custom_mode=custom_mode, mode=protocol_mode(custom_mode), updated_s=now)
        return found

    def on_mode_accepted(self, custom_mode: int, now: float) -> None:
        if self.alive(now):
            self._set(custom_mode=custom_mode, mode=protocol_mode(custom_mode), updated_s=now)

    def on_armed_accepted(self, armed: bool, now: float) -> None:
        if self.alive(now):
            self._set(armed=armed, updated_s=now)

    def on_attitude(self, roll: float, pitch: float, yaw: float, yaw_rate: float, now: float) -> None:
        values = (roll, pitch, yaw, yaw_rate)
        if all(math.isfinite(v) for v in values):
            self.last_attitude_s = now
            self._set(roll_rad=roll, pitch_rad=pitch, yaw_rad=yaw, yaw_rate_radps=yaw_rate, updated_s=now)

    def on_position(self, x: float, y: float, z: float, vx: float, vy: float, vz: float, now: float) -> None:
        if all(math.isfinite(v) for v in (x, y, z, vx, vy, vz)):
            self.last_position_s = now
            self._set(x_m=x, y_m=y, z_m=z, vx_mps=vx, vy_mps=vy, vz_mps=vz, updated_s=now)

    def on_range(self, range_m: float, now: float) -> None:
        """A downward rangefinder's range (RANGEFINDER or DISTANCE_SENSOR facing down); a
        reading out of the sensor's own bounds is passed as NaN: no altitude."""
        if math.isfinite(range_m) and range_m >= 0:
            self.range_m, self.last_range_s = float(range_m), now
        else:
            self.range_m, self.last_range_s = None, -math.inf

    def on_battery(self, volts: float | None, now: float) -> None:
        self._set(battery_v=volts, updated_s=now)

    def on_text(self, text: str, now: float) -> None:
        self.last_text_s = now
        self._set(status_text=text)

    def recent_text(self, now: float, within_s: float = 1.0) -> str:
        return self.values.status_text if now - self.last_text_s <= within_s else ""

    def lost(self) -> None:
        """The connection closed: the autopilot is gone now, not at the heartbeat timeout."""
        self.last_heartbeat_s = -math.inf
        self.forget()

    def forget(self) -> None:
        """The autopilot is gone (or another one appeared): nothing old stays valid."""
        self.last_attitude_s = -math.inf
        self.last_position_s = -math.inf
        self.last_range_s = -math.inf
        self.range_m = None

    def _set(self, **fields) -> None:
        self.values = dataclasses.replace(self.values, **fields)

    def snapshot(self, now: float, *, connected: bool, failsafe: bool) -> AutopilotSnapshot:
        snap = self.values
        alive = self.alive(now)
        attitude_age = now - self.last_attitude_s if math.isfinite(self.last_attitude_s) else None
        position_age = now - self.last_position_s if math.isfinite(self.last_position_s) else None
        altitude = None
        if alive and self.range_m is not None and now - self.last_range_s < RANGE_TIMEOUT_S:
            # The sounder looks along the body's down axis: a tilted vehicle measures a slant.
            altitude = self.range_m * max(0.0, math.cos(snap.roll_rad) * math.cos(snap.pitch_rad))
        common = dict(
            altitude_m=altitude,
            connected=connected,
            failsafe=failsafe,
            attitude_age_s=attitude_age,
            position_age_s=position_age,
            attitude_valid=alive and attitude_age is not None and attitude_age < ATTITUDE_TIMEOUT_S,
            position_valid=alive and position_age is not None and position_age < POSITION_TIMEOUT_S,
        )
        if alive:
            return dataclasses.replace(snap, autopilot_alive=True, **common)
        # Without a fresh heartbeat we know nothing about arming or mode.
        return dataclasses.replace(
            snap, autopilot_alive=False, armed=False, custom_mode=None, mode=PROTOCOL_MODE_UNKNOWN, **common
        )
