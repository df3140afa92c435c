"""The one command layer: every order the console gives, who may give it, what it does.

Goals: one path for every order, whatever surface it comes from (the web
page's buttons and keys, a script over REST, the viser scene's panel, keys
and gizmo), so that the surfaces cannot drift apart; exactly one pilot at a
time; never an ROV left moving by a pilot who is gone or a widget that
resends an old value.

Plan:
- Orders are frozen dataclasses (`Arm`, `SetMode`, `Drive`, `GoTo`,
  `PreviewTarget`, `ClearTarget`, `SendTarget`, `ChangeImage`, `NextImage`,
  `FollowRoi`, `FrameObject`, `Stop`); an adapter builds one and hands it to `ControlDesk.submit(order,
  caller)`.  The adapters hold no state of their own: what they show comes
  from the operator's events ("wish", "target", "control", "order", ...).
- One permission table, `PERMISSION`: STOP is open to all, everything else
  to the control holder only (a page by its client id, its embedded scene by
  the page's scene key).  A replay has no ROV: every order is refused.
- One set of effects, `ControlDesk._effects`: each order type maps to one
  method that calls the Operator.
- Wishes go neutral after STOP, at every change of holder, when the holder
  is lost (its page closed, a script silent for `lease_s`), when a streamed
  velocity stops arriving (`deadman_s`), and whenever nobody holds control.
- Re-centring belongs to the holder: whoever takes control (a page, a script,
  the ground station, the first holder of a console just started) moves the
  vehicle only after its own input has been neutral once since it took
  control; until then its wish goes out as neutral and the status says
  "centre the sticks to drive".  The operator is told whether a pilot's input
  is in force, so that nobody's neutral never releases the ROV's HOLD.
- One mode list (from the protocol's `Mode`), one key map, one set of
  defaults and limits: `page_config()`, which GET /api/config serves and the
  page builds its mode box and keys from.

A client (`Client`) is a browser page for as long as its WebSocket is open,
or a script for as long as it keeps talking.  Taking control is always
explicit and always allowed (the watcher next to the pilot must be able to
take over); what is refused is an order from a client that does not hold it.
"""

from __future__ import annotations

import math
import re
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

from rovlink.link.vocabulary import REQUESTABLE_MODES
from rovlink.rov.vehicle import BlueRovParams

from .session.base import OrderError
from .session.contract import VehicleSession
from .session.fates import Fate

NEUTRAL = (0.0, 0.0, 0.0, 0.0)
SCENE_KEY = re.compile(r"[A-Za-z0-9_-]{16,64}")

# ----------------------------------------------------------------------
# One mode list, one key map, one set of defaults and limits
# ----------------------------------------------------------------------

MODES: tuple[str, ...] = tuple(m.name for m in REQUESTABLE_MODES)
AXES = ("vx", "vy", "vz", "vyaw")
# Key letter -> (axis, sign); z is down and yaw clockwise, as in the wish.
# The page matches KeyboardEvent.code "Key" + letter, the scene viser hotkeys.
KEYS: dict[str, tuple[str, int]] = {"W": ("vx", +1), "S": ("vx", -1), "D": ("vy", +1), "A": ("vy", -1),
                                    "E": ("vyaw", +1), "Q": ("vyaw", -1), "F": ("vz", +1), "R": ("vz", -1)}
STOP_KEY = "Space"        # STOP from any focus but a text field, where it types
STOP_KEY_ANYWHERE = "Escape"  # STOP from any focus, text fields included
KEY_GAIN = 0.5            # the fraction a held key asks for (the page's strength slider starts here)
DEADMAN_S = 1.0           # a streamed velocity (keys, gamepad) goes neutral when not repeated within it
LEASE_S = 30.0            # a script holding control and silent this long loses it
STATUS_WAIT_S = 0.05      # a status waits this long for the lock, then reads without it
UNATTENDED_WARN_S = 60.0  # armed with nobody in control this long: every page is warned
# A page whose WebSocket failed (not closed by the page) is given control back when that
# same page (its key, one per page load) reconnects within this; meanwhile nobody drives.
RESUME_S = 10.0
# The picture budget's limit is the link's (`Capabilities.image_budget_max`), not one here.
LIMITS = {"velocity": (-1.0, 1.0), "shift": (0, 15)}
DEFAULT_ROI_SHIFT = 4     # bit planes an ROI is raised by when none was chosen
DEFAULT_TARGET = {"x_m": 0.0, "y_m": 0.0, "z_m": 2.0, "yaw_deg": 0.0}


