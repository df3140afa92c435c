"""A position order's end, as the replies show it.

The ROV acknowledges a POSITION when GUIDED has taken it (rov/goto.py); after
that the protocol says nothing more of it.  The pilot still needs to know
whether it got there, how far it has left, and whether it was given up: so
the console follows it in the replies.  Decision: it is "arrived" once a reply
puts the vehicle within ARRIVED_M of the target (and ARRIVED_YAW_DEG of its
heading); "aborted: ..." when a STOP or a newer position order replaces it,
when the ROV reports FAILSAFE (it braked and holds), when the vehicle is
disarmed, or when it leaves GUIDED after having flown it (a mode request,
the autopilot's own failsafe).  Until then the order carries
`distance_left_m`, from each reply's position.  Nothing here sends anything.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rovlink.link.vocabulary import Mode

from .fates import Fate
from .odometry import Fix
from .orders import REPORTED_MODE_NAMES, OrderBook

ARRIVED_M = 0.5
ARRIVED_YAW_DEG = 10.0


@dataclass
class _Active:
    order_id: int
    target: tuple[float, float, float, float]  # x, y, z m (NED), yaw deg
    seen_guided: bool = False
    shown_m: float | None = None


def resolve_target(x_m: float, y_m: float, z_m: float, yaw_deg: float, *, relative: bool, body: bool,
                   fix: Fix | None) -> tuple[float, float, float, float] | None:
    """Where an order goes, in NED, as the ROV resolves it (against the pose it
    has when it takes it: here the last one received); None when a relative
    order has no pose to go from."""
    if not relative:
        return x_m, y_m, max(z_m, 0.0), yaw_deg
    if fix is None:
        return None
    pose = fix.pose
    if body:
        c, s = math.cos(math.radians(pose.yaw_deg)), math.sin(math.radians(pose.yaw_deg))
        x_m, y_m = c * x_m - s * y_m, s * x_m + c * y_m
    return pose.x_m + x_m, pose.y_m + y_m, max(pose.z_m + z_m, 0.0), pose.yaw_deg + yaw_deg


class GoToWatch:
    """The position order in force, followed from the replies (the caller holds
    the session's lock or is the link's thread)."""

    def __init__(self, orders: OrderBook) -> None:
        self._orders = orders
        self.active: _Active | None = None

    def started(self, order_id: int, target: tuple[float, float, float, float] | None, t: float) -> None:
        self.abort(f"replaced by position order #{order_id}", t)
        if target is not None:
            self.active = _Active(order_id, target)

    def abort(self, why: str, t: float) -> None:
        """A STOP or a newer order: the one in force is given up (if it was in force)."""
        active, self.active = self.active, None
        if active is None:
            return
        fate = self._orders.fate(active.order_id)
        if fate is not None and not fate.ended:
            self._orders.set_state(active.order_id, Fate.ABORTED, t, why)

    def on_reply(self, fix: Fix, t: float) -> None:
        active = self.active
        if active is None:
            return
        fate = self._orders.fate(active.order_id)
        if fate is None or fate.ended:
            self.active = None
            return
        reply, pose = fix.report, fix.pose
        x, y, z, yaw = active.target
        left = math.dist((pose.x_m, pose.y_m, pose.z_m), (x, y, z)) if reply.position_valid else None
        shown = None if left is None else round(left, 1)
        if shown != active.shown_m:
            active.shown_m = shown
            self._orders.update(active.order_id, distance_left_m=shown)
        if fate is not Fate.ACKNOWLEDGED:
            return  # not taken yet (queued, sent): nothing to judge
        if reply.failsafe:
            self._end(Fate.ABORTED, t, "the ROV went into FAILSAFE (it braked and holds)")
        elif not reply.armed:
            self._end(Fate.ABORTED, t, "the vehicle is disarmed")
        elif left is not None and left <= ARRIVED_M and (
                not reply.attitude_valid or abs((pose.yaw_deg - yaw + 180) % 360 - 180) <= ARRIVED_YAW_DEG):
            self._end(Fate.ARRIVED, t)
        elif reply.mode == Mode.GUIDED:
            active.seen_guided = True
        elif active.seen_guided:
            self._end(Fate.ABORTED, t, f"the vehicle left GUIDED for {REPORTED_MODE_NAMES.get(int(reply.mode), 'OTHER')}")

    def _end(self, fate: Fate, t: float, reason: str = "") -> None:
        active, self.active = self.active, None
        self._orders.set_state(active.order_id, fate, t, reason)
