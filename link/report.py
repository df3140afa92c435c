"""What the ROV says of itself, in SI units, whatever the profile carried it.

Goal: wire units (centimetres, centidegrees, decimetres, velocity fractions)
end in link/.  A radio reply (§5) and an acoustic STATUS (§9.4) both become a
`VehicleReport`: the pose in metres and degrees, the status flags, and when
the ROV sampled it (estimated from the frame that carried it: its air time and
the intrinsic delay), so that the console shows one kind of thing with its age.
This is the mirror, on the operator's side, of the ROV's `status_from_pose`.
"""

from __future__ import annotations

from dataclasses import dataclass

from .radio.frame import OVERHEAD
from .radio.messages import Reply


@dataclass(frozen=True)
class VehicleReport:
    """The vehicle as one reply or STATUS said it, in SI.  `sampled_at` and
    `arrived_at` are the receiver's clock (session seconds)."""

    x_m: float
    y_m: float
    z_m: float  # down
    roll_deg: float
    pitch_deg: float
    yaw_deg: float
    armed: bool
    mode: int  # link.messages.Mode's number (0 unknown, 7 other)
    failsafe: bool
    hold: bool
    autopilot: bool
    position_valid: bool
    attitude_valid: bool
    sampled_at: float
    arrived_at: float
    going: bool | None = None  # a go-to in progress (the acoustic STATUS says it; a radio reply does not)
    battery_v: float | None = None  # acoustic STATUS only
    tilt_valid: bool = True  # roll and pitch measured (an acoustic STATUS carries a heading only)
    # Above the seabed (docs/PROTOCOL.md §11): the last ALT the link told (a radio reply's annex,
    # an acoustic SCENE), None: unknown (no rangefinder, beyond 37 m, nothing told yet).
    altitude_m: float | None = None

    @property
    def seabed_depth_m(self) -> float | None:
        """Where the seabed lies (NED z, down): the depth plus the altitude; None with no altitude."""
        return None if self.altitude_m is None else self.z_m + self.altitude_m

    def pose(self) -> tuple[float, float, float, float, float, float]:
        return (self.x_m, self.y_m, self.z_m, self.roll_deg, self.pitch_deg, self.yaw_deg)


def air_time_s(frame_bytes: int, bitrate_bps: float) -> float:
    return 8.0 * frame_bytes / bitrate_bps


def report_from_reply(reply: Reply, *, arrived_at: float, frame_bytes: int | None, bitrate_bps: float,
                      delay_s: float, round_trip_s: float | None = None,
                      altitude_m: float | None = None) -> VehicleReport:
    """A radio reply (§5) in SI.  The ROV samples its odometry when the poll
    arrives and answers at once, so the pose is as old as the reply's own air
    time plus the intrinsic delay.  `frame_bytes`: the frame that arrived (a
    version 2 frame is not the 1.1 payload rebuilt from it); None: the 1.1
    frame of `reply`.  `round_trip_s`: since its poll left; the ROV sampled no
    earlier than that (a link faster than its stated bitrate and delay, such as
    loopback UDP with no emulator, would otherwise date a long reply hundreds
    of milliseconds before its own poll, and a short one not: the speeds
    differenced from such dates were wrong).  `altitude_m`: the last ALT the replies' annex
    told (`AltitudeReported`, §11.1; a reply without ALT leaves it as it was)."""
    if frame_bytes is None:
        frame_bytes = len(reply.encode()) + OVERHEAD
    sampled = arrived_at - air_time_s(frame_bytes, bitrate_bps) - delay_s
    if round_trip_s is not None:
        sampled = min(arrived_at, max(sampled, arrived_at - round_trip_s))
    return VehicleReport(
        x_m=reply.x_cm / 100, y_m=reply.y_cm / 100, z_m=reply.z_cm / 100,
        roll_deg=reply.roll_cdeg / 100, pitch_deg=reply.pitch_cdeg / 100, yaw_deg=reply.yaw_cdeg / 100,
        armed=reply.armed, mode=int(reply.mode), failsafe=reply.failsafe, hold=reply.hold,
        autopilot=reply.autopilot, position_valid=reply.position_valid, attitude_valid=reply.attitude_valid,
        sampled_at=sampled, arrived_at=arrived_at, altitude_m=altitude_m)


def report_from_status(status, *, sampled_at: float, arrived_at: float,
                       altitude_m: float | None = None) -> VehicleReport:
    """An acoustic STATUS (§9.4, `link.acoustic.Status`) in SI: decimetres,
    a heading of 0..359.99 degrees (as a yaw of -180..180), no roll or pitch
    (the STATUS carries none: reported 0 with `tilt_valid` False; its
    ATTITUDE_VALID says the heading is measured), the
    battery in volts when it is given.  `sampled_at`: when the ROV made it, as
    the operator's end estimates it."""
    heading = status.heading_cdeg / 100
    return VehicleReport(
        x_m=status.x_dm / 10, y_m=status.y_dm / 10, z_m=status.z_dm / 10, roll_deg=0.0, pitch_deg=0.0,
        yaw_deg=(heading + 180.0) % 360.0 - 180.0, armed=status.armed, mode=int(status.mode),
        failsafe=status.failsafe, hold=status.hold, autopilot=status.autopilot,
        position_valid=status.position_valid, attitude_valid=status.attitude_valid, sampled_at=sampled_at,
        arrived_at=arrived_at, going=status.going, battery_v=status.battery_dv / 10 if status.battery_dv else None,
        tilt_valid=False, altitude_m=altitude_m)