# ----------------------------------------------------------------------
# Orders
# ----------------------------------------------------------------------


class Order:
    """Base of the typed orders (frozen dataclasses)."""

    kind = "ORDER"


@dataclass(frozen=True)
class Arm(Order):
    armed: bool
    kind = "ARM"


@dataclass(frozen=True)
class SetMode(Order):
    mode: str
    kind = "MODE"


@dataclass(frozen=True)
class Drive(Order):
    """Velocity wish, fractions -1..1.  `streamed` (keys, gamepad): it goes
    neutral unless repeated within the dead man's time; else it stands."""

    vx: float = 0.0
    vy: float = 0.0
    vz: float = 0.0
    vyaw: float = 0.0
    streamed: bool = False
    kind = "VELOCITY"

    @property
    def values(self) -> tuple[float, float, float, float]:
        return (self.vx, self.vy, self.vz, self.vyaw)


@dataclass(frozen=True)
class GoTo(Order):
    """A POSITION order; the ROV switches to GUIDED to fly it."""

    x_m: float
    y_m: float
    z_m: float
    yaw_deg: float = 0.0
    relative: bool = False
    body: bool = False
    kind = "POSITION"


@dataclass(frozen=True)
class PreviewTarget(Order):
    """The shared target (ghost and path in the scene); nothing is sent."""

    x_m: float
    y_m: float
    z_m: float
    yaw_deg: float = 0.0
    kind = "PREVIEW"


@dataclass(frozen=True)
class ClearTarget(Order):
    kind = "CLEAR_TARGET"


@dataclass(frozen=True)
class SendTarget(Order):
    """The previewed target goes out as a GoTo."""

    kind = "SEND_TARGET"


KEEP = "keep"  # ChangeImage.roi: keep the ROI last requested


@dataclass(frozen=True)
class ChangeImage(Order):
    """DEBT settings for the next images; None keeps a value (roi: KEEP keeps, None clears)."""

    roi: object = KEEP
    shift: int | None = None
    mono: bool | None = None
    budget_bytes: int | None = None
    kind = "IMAGE"


@dataclass(frozen=True)
class FollowRoi(Order):
    """FOLLOW (docs/PROTOCOL.md §10): `roi`, drawn on the picture whose IMG is `drawn_on`,
    follows its object; `keep`: a lost track keeps its last ROI."""

    roi: tuple = ()
    keep: bool = True
    drawn_on: int = 0
    kind = "FOLLOW"


@dataclass(frozen=True)
class FrameObject(Order):
    """"Frame it": the next picture's ROI on object `object_id` (docs/PROTOCOL.md §11), where
    it lies in the picture taken from where the ROV is (the session's `object_frame`), and
    FOLLOW where the link carries it; refused in one line when the object is not in view."""

    object_id: int
    kind = "FRAME"


@dataclass(frozen=True)
class NextImage(Order):
    kind = "NEXT_IMAGE"


@dataclass(frozen=True)
class Stop(Order):
    """Neutral velocity now, targets cancelled on the ROV, depth held."""

    kind = "STOP"


@dataclass(frozen=True)
class CancelStop(Order):
    """Give up a STOP the ROV cannot carry out (no autopilot), so that a DISARM can go out."""

    kind = "CANCEL_STOP"


ANYONE, HOLDER = "anyone", "holder"
PERMISSION: dict[type, str] = {Stop: ANYONE, Arm: HOLDER, SetMode: HOLDER, Drive: HOLDER, GoTo: HOLDER,
                               PreviewTarget: HOLDER, ClearTarget: HOLDER, SendTarget: HOLDER,
                               ChangeImage: HOLDER, NextImage: HOLDER, CancelStop: HOLDER, FollowRoi: HOLDER,
                               FrameObject: HOLDER}


