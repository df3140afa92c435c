"""The position order (docs/PROTOCOL.md §2 POSITION) as ArduSub's GUIDED mode flies it,
without I/O.

Goals
- Take a position order only when it can work: an autopilot, armed, with a
  position estimate.  Otherwise refuse it at once as impossible now (REASON 1):
  ArduSub acknowledges GUIDED disarmed and sits there, and refuses it without a
  position ("GUIDED requires position").
- Report the autopilot's refusal of GUIDED, or its silence for 2 s, as REASON 2.

Plan
- `GotoDriver.start(ticket, order, snapshot, now)` checks the order, resolves
  relative and body-frame offsets against the snapshot, and asks the
  `CommandTracker` for GUIDED unless the vehicle is already in it.
- `step(snapshot, now)` is called by the bridge's I/O loop; it returns the target
  to send (SET_POSITION_TARGET_LOCAL_NED) once GUIDED is acknowledged, and again
  every second (ArduSub keeps it; a lost datagram costs one second).  ArduSub does
  not acknowledge targets, so the ticket is accepted when GUIDED is confirmed and
  the target first handed out.
- The order ends with `cancel` (STOP, a mode request, a newer order) or when the
  autopilot leaves GUIDED by itself.
- A GUIDED that the autopilot accepts after the order failed for want of an answer
  (docs/PROTOCOL.md §3: an answer after the 2 s) sets `brake_wanted`: the bridge brakes
  as for STOP, since nobody flies that GUIDED any more.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from rovlink.link.radio.messages import Reason
from rovlink.rov.ardusub import SubMode
from rovlink.rov.commands import CommandTracker, GotoTicket, Request, Ticket
from rovlink.rov.telemetry import AutopilotSnapshot
from rovlink.rov.vehicle import wrap_angle

log = logging.getLogger(__name__)

REACHED_DISTANCE_M = 0.3
REACHED_YAW_RAD = math.radians(10)
TARGET_RESEND_S = 1.0
LATE_ANSWER_WATCH_S = 10.0  # how long a late GUIDED is still taken as our late answer


@dataclass(frozen=True)
class GotoOrder:
    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float | None = None  # None keeps the heading
    relative: bool = False
    body: bool = False


@dataclass
class _Active:
    ticket: GotoTicket
    mode_request: Request | None
    target_sent_s: float = -math.inf
    seen_guided: bool = False


def goto_refusal(snap: AutopilotSnapshot) -> str | None:
    """Why a position order is impossible now (REASON 1), or None."""
    if not snap.autopilot_alive:
        return "no autopilot"
    if not snap.armed:
        return "the vehicle is disarmed"
    if not snap.position_valid:
        return "no position estimate"
    return None


def resolve_target(order: GotoOrder, snap: AutopilotSnapshot) -> tuple[float, float, float, float | None]:
    x, y, z, yaw = order.x_m, order.y_m, order.z_m, order.yaw_rad
    if order.relative:
        if order.body:
            c, s = math.cos(snap.yaw_rad), math.sin(snap.yaw_rad)
            x, y = c * x - s * y, s * x + c * y
        x, y, z = snap.x_m + x, snap.y_m + y, snap.z_m + z
        yaw = wrap_angle(snap.yaw_rad + yaw) if yaw is not None else None
    elif yaw is not None:
        yaw = wrap_angle(yaw)
    # The vehicle cannot fly above the surface; ArduSub would clamp too.
    return x, y, max(z, 0.0), yaw


class GotoDriver:
    def __init__(self, tracker: CommandTracker) -> None:
        self.tracker = tracker
        self.active: _Active | None = None
        self.brake_wanted = False
        self._late_until_s = -math.inf

    def start(self, ticket: GotoTicket, order: GotoOrder, snap: AutopilotSnapshot, now: float) -> None:
        why = goto_refusal(snap)
        if why is not None:
            ticket.fail(why, Reason.IMPOSSIBLE)
            return
        self.cancel("replaced by a newer position order")
        self._late_until_s = -math.inf  # a newer POSITION: a late GUIDED is no longer ours to stop
        ticket.target = resolve_target(order, snap)
        request = None
        if snap.custom_mode != SubMode.GUIDED:
            request = self.tracker.mode(Ticket("mode GUIDED for a position order"), SubMode.GUIDED, now)
        self.active = _Active(ticket, request)

    def cancel(self, why: str) -> None:
        active, self.active = self.active, None
        if active is not None:
            active.ticket._resolve(Ticket.CANCELLED, why)
            if active.mode_request is not None and not active.mode_request.ticket.done:
                self.tracker.discard(active.mode_request)
                active.mode_request.ticket._resolve(Ticket.CANCELLED, why)

    def step(self, snap: AutopilotSnapshot, now: float) -> tuple[float, float, float, float | None] | None:
        """The target to send now, if any."""
        active = self.active
        if active is None:
            if snap.custom_mode == SubMode.GUIDED and now < self._late_until_s:
                log.warning("the autopilot took GUIDED after the position order had failed: braking")
                self._late_until_s = -math.inf
                self.brake_wanted = True
            return None
        ticket, request = active.ticket, active.mode_request
        if request is not None and request.ticket.status == Ticket.CANCELLED:
            self.active = None
            ticket._resolve(Ticket.CANCELLED, request.ticket.reason)
            return None
        if request is not None and request.ticket.status == Ticket.FAILED:
            self.active = None
            reason = request.ticket.reject_reason or Reason.REFUSED
            ticket.fail(f"autopilot refused GUIDED ({request.ticket.reason})", reason)
            if request.timed_out and request.ticket.reject_reason == Reason.REFUSED:
                self._late_until_s = now + LATE_ANSWER_WATCH_S
            return None
        if snap.custom_mode == SubMode.GUIDED:
            active.seen_guided = True
        elif active.seen_guided:
            # The autopilot left GUIDED on its own (a failsafe, another ground
            # station): the order is over; do not keep sending targets it ignores.
            log.info("autopilot left GUIDED: position order ended")
            self.active = None
            return None
        guided = snap.custom_mode == SubMode.GUIDED or (request is not None and request.ticket.ok)
        if not guided:
            return None
        target = None
        if now - active.target_sent_s >= TARGET_RESEND_S:
            active.target_sent_s = now
            target = ticket.target
            if ticket._resolve(Ticket.ACCEPTED):
                x, y, z, yaw = target
                log.info("GUIDED target: x %.2f y %.2f z %.2f m yaw %s", x, y, z,
                         "keep" if yaw is None else f"{math.degrees(yaw):.0f} deg")
        if snap.position_valid:
            x, y, z, yaw = ticket.target
            close = math.dist((snap.x_m, snap.y_m, snap.z_m), (x, y, z)) < REACHED_DISTANCE_M
            facing = yaw is None or abs(wrap_angle(yaw - snap.yaw_rad)) < REACHED_YAW_RAD
            ticket.reached = close and facing
        return target
