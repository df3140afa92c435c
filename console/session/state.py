"""The session's state, typed: what `Operator`'s getters return, described once.

`pose_state()` is a `PoseState`, `image_state()` an `ImageState`,
`link_state()` a `LinkState`, `orders_state()` a list of `OrderInfo`,
`log_entries()` a list of `LogEntry`, `image_history()` a list of
`PastImage` (with its "stream").  The getters build plain dicts (the scene,
the gateway and the WebSocket read them at 10 Hz); the web API's response
models are these same classes (console/web/models.py imports them), and
tests/console/test_state_types.py checks every getter against its class, so
the two cannot drift apart.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

# The session's own pose (a frozen dataclass) is the API's too: pydantic takes dataclasses as they are.
from .fates import Fate
from .odometry import Pose


class MeasuredVelocity(BaseModel):
    forward_mps: float
    right_mps: float
    down_mps: float
    yaw_dps: float


class PoseState(BaseModel):
    t: float = Field(description="session time, seconds")
    received: Pose | None = Field(description="the last odometry the ROV sent")
    predicted: Pose | None = Field(description="dead reckoning from it to now, under the velocity wish")
    armed: bool | None = None
    mode: str | None = None
    failsafe: bool | None = None
    autopilot: bool | None = None
    position_valid: bool | None = None
    odometry_age_s: float | None = None
    hold: bool | None = Field(None, description="the ROV holds position after a STOP or failsafe (protocol 1.1)")
    attitude_valid: bool | None = Field(None, description="roll, pitch and yaw are measured (protocol 1.1)")
    stopping: bool | None = Field(None, description="a STOP goes out until the ROV confirms it (no wish meanwhile)")
    stale: bool | None = Field(None, description="the link is lost: the received pose is old news")
    uncertainty_m: float | None = Field(None, description="how far the vehicle may be from the prediction")
    velocity: MeasuredVelocity | None = Field(None, description="speeds from successive received poses")
    tilt_valid: bool | None = Field(None, description="roll and pitch are measured (false: an acoustic status "
                                                      "carries a heading only)")
    going: bool | None = Field(None, description="the acoustic status says a go-to is being flown")
    battery_v: float | None = Field(None, description="the acoustic status's battery voltage, when given")
    next_report_in_s: float | None = Field(None, description="the acoustic link: when the next status is due "
                                                             "at the latest")


class ImageSettingsState(BaseModel):
    roi: list[int] | None
    shift: int
    mono: bool
    budget_bytes: int


class FollowTrack(BaseModel):
    """A followed picture's track, as the ROV said it (docs/PROTOCOL.md §10)."""

    state: Literal["holds", "lost", "dropped", "unknown"]
    keep: bool = Field(description="while lost, the pictures keep the last ROI (else none)")
    lost_for_s: float = Field(description="how long the track had been lost when the picture was captured")


class Capture(BaseModel):
    t: float = Field(description="session seconds of the best estimate")
    wall: float = Field(description="clock time of the best estimate, Unix seconds")
    not_before_wall: float | None = Field(description="the capture was not earlier (null: any age)")
    not_after_wall: float = Field(description="the capture was not later (its first trunk arrived)")
    how: Literal["prefetch", "request", "unknown"]
    pose: Pose | None = Field(description="odometry at capture (null: position not valid)")


class PastImage(BaseModel):
    n: int = Field(description="the image's serial (GET /api/images/{n}.png)")
    img: int | None
    capture: Capture | None
    bytes: int = Field(description="bytes of DEBT stream received")
    total_bytes: int | None
    partial: bool = Field(description="abandoned before it was complete")
    skipped: bool = Field(False, description="partial because the pilot skipped it (Next image)")
    received_wall: float
    seconds: float | None = Field(description="from its first trunk to its last")
    settings: ImageSettingsState | None
    track: FollowTrack | None = Field(None, description="a followed picture's track (its settings' ROI: the one it was coded with)")


