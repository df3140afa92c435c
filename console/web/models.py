"""Pydantic models for every body the web API reads or writes.

Goals: the OpenAPI schema at /openapi.json is the API's documentation, so
every request and response has a model with units in its field names; a
request that is wrong in any way (a typo in a field name, a number out of
range, a string where a number belongs) is refused with 422 before it
reaches the Operator.

Plan: request models forbid unknown fields and take numbers strictly (no
"0.5" strings, no booleans as numbers, no NaN); the session's state
types are console/session/state.py's (the getters' dicts are checked against
them), reused here as they are.  Orders keep their kind-specific
details as extra fields, so `OrderInfo` allows them.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, StrictInt, model_validator

from rovlink.console.control import MODES
from rovlink.console.session.state import (
    ImageState,
    LinkState,
    LogEntry,
    OrderInfo,
    PoseState,
    VelocityWish,
    WorldState,
)

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
    budget_bytes: int | None = Field(None, ge=0, description="image size, bytes, 0 up to the link's image_budget_max "
                                                            "(GET /api/config; more is refused, 422, by the session)")


class FollowOrder(Request):
    """FOLLOW (docs/PROTOCOL.md §10): the ROI follows what it framed in picture `img`."""

    roi: tuple[StrictInt, StrictInt, StrictInt, StrictInt] = Field(
        strict=False, description="region of interest (x0, y0, x1, y1) in pixels of picture img, x0 < x1, y0 < y1")
    img: int = Field(ge=0, le=255, description="the picture the ROI was drawn on: its IMG (radio, 0..7) or its "
                                               "thumbnail's OID (acoustic)")
    keep: bool = Field(True, description="while the track is lost, keep its last ROI (false: no ROI)")


class TakeControl(Request):
    name: str = Field("", max_length=40, description="shown to the other clients, e.g. 'pilot laptop'")


# ----------------------------------------------------------------------
# Responses
# ----------------------------------------------------------------------


class ErrorBody(BaseModel):
    detail: object = Field(description="FastAPI's detail: a string, or a list of field errors for a 422")
    message: str = Field(description="one line saying what is wrong")


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
    world: WorldState
    log: list[LogEntry]
    replaying: bool
    wall: float | None = Field(None, description="the session's clock time now, Unix seconds (a replay's own)")
    control: ControlStatus
    target: Target | None = None


class OrderQueued(BaseModel):
    id: int = Field(description="order id; follow it in /api/orders")
    kind: str
    mode: str | None = Field(None, description="the mode the ROV switches to for it (GUIDED for a position)")


class FrameQueued(OrderQueued):
    """"Frame it" (POST /api/world/objects/{id}/frame): the IMAGE or FOLLOW order that frames it."""

    object_id: int
    roi: tuple[int, int, int, int] = Field(description="the ROI, pixels of a picture of size_px, x1 and y1 exclusive")
    size_px: tuple[int, int] = Field(description="the picture's width and height the ROI is in")
    follow: bool = Field(description="FOLLOW went with it: the ROV tracks the object")
    drawn_on: int | None = Field(description="FOLLOW's picture the ROI was drawn on (None without FOLLOW)")
    text: str = Field(description="what was decided, in one line")


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
    capabilities: dict[str, bool | str | float | int | list[int] | None] = Field(
        default_factory=dict, description="what the link carries (console/session/contract.py Capabilities): "
                                          "profile, velocity (sticks), next_image, picture ('stream' or "
                                          "'thumbnail'), image_budget_max, report_every_s, picture_px "
                                          "([width, height] before a picture came), follow_newest_frame")
