"""Pydantic models for every body the web API reads or writes.

Goals: the OpenAPI schema at /openapi.json is the API's documentation, so
every request and response has a model with units in its field names; a
request that is wrong in any way (a typo in a field name, a number out of
range, a string where a number belongs) is refused with 422 before it
reaches the Operator.

Plan: request models forbid unknown fields and take numbers strictly (no
"0.5" strings, no booleans as numbers, no NaN); response models mirror the
dicts of `Operator.state()` and its parts.  Orders keep their kind-specific
details as extra fields, so `OrderInfo` allows them.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, StrictInt, model_validator

from rovlink.console.control import MODES
from rovlink.link.messages import MAX_BUDGET

# The one mode list (the protocol's), as a type for the schema.
ModeName = Literal[tuple(MODES)]  # type: ignore[valid-type]


class Request(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


MAX_POSITION_M = 327.67  # the protocol's int16 centimetres


def fraction(description: str):
    return Field(0.0, ge=-1.0, le=1.0, description=description)


# ----------------------------------------------------------------------
# Requests
# ----------------------------------------------------------------------


class VelocityOrder(Request):
    """Velocity wish in fractions of the maximum, body frame, z down."""

    vx: float = fraction("surge, forward positive, -1..1")
    vy: float = fraction("sway, right positive, -1..1")
    vz: float = fraction("heave, down positive, -1..1")
    vyaw: float = fraction("yaw rate, clockwise positive, -1..1")


class PositionOrder(Request):
    """A position target (local NED, metres and degrees); GUIDED on the ROV."""

    x_m: float = Field(ge=-MAX_POSITION_M, le=MAX_POSITION_M,
                       description=f"north (or forward with body=true), metres, within ±{MAX_POSITION_M}")
    y_m: float = Field(ge=-MAX_POSITION_M, le=MAX_POSITION_M,
                       description=f"east (or right with body=true), metres, within ±{MAX_POSITION_M}")
    z_m: float = Field(ge=-MAX_POSITION_M, le=MAX_POSITION_M,
                       description=f"down, metres: 0..{MAX_POSITION_M} (below the surface), or a change of "
                                   f"depth with relative=true")
    yaw_deg: float = Field(0.0, ge=-360.0, le=360.0, description="heading, degrees, clockwise from north, -360..360")
    relative: bool = Field(False, description="relative to the current position")
    body: bool = Field(False, description="x/y in the vehicle's frame; needs relative=true")

    @model_validator(mode="after")
    def _below_the_surface(self):
        if not self.relative and self.z_m < 0:
            raise ValueError(f"z_m must be 0 or more (depth below the surface) for an absolute target, "
                             f"got {self.z_m}")
        return self


class ArmOrder(Request):
    armed: bool = Field(description="true to arm the thrusters, false to disarm")


class ModeOrder(Request):
    mode: ModeName


class ImageSettingsOrder(Request):
    """DEBT settings for the next images; a field left out keeps its value (roi: null clears it)."""

    # Strict ints inside, but a JSON array must still make a tuple.
    roi: tuple[StrictInt, StrictInt, StrictInt, StrictInt] | None = Field(
        None, strict=False, description="region of interest (x0, y0, x1, y1) in pixels, x0 < x1, y0 < y1; null for none")
    shift: int | None = Field(None, ge=0, le=15, description="bit planes the ROI is raised by, 0..15")
    mono: bool | None = Field(None, description="grey instead of colour")
    budget_bytes: int | None = Field(None, ge=0, le=MAX_BUDGET, description=f"image size, bytes, 0..{MAX_BUDGET}")


class TakeControl(Request):
    name: str = Field("", max_length=40, description="shown to the other clients, e.g. 'pilot laptop'")


# ----------------------------------------------------------------------
# Responses
# ----------------------------------------------------------------------


class ErrorBody(BaseModel):
    detail: object = Field(description="FastAPI's detail: a string, or a list of field errors for a 422")
    message: str = Field(description="one line saying what is wrong")


class Pose(BaseModel):
    x_m: float
    y_m: float
    z_m: float
    roll_deg: float
    pitch_deg: float
    yaw_deg: float


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


class ImageSettingsState(BaseModel):
    roi: list[int] | None
    shift: int
    mono: bool
    budget_bytes: int


class CapturePose(BaseModel):
    x_m: float
    y_m: float
    z_m: float
    roll_deg: float
    pitch_deg: float
    yaw_deg: float


class Capture(BaseModel):
    t: float = Field(description="session seconds of the best estimate")
    wall: float = Field(description="clock time of the best estimate, Unix seconds")
    not_before_wall: float | None = Field(description="the capture was not earlier (null: any age)")
    not_after_wall: float = Field(description="the capture was not later (its first trunk arrived)")
    how: Literal["prefetch", "request", "unknown"]
    pose: CapturePose | None = Field(description="odometry at capture (null: position not valid)")


class PastImage(BaseModel):
    n: int = Field(description="the image's serial (GET /api/images/{n}.png)")
    img: int | None
    capture: Capture | None
    bytes: int = Field(description="bytes of DEBT stream received")
    total_bytes: int | None
    partial: bool = Field(description="abandoned before it was complete")
    received_wall: float
    seconds: float | None = Field(description="from its first trunk to its last")
    settings: ImageSettingsState | None


class ImageState(BaseModel):
    img: int | None = Field(description="image object number on the link")
    received_bytes: int
    total_bytes: int | None
    complete: bool
    decoded_bytes: int = Field(description="length of the prefix the latest picture was decoded from")
    started_at: float | None
    decoded_at: float | None
    images_completed: int
    serial: int = Field(0, description="counts images, never wraps (img wraps at 8)")
    capture: Capture | None = Field(None, description="when and where the ROV captured it (stamped from replies)")
    settings: ImageSettingsState | None


class LinkState(BaseModel):
    state: Literal["starting", "up", "degraded", "lost", "replay"] = Field(
        description="from replies: lost after lost_after_s without one, degraded on recent losses or CRC errors")
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
    last_round_trip_s: float | None
    polls_sent: int
    replies: int
    replies_lost: int
    crc_errors: int
    protocol_errors: int
    bytes_per_s: float = Field(description="both directions, last 10 s")
    bytes_sent: int
    bytes_received: int
    odometry_age_s: float | None
    failsafe: bool
    autopilot: bool
    estimated_ber: float | None
    images_completed: int
    images_abandoned: int
    version: str = Field("1.1", description='"2": every frame authenticated; "1.1": INSECURE, nothing authenticated')
    inauthentic_frames: int = Field(0, description="forged or replayed frames dropped (protocol 2)")
    late_replies: int = Field(0, description="authentic replies that came too late (protocol 2)")
    auth_alert: bool = Field(False, description="more than 3 inauthentic frames in the last 10 s")
    link_up: bool = Field(description="replies arrive (state up or degraded)")
    transport_up: bool


class VelocityWish(BaseModel):
    vx: float
    vy: float
    vz: float
    vyaw: float


class OrderInfo(BaseModel):
    """An order's progress; its kind-specific details ride along as extra fields."""

    model_config = ConfigDict(extra="allow")

    id: int
    kind: str
    state: str = Field(description="queued or requested, sent, acknowledged (one-shot) or followed (arm, mode), "
                                   "'rejected: <reason>', 'refused: <reason>', 'cancelled: <reason>'")
    t_queued: float