class ImageSkipped(BaseModel):
    n: int | None = Field(description="the picture's number, if any of it was shown")
    received_bytes: int = Field(description="bytes of it received when it was skipped")
    total_bytes: int | None = Field(description="its image object's length (2 more than the picture's stream)")
    wall: float = Field(description="when, Unix time")


class ImageState(BaseModel):
    img: int | None = Field(description="image object number on the link")
    received_bytes: int
    total_bytes: int | None
    complete: bool
    decoded_bytes: int = Field(description="length of the prefix the latest picture was decoded from")
    started_at: float | None
    decoded_at: float | None
    images_completed: int
    kept: int = Field(0, description="pictures kept so far to look back at (GET /api/images keeps the last "
                                     "24), partial ones included")
    serial: int = Field(0, description="counts images, never wraps (img wraps at 8)")
    capture: Capture | None = Field(None, description="when and where the ROV captured it (stamped from replies)")
    waiting: str | None = Field(None, description="why there is no picture yet (null once there is one)")
    verified: bool | None = Field(None, description="the acoustic thumbnail's MAC held (false: unverified "
                                                    "until it does); null on the radio link, where every trunk "
                                                    "is authenticated as it comes")
    skipped: ImageSkipped | None = Field(None, description="the pilot's last Next image: what it skipped")
    settings: ImageSettingsState | None
    track: FollowTrack | None = Field(None, description="a followed picture's track (its settings' ROI: the one it was coded with)")


class RadioCounters(BaseModel):
    last_round_trip_s: float | None
    estimated_ber: float | None = Field(description="the bit error rate the CRC failures suggest (1.1)")
    images_abandoned: int


class AcousticCounters(BaseModel):
    synced: bool = Field(description="the acoustic link's session is synchronised")
    next_report_in_s: float | None = Field(description="when the next status is due at the latest")


class LinkState(BaseModel):
    state: Literal["starting", "up", "degraded", "lost", "replay"] = Field(
        description="from replies: lost after lost_after_s without one, degraded while a figure of the last 10 s "
                    "(replies lost, bad frames, late replies) crosses its threshold (console/session/health.py)")
    degraded_reason: str | None = Field(None, description="while degraded: which figure crossed which threshold")
    degraded_short: str | None = Field(None, description="the same in a few words, for a badge")
    since_reply_s: float | None = Field(description="seconds since the last reply")
    lost_after_s: float
    rov_failsafe_s: float
    failsafe_inferred: bool = Field(description="no poll reached the ROV for its failsafe time: it is in FAILSAFE")
    failsafe_inferred_at: float | None = Field(description="when it went into FAILSAFE, Unix time")
    failsafe_inferred_since: str | None = Field(description="the same, HH:MM:SS local time")
    t: float
    poll_rate_hz: float
    reply_rate_hz: float
    round_trip_s: float | None = Field(description="median of recent round trips")
    sent: int = Field(description="frames sent to the ROV: polls (radio), packets (acoustic)")
    reports: int = Field(description="reports of the vehicle received: replies (radio), statuses (acoustic)")
    reports_lost: int | None = Field(description="reports asked for and not received (radio: replies lost); "
                                                 "null where none is asked for (acoustic)")
    bad_frames: int = Field(description="frames that failed their check: CRC (radio 1.1), tag (version 2, acoustic)")
    protocol_errors: int
    bytes_per_s: float = Field(description="both directions, last 10 s")
    bytes_sent: int
    bytes_received: int
    odometry_age_s: float | None
    failsafe: bool
    autopilot: bool
    images_completed: int
    radio: RadioCounters | None = Field(None, description="what only the radio link has")
    acoustic: AcousticCounters | None = Field(None, description="what only the acoustic link has")
    version: str = Field("1.1", description='"2": every frame authenticated; "1.1": INSECURE, nothing authenticated; '
                                             '"acoustic": the acoustic profile, every packet authenticated')
    inauthentic_frames: int = Field(0, description="frames whose tag did not hold, dropped (protocol 2: noise or forgery)")
    late_replies: int = Field(0, description="authentic replies that came too late (protocol 2)")
    auth_alert: bool = Field(False, description="more than 3 frames failed authentication in the last 10 s, and no reply came")
    link_up: bool = Field(description="replies arrive (state up or degraded)")
    transport_up: bool
    port_error: str | None = Field(None, description="why this console's own modem port is down (the transport's reason); "
                                                     "null while it is up, or for a replay")
    link_process: Literal["starting", "up", "down"] | None = Field(
        None, description="the console's link process (link/process.py): down from its end until it runs again; "
                          "null where the link runs in the console's own process (a replay, a test's stack)")
    link_process_reason: str | None = Field(None, description="while down: why it ended")
    link_process_pid: int | None = Field(None, description="the link process's pid while it runs")
    profile: Literal["radio", "acoustic"] = Field("radio", description="the link's profile (docs/PROTOCOL.md §9: acoustic)")