@dataclass(frozen=True)
class Caller:
    """Who gives an order: a client (page or script) by id, a scene viewer by
    its page's scene key, or the console itself (`internal`: its timers)."""

    client_id: str | None = None
    scene_key: str | None = None
    via: Literal["rest", "ws", "scene", "internal", "gcs"] = "rest"

    @property
    def internal(self) -> bool:
        return self.via == "internal"


CONSOLE = Caller(via="internal")


# ----------------------------------------------------------------------
# Refusals
# ----------------------------------------------------------------------


class NotHolder(Exception):
    """An order from a caller that does not hold control (HTTP 409)."""


class Replaying(NotHolder):
    """An order to a console that replays a recording: there is no ROV (HTTP 409)."""


class UnknownClient(Exception):
    """A client id this desk never issued or has forgotten (HTTP 422)."""


@dataclass
class Client:
    id: str
    kind: Literal["browser", "script"]
    name: str
    last_seen: float
    # Monotonic time of the last non-neutral streamed velocity; None when
    # the last one was neutral (or a standing one).
    streamed_at: float | None = None
    # The key of the 3D scene embedded in this page (browser clients), if any.
    scene_key: str | None = None
    # Its input is a stream that may be held off neutral (page keys, gamepad, joystick).
    streams: bool = True
    # Its input has been neutral once since it took control (or since a STOP or the
    # dead man, for a stream): only then does it drive.
    centred: bool = False
    centre_told: bool = False  # the log said so, once per spell


@dataclass
class Target:
    x_m: float
    y_m: float
    z_m: float
    yaw_deg: float
    points: list = field(default_factory=list)
    order_id: int | None = None

    def as_dict(self) -> dict:
        return {"x_m": self.x_m, "y_m": self.y_m, "z_m": self.z_m, "yaw_deg": self.yaw_deg,
                "order_id": self.order_id, "sent": self.order_id is not None, "points": self.points}


def wish_scale() -> dict:
    """What a wish fraction means in m/s and deg/s, for the pilot: the vehicle
    model's (rov/vehicle.py, a BlueROV2 under ArduSub) steady state in the
    stabilised modes.  Surge and sway are thrust against linear + quadratic drag
    (speed = the root of lin*v + quad*v^2 = thrust*fraction); heave and yaw are
    rate-controlled (climb rate, yaw rate proportional to the stick).  A model's
    figure, shown as approximate: the real vehicle's speed depends on its tether
    and current; the received odometry gives the true speed beside it."""
    p = BlueRovParams()
    return {"vx": {"kind": "drag", "thrust_n": p.thrust_surge_n, "lin": p.drag_lin_surge, "quad": p.drag_quad_surge},
            "vy": {"kind": "drag", "thrust_n": p.thrust_sway_n, "lin": p.drag_lin_sway, "quad": p.drag_quad_sway},
            "vz": {"kind": "rate", "max": p.climb_rate_max_mps, "unit": "m/s"},
            "vyaw": {"kind": "rate", "max": round(math.degrees(p.yaw_rate_max_radps), 2), "unit": "deg/s"}}


def page_config(*, image_budget_max: int, **extra) -> dict:
    """What every surface needs to build its controls: modes, keys, limits, defaults
    (`image_budget_max`: the largest picture budget the session's link carries)."""
    limits = {k: list(v) for k, v in LIMITS.items()}
    limits["budget_bytes"] = [0, image_budget_max]
    return {"modes": list(MODES), "keys": {k: [axis, sign] for k, (axis, sign) in KEYS.items()},
            "wish_scale": wish_scale(),
            "stop_key": STOP_KEY, "stop_key_anywhere": STOP_KEY_ANYWHERE, "key_gain": KEY_GAIN,
            "limits": limits, "default_target": dict(DEFAULT_TARGET),
            "default_roi_shift": DEFAULT_ROI_SHIFT,
            "go_to_mode": "GUIDED", **extra}


