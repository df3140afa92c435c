"""The ghost: where the vehicle is now, from where it last said it was.

The last odometry, from its sample time, flown forward with
`rov.vehicle.VehicleModel` under the wishes as they were sent, each from when it
reached the ROV (never today's wish over yesterday's pose), as the ROV applies
them: a STOP brakes, HOLD ignores non-zero wishes until a neutral one arrives,
a wish lapses after the link's velocity lapse (radio §5: 1.5 s) without another.  The same model previews
the path of a position order before it is sent.
"""

from __future__ import annotations

import collections
import math

from rovlink.rov.ardusub import PROTOCOL_TO_SUB
from rovlink.rov.vehicle import (
    Controls,
    PilotInput,
    PositionTarget,
    SubMode,
    VehicleModel,
    VehicleState,
)

from .odometry import Fix, Pose

NEUTRAL_WISH = (0.0, 0.0, 0.0, 0.0)
STOP_WISH = ("STOP",)     # a STOP poll in the timeline of wishes sent: brake and HOLD


class Predictor:
    """The wishes as they went out, and the poses they lead to.  Not thread-safe
    on its own: the session calls it under its lock (`wishes` is copied)."""

    def __init__(self, *, velocity_lapse_s: float) -> None:
        # (arrival at the ROV, (vx, vy, vz, vyaw) fractions | STOP_WISH)
        self.sent: collections.deque = collections.deque(maxlen=256)
        self.velocity_lapse_s = velocity_lapse_s  # the link's rule (radio §5): a wish lapses without another

    def wish_sent(self, arrival: float, wish: tuple[float, float, float, float]) -> None:
        self.sent.append((arrival, tuple(wish)))

    def stop_sent(self, arrival: float) -> None:
        self.sent.append((arrival, STOP_WISH))

    def predict(self, fix: Fix | None, at: float, failsafe_s: float) -> Pose | None:
        """Dead reckoning from `fix` to session time `at`, no further than the
        ROV's failsafe time past its sample (by then, with no poll heard, it has
        stopped; beyond it the uncertainty grows instead)."""
        if fix is None:
            return None
        reply, sampled, vel = fix.report, fix.sampled_at, fix.velocity
        end = sampled + max(0.0, min(at - sampled, failsafe_s))
        pose = fix.pose
        if end <= sampled:
            return pose
        state = VehicleState(x_m=pose.x_m, y_m=pose.y_m, z_m=pose.z_m, yaw_rad=math.radians(pose.yaw_deg),
                             vn_mps=vel[0], ve_mps=vel[1], vd_mps=vel[2], yaw_rate_radps=math.radians(vel[3]))
        model = VehicleModel(state=state)
        mode = PROTOCOL_TO_SUB.get(reply.mode, SubMode.MANUAL)
        hold = bool(reply.hold or reply.failsafe)
        wish, wish_at = NEUTRAL_WISH, -math.inf
        t = sampled
        for arrival, sent in list(self.sent):
            if arrival > t:
                t = _fly(model, t, min(arrival, end), wish, wish_at + self.velocity_lapse_s, hold, mode, reply.armed)
                if t >= end:
                    break
            if sent is STOP_WISH:
                wish, hold = NEUTRAL_WISH, True
            else:
                wish, wish_at = sent, arrival
                if hold and not any(sent):
                    hold = False  # the re-centring reached the ROV
        if t < end:
            _fly(model, t, end, wish, wish_at + self.velocity_lapse_s, hold, mode, reply.armed)
        s = model.state
        return Pose(s.x_m, s.y_m, s.z_m, pose.roll_deg, pose.pitch_deg, math.degrees(s.yaw_rad))


def _fly(model: VehicleModel, t: float, until: float, wish: tuple, lapse_at: float, hold: bool, mode,
         armed: bool) -> float:
    """Step the model from t to `until` under `wish` as the ROV applies it, neutral from `lapse_at`."""
    for t0, t1, applied in ((t, min(until, lapse_at), wish), (max(t, lapse_at), until, NEUTRAL_WISH)):
        if t1 > t0:
            if hold:
                applied = NEUTRAL_WISH
            model.step(t1 - t0, Controls(pilot=PilotInput.from_velocity(*applied), mode=mode, armed=armed,
                                         target=None))
    return until


def preview_path(start: Pose, x_m: float, y_m: float, z_m: float, yaw_deg: float = 0.0, *,
                 seconds: float = 30.0, step_s: float = 0.5) -> list[tuple[float, float, float]]:
    """Where a POSITION order would take the vehicle from `start` (GUIDED)."""
    model = VehicleModel(state=VehicleState(x_m=start.x_m, y_m=start.y_m, z_m=start.z_m,
                                            yaw_rad=math.radians(start.yaw_deg)))
    target = PositionTarget(x_m=x_m, y_m=y_m, z_m=z_m, yaw_rad=math.radians(yaw_deg))
    controls = Controls(pilot=PilotInput(), mode=SubMode.GUIDED, armed=True, target=target)
    points = [(start.x_m, start.y_m, start.z_m)]
    t = 0.0
    while t < seconds:
        s = model.step(step_s, controls)
        points.append((s.x_m, s.y_m, s.z_m))
        t += step_s
        if math.dist(points[-1], (x_m, y_m, z_m)) < 0.05:
            break
    return points