class SeenObjectInfo(BaseModel):
    """An object the ROV recognised on the seabed (docs/PROTOCOL.md §11), as it last told it."""

    id: int
    class_: str = Field(alias="class", description="amphora, pipe, timber, ladder or unknown")
    confidence: float = Field(description="0..1")
    north_m: float
    east_m: float
    length_m: float
    width_m: float
    heading_deg: float = Field(description="of the long axis, 0..180, clockwise from north")
    record_bytes: int = Field(description="the bytes its last record took on the link")
    first_t: float
    updated_t: float
    age_s: float = Field(description="since the ROV last told it")


class WorldState(BaseModel):
    """The world as the ROV measured it: the seabed at its depth plus its altitude, and
    the objects it recognised; nothing from any simulator's truth."""

    seabed_depth_m: float | None = Field(description="null: no altitude reported, so no floor is drawn")
    altitude_m: float | None
    altitude_age_s: float | None
    altitude_stale: bool
    seabed_unknown_why: str | None
    objects: list[SeenObjectInfo]
    records_ignored: int = Field(description="object records out of range, counted and ignored")


class VelocityWish(BaseModel):
    vx: float
    vy: float
    vz: float
    vyaw: float


class OrderInfo(BaseModel):
    """An order's progress; its kind-specific details ride along as extra fields (and `then`:
    the order that carries its purpose on after it ended, a Frame it's FOLLOW the ROV
    rejected followed by its ROI sent alone)."""

    model_config = ConfigDict(extra="allow")

    id: int
    kind: str
    state: Fate = Field(description="the fate (console/session/fates.py): queued or requested, sent, waiting (the "
                                    "vehicle has not followed it yet; still watched), acknowledged (one-shot) or "
                                    "followed (arm, mode), rejected, refused (never sent), cancelled, unknown; a "
                                    "position order then arrived or aborted, with distance_left_m (from the last "
                                    "reply; null: no position); each state's time is t_<state>")
    reason: str = Field("", description="why, in the ROV's or the console's words (empty: nothing to add)")
    version: int = Field(1, description="counts up at each change: a copy with a lower one is older than one seen")
    text: str = Field(description="the fate in words, as the pilot reads it")
    outcome: Literal["pending", "done", "bad", "ended"] = Field(
        description="pending: the vehicle has not said yet; done; bad: the pilot is alerted; ended: by a choice")
    t_queued: float


class LogEntry(BaseModel):
    t: float = Field(description="session seconds")
    wall: float = Field(description="clock time, Unix seconds")
    text: str
    level: Literal["alert", "warn", "info"] = Field(
        description="alert: the pilot must see it (link lost, failsafe, an order refused); info: routine")
    cause: Literal["link", "failsafe", "port", "process"] | None = Field(
        None, description="a condition the alert is about; it is cleared when the condition ends")
    cleared_wall: float | None = Field(None, description="when its cause ended (clock time); null: still on, "
                                                         "or an event that has no end")