class ControlDesk:
    def __init__(self, operator: VehicleSession, *, lease_s: float = LEASE_S, deadman_s: float = DEADMAN_S,
                 unattended_warn_s: float = UNATTENDED_WARN_S, disarm_unattended_s: float | None = None,
                 resume_s: float = RESUME_S, clock: Callable[[], float] = time.monotonic) -> None:
        for name, value in (("lease_s", lease_s), ("deadman_s", deadman_s),
                            ("unattended_warn_s", unattended_warn_s), ("resume_s", resume_s)):
            if not value > 0:
                raise ValueError(f"{name} must be positive, got {value!r}")
        if disarm_unattended_s is not None and not disarm_unattended_s > 0:
            raise ValueError(f"disarm_unattended_s must be positive, got {disarm_unattended_s!r}")
        self.operator = operator
        self.lease_s = lease_s
        self.deadman_s = deadman_s
        self.unattended_warn_s = unattended_warn_s
        self.disarm_unattended_s = disarm_unattended_s
        self.resume_s = resume_s
        self._clock = clock
        self._lock = threading.RLock()
        self._clients: dict[str, Client] = {}
        self._holder: str | None = None
        self._held_since: float | None = None
        self._unheld_since: float = clock()
        self._disarmed_unattended = False
        # (page key, name, until): the holder whose WebSocket failed, given control back
        # if that page reconnects in time (nobody took it meanwhile).
        self._resume: tuple[str, str, float] | None = None
        self.target: Target | None = None
        self.version = 0  # bumped at every change of holder, so WebSockets know to tell their pages
        self._effects: dict[type, Callable] = {
            Arm: self._arm, SetMode: self._mode, Drive: self._drive, GoTo: self._go_to,
            PreviewTarget: self._preview, ClearTarget: self._clear_target, SendTarget: self._send_target,
            ChangeImage: self._image, NextImage: self._next_image, Stop: self._stop, CancelStop: self._cancel_stop,
            FollowRoi: self._follow, FrameObject: self._frame}
        assert set(self._effects) == set(PERMISSION)
        operator.set_pilot_in_force(False)  # nobody holds control yet
        operator.set_attended(False)

    # ------------------------------------------------------------------
    # The one order path
    # ------------------------------------------------------------------

    def submit(self, order: Order, caller: Caller = CONSOLE):
        """Check `order` against the permission table, then carry it out.
        NotHolder/Replaying when refused, OrderError when malformed; returns
        what the effect returns (an order id, the preview's points, ...)."""
        effect = self._effects.get(type(order))
        if effect is None:
            raise OrderError(f"not an order: {order!r}")
        with self._lock:
            self._permit(order, caller)
            return effect(order, caller)

    def refusal(self, order: Order, caller: Caller) -> str | None:
        """Why `caller` may not give `order` now, or None."""
        try:
            with self._lock:
                self._permit(order, caller, touch=False)
        except (NotHolder, UnknownClient) as exc:
            return str(exc)
        return None

    def _permit(self, order: Order, caller: Caller, touch: bool = True) -> None:
        self.check_live()
        if caller.internal:
            return
        if PERMISSION[type(order)] == ANYONE:
            if touch:
                self.touch(caller.client_id)
            return
        if caller.via == "scene":
            reason = self._scene_reason(caller.scene_key)
            if reason is not None:
                raise NotHolder(reason)
            return
        self.require(caller.client_id, touch=touch)

    # ------------------------------------------------------------------
    # Effects (the lock held)
    # ------------------------------------------------------------------

    def _arm(self, order: Arm, caller: Caller) -> int:
        return self.operator.arm(bool(order.armed))

    def _mode(self, order: SetMode, caller: Caller) -> int:
        return self.operator.set_mode(order.mode)

    def _uncentre(self, holder: Client) -> None:
        """Its input no longer counts until it has been neutral (lock held)."""
        holder.centred = holder.centre_told = False
        self.operator.set_pilot_in_force(False)

    def _centred(self, holder: Client) -> None:
        """Its own input is neutral: it drives from now on, and the ROV's HOLD may go."""
        if not holder.centred:
            holder.centred = True
            self.operator.set_pilot_in_force(True)
        self.operator.recentred()

    def _drive(self, order: Drive, caller: Caller) -> tuple:
        holder = self._holder_client()
        if holder is not None and order.values == NEUTRAL:
            was = holder.centred
            self._centred(holder)
            if not was:
                self._publish_control()
        elif holder is not None and not holder.centred:
            # Held since before it took control (a console restarted with the stick
            # forward, a ground station taking over) or since a STOP: not yet its drive.
            self.operator.set_velocity(*NEUTRAL)
            holder.streamed_at = None
            if not holder.centre_told:
                holder.centre_told = True
                self.operator.note(f"{holder.name}: centre the sticks to drive", "warn")
            return NEUTRAL
        self.operator.set_velocity(*order.values)
        if holder is not None:
            holder.streamed_at = self._clock() if order.streamed and order.values != NEUTRAL else None
        return order.values

    def _go_to(self, order: GoTo, caller: Caller) -> int:
        order_id = self.operator.send_position(order.x_m, order.y_m, order.z_m, order.yaw_deg,
                                               relative=order.relative, body=order.body)
        if not order.relative:
            points = self.target.points if self._same_target(order) else []
            self.target = Target(order.x_m, order.y_m, order.z_m, self._yaw(order.yaw_deg), points, order_id)
            self._publish_target()
        return order_id

    def _same_target(self, order) -> bool:
        t = self.target
        return t is not None and (t.x_m, t.y_m, t.z_m, t.yaw_deg) == (order.x_m, order.y_m, order.z_m,
                                                                     self._yaw(order.yaw_deg))

    @staticmethod
    def _yaw(yaw_deg: float) -> float:
        return (yaw_deg + 180.0) % 360.0 - 180.0

    def _preview(self, order: PreviewTarget, caller: Caller) -> list:
        for name in ("x_m", "y_m", "z_m", "yaw_deg"):
            v = getattr(order, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise OrderError(f"{name} must be a finite number, got {v!r}")
        points = self.operator.preview_path(order.x_m, order.y_m, order.z_m, order.yaw_deg)
        self.target = Target(order.x_m, order.y_m, order.z_m, self._yaw(order.yaw_deg), points, None)
        self._publish_target()
        return points

    def _clear_target(self, order: ClearTarget, caller: Caller) -> None:
        self.target = None
        self._publish_target()

    def _send_target(self, order: SendTarget, caller: Caller) -> int | None:
        t = self.target
        if t is None:
            raise OrderError("no target to send: preview one first")
        return self._go_to(GoTo(t.x_m, t.y_m, t.z_m, t.yaw_deg), caller)

    def _image(self, order: ChangeImage, caller: Caller) -> int:
        roi = self.operator.requested_settings.roi if order.roi is KEEP or order.roi == KEEP else order.roi
        shift = order.shift
        if roi is not None and (shift if shift is not None else self.operator.requested_settings.shift) == 0:
            shift = DEFAULT_ROI_SHIFT  # an ROI raised by nothing would do nothing
        return self.operator.set_image_settings(roi=roi, shift=shift, mono=order.mono,
                                                budget_bytes=order.budget_bytes)

    def _follow(self, order: FollowRoi, caller: Caller) -> int:
        shift = self.operator.requested_settings.shift
        return self.operator.follow_roi(order.roi, keep=order.keep, drawn_on=order.drawn_on,
                                        shift=shift if shift else DEFAULT_ROI_SHIFT)

    def _frame(self, order: FrameObject, caller: Caller) -> dict:
        """The IMAGE (or FOLLOW) order that frames the object; what was decided, with its id."""
        if isinstance(order.object_id, bool) or not isinstance(order.object_id, int):
            raise OrderError(f"an object is named by its id, not {order.object_id!r}")
        try:
            plan = self.operator.object_frame(order.object_id)
        except OrderError as exc:
            self.operator.note(f"Frame it: {exc}", "warn")
            raise
        roi = tuple(plan["roi"])
        if plan["follow"]:
            order_id = self._follow(FollowRoi(roi=roi, keep=True, drawn_on=plan["drawn_on"]), caller)
            self.operator.when_settled(order_id, lambda fate, reason: self._frame_unfollowed(order_id, roi, caller,
                                                                                         fate, reason))
        else:
            order_id = self._image(ChangeImage(roi=roi), caller)
        self.operator.note(f"Frame it: {plan['text']}; ROI {roi}, order #{order_id}")
        return {**plan, "id": order_id, "kind": "IMAGE"}

    def _frame_unfollowed(self, follow_id: int, roi: tuple, caller: Caller, fate: Fate, reason: str) -> None:
        """A Frame it's FOLLOW the ROV rejected: it does not follow (docs/PROTOCOL.md §10, a ROV
        without a tracker).  Its ROI still frames the object: it goes alone, as an IMAGE order
        from the same caller (on a thread of its own: this runs where the link settles
        orders), and later Frame its send the ROI alone."""
        if fate is not Fate.REJECTED:
            return
        self.operator.follow_rejected(reason)
        threading.Thread(target=self._frame_roi_alone, args=(follow_id, roi, caller, reason), daemon=True,
                         name="frame-it").start()

    def _frame_roi_alone(self, follow_id: int, roi: tuple, caller: Caller, reason: str) -> None:
        why = f"Frame it: the ROV does not follow (FOLLOW rejected: {reason})"
        asked = self.operator.requested_settings
        if asked.roi is None or tuple(asked.roi) != roi or not asked.follow:
            self.operator.note(f"{why}; the ROI alone was not sent: other image settings were asked since", "warn")
            return
        try:
            order_id = self.submit(ChangeImage(roi=roi), caller)
        except (OrderError, NotHolder, UnknownClient) as exc:
            self.operator.note(f"{why}; the ROI alone was not sent: {exc}", "warn")
            return
        self.operator.order_followed_by(follow_id, order_id)
        self.operator.note(f"{why}; the ROI {roi} alone on the next picture, order #{order_id}")

    def _next_image(self, order: NextImage, caller: Caller) -> None:
        self.operator.next_image()

    def _stop(self, order: Stop, caller: Caller) -> int:
        holder = self._holder_client()
        if holder is not None:
            holder.streamed_at = None
            if holder.streams:
                # STOP sets HOLD: a held stick is not the pilot's drive until centred again.
                self._uncentre(holder)
                self._publish_control()
        order_id = self.operator.stop()
        if self.target is not None:
            self.target = None
            self._publish_target()
        return order_id

    def _cancel_stop(self, order: CancelStop, caller: Caller) -> bool:
        if not self.operator.cancel_stop():
            raise OrderError("no STOP to cancel: only a STOP the ROV shows it cannot carry out may be cancelled")
        return True

    def _publish_target(self) -> None:
        self.operator.publish("target", self.target_state())

    def target_state(self) -> dict | None:
        t = self.target
        return None if t is None else t.as_dict()

    # ------------------------------------------------------------------
    # Clients
    # ------------------------------------------------------------------

    def connect(self, name: str = "", scene_key: str | None = None) -> Client:
        """A browser page's WebSocket opened: a new watcher.  `scene_key`: the
        key its 3D scene was opened with (ignored unless 16-64 characters of
        letters, digits, - and _); one per page load, it also says that a page
        whose connection failed has come back (it is given its control back)."""
        if scene_key is not None and not SCENE_KEY.fullmatch(scene_key):
            scene_key = None
        with self._lock:
            client = Client(secrets.token_urlsafe(16), "browser", name or "browser", self._clock(),
                            scene_key=scene_key)
            self._clients[client.id] = client
            back = self._resume is not None and scene_key is not None and self._resume[0] == scene_key \
                and self._holder is None and self._clock() <= self._resume[2] and not self.operator.replaying
            if back:
                self._give(client, None)  # (forgets the page to give back to)
        if back:
            self.operator.note(f"control given back to {client.name}: its page reconnected")
            self._publish_control()
        return client

    def disconnect(self, client_id: str, how: str = "", *, failed: bool = False) -> None:
        """A WebSocket closed: its page is gone, and control with it.  `how`:
        what ended it, for the log ("closed by the page (1001)", ...).  `failed`:
        the connection failed rather than the page closing it: if this page held
        control and reconnects within `resume_s`, it is given control back."""
        with self._lock:
            client = self._clients.pop(client_id, None)
            if client is not None and self._holder == client_id:
                back = failed and client.scene_key is not None
                self._release(f"control released: {client.name} left" + (f" ({how})" if how else "")
                              + (f"; given back if the page reconnects within {self.resume_s:g} s" if back else ""))
                if back:
                    self._resume = (client.scene_key, client.name, self._clock() + self.resume_s)

    def _lookup(self, client_id: str) -> Client:
        client = self._clients.get(client_id)
        if client is None:
            raise UnknownClient(f"unknown client id {client_id[:24]!r}: use the id from the WebSocket's hello "
                                f"message, or leave X-Rovlink-Client out to be given a new one")
        return client

    def touch(self, client_id: str | None) -> None:
        if client_id is None:
            return
        with self._lock:
            client = self._clients.get(client_id)
            if client is not None:
                client.last_seen = self._clock()

    def _holder_client(self) -> Client | None:
        return self._clients.get(self._holder) if self._holder else None

    # ------------------------------------------------------------------
    # Taking and giving back
    # ------------------------------------------------------------------

    def check_live(self) -> None:
        """Replaying has no ROV to order: Replaying, saying so."""
        if self.operator.replaying:
            raise Replaying("this console replays a recording: there is no ROV to order")

    def take(self, client_id: str | None, name: str = "", *, streams_input: bool | None = None,
             unless_held: bool = False) -> Client:
        """Give control to `client_id`, or to a new script client if None.

        `streams_input`: its input is a stream that may already be held off
        neutral (a page's keys and gamepad, a ground station's joystick): it
        drives only once that input has been neutral since this taking.  By
        default a page streams, a script does not (it has sent nothing yet,
        and each of its wishes is a deliberate new one).  `unless_held`: only if
        nobody else holds control (NotHolder if someone does), decided under the
        desk's lock: a ground station that takes control when it is free never
        takes it from a page that took it a moment before."""
        self.check_live()
        with self._lock:
            if unless_held and self._holder is not None and self._holder != client_id:
                raise NotHolder(f"control is held by {self._clients[self._holder].name}")
            if client_id is None:
                client = Client(secrets.token_urlsafe(16), "script", name or "script", self._clock())
                self._clients[client.id] = client
            else:
                client = self._lookup(client_id)
                client.last_seen = self._clock()
                if name:
                    client.name = name
            if self._holder == client.id:
                return client
            previous = self._give(client, streams_input)
        taken = f" from {previous.name}" if previous else ""
        self.operator.note(f"control taken by {client.name}{taken}")
        self._publish_control()
        return client

    def _give(self, client: Client, streams_input: bool | None) -> Client | None:
        # (lock held) Control to `client`; the previous holder's Client, if any.
        previous = self._holder_client()
        self._set_neutral()
        self._holder, self._held_since = client.id, self._clock()
        self._resume = None  # taken: nobody is given it back
        self.operator.set_attended(True)
        self._disarmed_unattended = False
        client.streamed_at = None
        client.streams = client.kind == "browser" if streams_input is None else streams_input
        self._uncentre(client)
        if not client.streams:
            self._centred(client)  # a script's first wish is a deliberate new one
        self.version += 1
        return previous

    def release(self, client_id: str | None) -> None:
        with self._lock:
            self.require(client_id)
            name = self._clients[client_id].name
            self._release(f"control released by {name}")

    def _release(self, why: str) -> None:
        # Caller holds the lock.
        self._resume = None
        self._set_neutral()
        self._holder, self._held_since = None, None
        self.operator.set_pilot_in_force(False)
        self.operator.set_attended(False)
        self._unheld_since = self._clock()
        self.version += 1
        self.operator.note(why)
        self._publish_control()

    def _publish_control(self) -> None:
        self.operator.publish("control", self.status())

    def _set_neutral(self) -> None:
        if self.operator.velocity_wish() != NEUTRAL:
            self.operator.set_velocity(*NEUTRAL)

    def require(self, client_id: str | None, touch: bool = True) -> Client:
        """The holder's Client, or NotHolder saying why not."""
        self.check_live()
        with self._lock:
            if self._holder is None:
                raise NotHolder("nobody holds control: POST /api/control/take first")
            if client_id is None:
                raise NotHolder(f"control is held by {self._clients[self._holder].name}; send your "
                                f"X-Rovlink-Client header, or POST /api/control/take to take over")
            if client_id != self._holder:
                self._lookup(client_id)
                raise NotHolder(f"control is held by {self._clients[self._holder].name}, not by you: "
                                f"POST /api/control/take to take over")
            client = self._clients[client_id]
            if touch:
                client.last_seen = self._clock()
            return client

    def scene_refusal(self, scene_key: str | None) -> str | None:
        """May a viewer of the 3D scene opened with `scene_key` order now?
        None if so (its page holds control), else why not, in one line."""
        try:
            self.check_live()
        except Replaying as exc:
            return str(exc)
        with self._lock:
            return self._scene_reason(scene_key)

    def _scene_reason(self, scene_key: str | None) -> str | None:
        holder = self._holder_client()
        if holder is None:
            return "nobody holds control: take control on the operator page first"
        if scene_key is None:
            return (f"control is held by {holder.name}; this 3D view was not opened from an operator "
                    f"page and can only watch")
        if holder.scene_key != scene_key:
            return f"control is held by {holder.name}, not by this page: take control to order"
        holder.last_seen = self._clock()
        return None

    # ------------------------------------------------------------------
    # Timers
    # ------------------------------------------------------------------

    def tick(self) -> None:
        """What no request triggers: the dead man, script leases, nobody in
        control (neutral; a warning; optionally disarm).  A few times a second."""
        now = self._clock()
        # An order waiting on the link process holds the lock (2 s at most): this tick
        # is skipped, not waited for (the pages' telemetry calls it, and would stall).
        if not self._lock.acquire(blocking=False):
            return
        try:
            self._tick(now)
        finally:
            self._lock.release()

    def _tick(self, now: float) -> None:
        # (lock held)
        holder = self._holder_client()
        if holder is not None and holder.streamed_at is not None \
                and now - holder.streamed_at > self.deadman_s:
            holder.streamed_at = None
            self._set_neutral()
            self._uncentre(holder)  # the stick's state is unknown until its next neutral
            self.operator.note(f"velocity from {holder.name} stopped arriving: neutral", "warn")
            self._publish_control()
        if self._resume is not None and now > self._resume[2]:
            self.operator.note(f"control not given back: {self._resume[1]} did not reconnect within "
                               f"{self.resume_s:g} s")
            self._resume = None
        if holder is not None and holder.kind == "script" and now - holder.last_seen > self.lease_s:
            self._release(f"control released: {holder.name} silent for {self.lease_s:g} s")
            holder = None
        for client in [c for c in self._clients.values() if c.kind == "script"]:
            # Forget idle scripts so that memory stays flat.
            if client.id != self._holder and now - client.last_seen > self.lease_s:
                del self._clients[client.id]
        if holder is None:
            self._set_neutral()  # nobody in control: nobody drives
            if self.disarm_unattended_s is not None and not self._disarmed_unattended \
                    and self._armed() and now - self._unheld_since >= self.disarm_unattended_s \
                    and not self.operator.replaying:
                self._disarmed_unattended = True
                self.operator.note(f"nobody in control for {self.disarm_unattended_s:g} s with the "
                                   f"vehicle armed: disarming", "alert")
                self.operator.arm(False)

    def _armed(self) -> bool:
        report = self.operator.vehicle()
        return bool(report is not None and report.armed)

    def _unattended_s(self) -> float | None:
        """How long the vehicle has been armed with nobody in control (None if it is not; lock held)."""
        if self._holder is not None or not self._armed() or self.operator.replaying:
            return None
        return self._clock() - self._unheld_since

    # ------------------------------------------------------------------
    # Status
    # ------------------------------------------------------------------

    def status(self, client_id: str | None = None) -> dict:
        # Read without the lock when an order waiting on the link holds it: the pages'
        # telemetry must not stall meanwhile; what changes under it shows next tick.
        locked = self._lock.acquire(timeout=STATUS_WAIT_S)
        try:
            holder = self._holder_client()
            unattended = self._unattended_s()
            return {
                "held": holder is not None,
                "holder": holder.name if holder else None,
                "holder_kind": holder.kind if holder else None,
                "held_for_s": self._clock() - self._held_since if holder and self._held_since else None,
                "you": holder is not None and client_id == holder.id,
                "lease_s": self.lease_s,
                "unattended_s": unattended,
                "unattended_warning": unattended is not None and unattended >= self.unattended_warn_s,
                "disarm_unattended_s": self.disarm_unattended_s,
                "centre_to_drive": holder is not None and not holder.centred,
            }
        finally:
            if locked:
                self._lock.release()
