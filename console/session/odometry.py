"""What the ROV last said of itself, and when.

The ROV samples its odometry when a poll arrives, so a reply's pose is as old
as the reply's own transmission plus the intrinsic delay when it arrives here.
Speeds come from successive poses (finite differences of quantised odometry,
smoothed).  Bounded series for the live plots live in `History`.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field

from rovlink.link.frame import OVERHEAD
from rovlink.link.messages import Reply

LOG_KEPT = 500            # log lines kept (the page filters them)
SERIES_KEPT = 1000        # points kept in each live plot


@dataclass(frozen=True)
class Pose:
    x_m: float
    y_m: float
    z_m: float
    roll_deg: float
    pitch_deg: float
    yaw_deg: float

    @classmethod
    def from_reply(cls, r: Reply) -> "Pose":
        return cls(r.x_cm / 100, r.y_cm / 100, r.z_cm / 100, r.roll_cdeg / 100, r.pitch_cdeg / 100,
                   r.yaw_cdeg / 100)

    def as_dict(self) -> dict:
        return {"x_m": self.x_m, "y_m": self.y_m, "z_m": self.z_m, "roll_deg": self.roll_deg,
                "pitch_deg": self.pitch_deg, "yaw_deg": self.yaw_deg}


def _series() -> collections.deque:
    return collections.deque(maxlen=SERIES_KEPT)


@dataclass
class LogLine:
    """A line of the session's log; an alert about a condition (`cause`) is
    marked `cleared` (session time) when the condition ends."""

    t: float
    text: str
    level: str
    cause: str | None = None
    cleared: float | None = None


@dataclass
class History:
    """Bounded series for the live plots and the session summary."""

    trail: collections.deque = field(default_factory=_series)  # (t, x, y, z)
    commanded: collections.deque = field(default_factory=_series)  # (t, vx..vyaw)
    received: collections.deque = field(default_factory=_series)  # (t, vx..vyaw)
    link_events: collections.deque = field(default_factory=_series)  # (t, kind, n)
    log: collections.deque = field(default_factory=lambda: collections.deque(maxlen=LOG_KEPT))  # LogLine
    round_trips: collections.deque = field(default_factory=lambda: collections.deque(maxlen=50))


@dataclass(frozen=True)
class Fix:
    """The last reply with its times (session seconds)."""

    reply: Reply
    arrived_at: float          # when it arrived here
    sampled_at: float          # when the ROV sampled its odometry (estimated)
    poll_sent_at: float | None  # when the poll it answers left: the ROV acted on nothing later
    velocity: tuple[float, float, float, float]  # NED m/s and yaw deg/s, from successive poses

    @property
    def pose(self) -> Pose:
        return Pose.from_reply(self.reply)


class Odometry:
    """The last fix; `take` a reply as it arrives.  The caller holds the session's lock."""

    def __init__(self, *, bitrate_bps: float, delay_s: float) -> None:
        self.bitrate_bps = bitrate_bps
        self.delay_s = delay_s
        self.fix: Fix | None = None
        self.fixes = 0

    def take(self, reply: Reply, t: float, round_trip_s: float | None) -> Fix | None:
        """The reply that arrived at `t`; returns the fix it replaces."""
        sampled = t - (8.0 * (len(reply.encode()) + OVERHEAD) / self.bitrate_bps) - self.delay_s
        previous = self.fix
        velocity = (0.0, 0.0, 0.0, 0.0) if previous is None else previous.velocity
        # Speeds only between two poses that are measured: a reply without a position
        # (the autopilot's estimate not up yet) says 0,0,0, and the step from it to the
        # first real pose is no speed (it read as metres per second at start).
        both_valid = previous is not None and previous.reply.position_valid and reply.position_valid
        if not both_valid:
            velocity = (0.0, 0.0, 0.0, 0.0)
        elif sampled - previous.sampled_at > 0.05:
            dt = sampled - previous.sampled_at
            old, new_pose = previous.pose, Pose.from_reply(reply)
            dyaw = (new_pose.yaw_deg - old.yaw_deg + 180) % 360 - 180
            new = ((new_pose.x_m - old.x_m) / dt, (new_pose.y_m - old.y_m) / dt, (new_pose.z_m - old.z_m) / dt,
                   dyaw / dt)
            a = 0.5  # smooth the finite difference of quantised odometry
            velocity = tuple(a * n + (1 - a) * o for n, o in zip(new, velocity))
        self.fix = Fix(reply, t, sampled, t - round_trip_s if round_trip_s is not None else None, velocity)
        self.fixes += 1
        return previous

    def age_s(self, now: float) -> float | None:
        return None if self.fix is None else now - self.fix.sampled_at

    def measured_velocity(self) -> dict | None:
        """Speeds from successive received poses: body forward and right, down,
        and yaw rate; None before two replies."""
        fix = self.fix
        if fix is None or self.fixes < 2:
            return None
        vn, ve, vd, vyaw = fix.velocity
        yaw = math.radians(fix.reply.yaw_cdeg / 100)
        return {"forward_mps": round(vn * math.cos(yaw) + ve * math.sin(yaw), 3),
                "right_mps": round(-vn * math.sin(yaw) + ve * math.cos(yaw), 3),
                "down_mps": round(vd, 3), "yaw_dps": round(vyaw, 2)}