class LogEntry(BaseModel):
    t: float = Field(description="session seconds")
    wall: float = Field(description="clock time, Unix seconds")
    text: str
    level: Literal["alert", "warn", "info"] = Field(
        description="alert: the pilot must see it (link lost, failsafe, an order refused); info: routine")


class ControlStatus(BaseModel):
    held: bool
    holder: str | None = Field(description="the holder's name, or null")
    holder_kind: Literal["browser", "script"] | None
    held_for_s: float | None
    you: bool = Field(description="whether the client asking (X-Rovlink-Client) holds control")
    lease_s: float = Field(description="a script holder silent this long loses control")
    unattended_s: float | None = Field(None, description="armed with nobody in control for this long")
    unattended_warning: bool = False
    disarm_unattended_s: float | None = None
    centre_to_drive: bool = Field(False, description="the holder's input has not been neutral since it took "
                                                     "control: its wish goes out neutral until it is")


class Target(BaseModel):
    x_m: float
    y_m: float
    z_m: float
    yaw_deg: float
    order_id: int | None
    sent: bool
    points: list[tuple[float, float, float]]


class State(BaseModel):
    pose: PoseState
    image: ImageState
    link: LinkState
    velocity_wish: VelocityWish
    orders: list[OrderInfo]
    log: list[LogEntry]
    replaying: bool
    wall: float | None = Field(None, description="the session's clock time now, Unix seconds (a replay's own)")
    control: ControlStatus
    target: Target | None = None


class OrderQueued(BaseModel):
    id: int = Field(description="order id; follow it in /api/orders")
    kind: str
    mode: str | None = Field(None, description="the mode the ROV switches to for it (GUIDED for a position)")


class Requested(BaseModel):
    """A request the link repeats until the ROV confirms it (arm, mode)."""

    kind: Literal["ARM", "DISARM", "MODE"]
    mode: ModeName | None = None
    id: int | None = Field(None, description="follow it in /api/orders")


class TakeResult(BaseModel):
    client_id: str = Field(description="send it as X-Rovlink-Client with every order")
    control: ControlStatus


class PathPreview(BaseModel):
    points: list[tuple[float, float, float]] = Field(description="(x_m, y_m, z_m) every 0.5 s, from the predicted pose")


class Config(BaseModel):
    """The one set of modes, keys, limits and defaults every surface builds its controls from."""

    viser_url: str | None
    telemetry_hz: float
    velocity_deadman_s: float
    lease_s: float
    modes: list[str]
    keys: dict[str, tuple[str, int]] = Field(description="key letter -> (axis, sign); hold to drive")
    stop_key: str
    stop_key_anywhere: str = Field("Escape", description="STOP from any focus, text fields included")
    key_gain: float
    wish_scale: dict[str, dict[str, float | str]] = Field(
        description="per axis, what a wish fraction means: 'drag' (steady speed, the root of "
                    "lin*v + quad*v^2 = thrust_n*fraction, m/s) or 'rate' (max * fraction, in unit)")
    limits: dict[str, tuple[float, float]]
    default_target: dict[str, float]
    default_roi_shift: int
    go_to_mode: str
    lost_after_s: float
    rov_failsafe_s: float
    unattended_warn_s: float
    disarm_unattended_s: float | None
