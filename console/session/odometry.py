"""What the ROV last said of itself, and when.

What the ROV says of itself arrives as a `link.report.VehicleReport` (SI, with
when it was sampled: the link knows the frame's air time and delay), from a
radio reply or an acoustic STATUS alike.  Speeds come from successive poses
(finite differences of quantised odometry over a span).  Bounded series for the live plots live in `History`.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field

from rovlink.link.report import VehicleReport

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
    def from_report(cls, r: VehicleReport) -> "Pose":
        return cls(r.x_m, r.y_m, r.z_m, r.roll_deg, r.pitch_deg, r.yaw_deg)

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
    """The last report with its times (session seconds)."""

    report: VehicleReport
    arrived_at: float          # when it arrived here
    sampled_at: float          # when the ROV sampled its odometry (estimated)
    poll_sent_at: float | None  # when the poll it answers left: the ROV acted on nothing later
    velocity: tuple[float, float, float, float]  # NED m/s and yaw deg/s, from successive poses

    @property
    def pose(self) -> Pose:
        return Pose.from_report(self.report)


# Speeds are fitted over at least this span of sampling times.  The sampling times are
# estimates (a pose is as old as the ROV's last telemetry when it answers, which a busy
# ROV makes older by a varying amount), and noise in the times of a least-squares fit
# shrinks its slope by var(t) / (var(t) + sigma^2), var(t) = span^2 / 12 for poses spread
# over the span: with sigma about 70 ms (a suite's loaded run: a 29 deg/s turn shown as
# 23), a 0.5 s span shows 0.80 of the speed, a 1 s span 0.94.  The cost: the fit lags
# half its span, 0.5 s, which a pilot reading a speed does not feel.
SPEED_SPAN_S = 1.0


def _slope(poses: list[tuple[float, Pose]]) -> tuple[float, float, float, float]:
    """North, east, down m/s and yaw deg/s: the least-squares line through the
    poses (two poses: their difference).  A fit rather than the two ends, because
    on a fast link the sampling times are estimates from arrival times, jittered
    by the console's own scheduling; yaw unwrapped against the newest pose."""
    t_new, newest = poses[-1]
    ts = [t - t_new for t, _ in poses]
    columns = [[p.x_m for _, p in poses], [p.y_m for _, p in poses], [p.z_m for _, p in poses],
               [newest.yaw_deg - ((newest.yaw_deg - p.yaw_deg + 180) % 360 - 180) for _, p in poses]]
    n = len(ts)
    mean_t = sum(ts) / n
    var = sum((t - mean_t) ** 2 for t in ts)
    out = []
    for values in columns:
        mean_v = sum(values) / n
        out.append(sum((t - mean_t) * (v - mean_v) for t, v in zip(ts, values)) / var)
    return (out[0], out[1], out[2], out[3])


class Odometry:
    """The last fix; `take` a report as it arrives.  The caller holds the session's lock.

    Speeds are fitted to the quantised poses of at least SPEED_SPAN_S of
    sampling time, whatever the reply rate: a reply every 20 ms (a fast link)
    fits the last 0.5 s of poses, a reply every second differences against the
    one before it.  (Before, each fix was differenced only
    against the last, and not at all under 50 ms apart: speeds read 0 on a fast
    link.)  Only measured poses count: a report without a valid position (the
    autopilot's estimate not up yet) restarts the position's window, one without a
    valid attitude the turn rate's."""

    def __init__(self) -> None:
        self.fix: Fix | None = None
        self.fixes = 0
        self._window: collections.deque[tuple[float, Pose]] = collections.deque()  # measured positions
        self._yaw_window: collections.deque[tuple[float, Pose]] = collections.deque()  # valid attitudes

    def take(self, report: VehicleReport, round_trip_s: float | None) -> Fix | None:
        """The report that arrived; returns the fix it replaces."""
        t, sampled = report.arrived_at, report.sampled_at
        previous = self.fix
        vn, ve, vd, vyaw = (0.0, 0.0, 0.0, 0.0) if previous is None else previous.velocity
        pose = Pose.from_report(report)
        # The position's speeds from measured positions, the turn rate from valid attitudes:
        # a report whose position is a second old (a vehicle side starved for a moment)
        # restarts the one, not the other (a suite's loaded run showed a steady turn as 0).
        fitted = self._fit(self._window, report.position_valid, sampled, pose)
        if fitted is not None:
            vn, ve, vd, _ = fitted
        fitted = self._fit(self._yaw_window, report.attitude_valid, sampled, pose)
        if fitted is not None:
            vyaw = fitted[3]
        velocity = (vn, ve, vd, vyaw)
        self.fix = Fix(report, t, sampled, t - round_trip_s if round_trip_s is not None else None, velocity)
        self.fixes += 1
        return previous

    @staticmethod
    def _fit(window: collections.deque, valid: bool, sampled: float, pose: Pose):
        """The slope over `window` and the new pose when `valid` (None while the window is
        shorter than the span: the last speed stands); all zeros when not (no speed measured)."""
        if not valid:
            window.clear()
            return (0.0, 0.0, 0.0, 0.0)
        fitted = None
        # Kept: the poses newer than the span, and the newest one older than it.
        while len(window) > 1 and sampled - window[1][0] >= SPEED_SPAN_S:
            window.popleft()
        if window and sampled - window[0][0] >= SPEED_SPAN_S:
            fitted = _slope([*window, (sampled, pose)])
        window.append((sampled, pose))
        return fitted

    def age_s(self, now: float) -> float | None:
        return None if self.fix is None else now - self.fix.sampled_at

    def measured_velocity(self) -> dict | None:
        """Speeds from successive received poses: body forward and right, down,
        and yaw rate; None before two reports."""
        fix = self.fix
        if fix is None or self.fixes < 2:
            return None
        vn, ve, vd, vyaw = fix.velocity
        yaw = math.radians(fix.report.yaw_deg)
        return {"forward_mps": round(vn * math.cos(yaw) + ve * math.sin(yaw), 3),
                "right_mps": round(-vn * math.sin(yaw) + ve * math.cos(yaw), 3),
                "down_mps": round(vd, 3), "yaw_dps": round(vyaw, 2)}
