"""A BlueROV-like vehicle and the ArduSub controllers that fly it, as pure physics.

Goals
- One model of how the vehicle moves under ArduSub, used in three places: the
  simulated autopilot (`rov.simulator`, stepped with real time), the tests (stepped
  in simulated time, fast), and the console's pose prediction (dead reckoning from
  the pilot's last wish).
- Behave roughly like ArduSub on a BlueROV as measured with ArduSub SITL:
  5.5 m forward in 8 s at x=700 (MANUAL); 4.7 m deeper in 8 s at z=150 (ALT_HOLD),
  then depth held at z=500; 144 degrees of yaw in 4 s at r=600; a GUIDED target
  7.3 m away reached within 0.14 m in 15 s.
- No clock, no socket, no thread: `VehicleModel.step(dt_s, controls)` is all there is.

Plan
- 4 degrees of freedom: surge and sway (body frame), heave (down), yaw.  Roll and
  pitch stay zero: a BlueROV is strongly self-righting and the link does not care.
- Each axis is a mass (with added mass) pushed by thrust and slowed by linear plus
  quadratic drag; the vehicle is slightly positively buoyant, so depth is only held
  when a controller holds it.
- The modes shape thrust the way ArduSub does: MANUAL passes pilot input straight to
  the thrusters; STABILIZE adds heading hold and a yaw-rate loop; ALT_HOLD adds a
  climb-rate loop on the pilot's z and holds depth at z=500; POSHOLD also holds the
  horizontal position while x and y are neutral; GUIDED flies to a position target
  with a speed limit; SURFACE climbs to the surface.  Controller memory (the depth,
  heading and position being held) lives in the model, reset on mode changes.

API
- `PilotInput(x, y, z, r)`: MANUAL_CONTROL in ArduSub's units (x, y, r -1000..1000,
  z 0..1000 with 500 neutral, z below 500 goes down).  `PilotInput.from_velocity(vx,
  vy, vz, vyaw)` maps the protocol's velocity wish (fractions -1..1, body frame, z
  down, yaw clockwise) onto it; the autopilot bridge uses the same mapping.
- `Controls(pilot, mode, armed, target)`: what the autopilot acts on; `mode` is an
  ArduSub custom mode number (`SubMode`), `target` a `PositionTarget` or None.
- `VehicleModel(state=None, params=BlueRovParams(), floor_depth_m=None)`;
  `.step(dt_s, controls) -> VehicleState` advances by any dt (internally in small
  sub-steps) and returns the new state; `.state` is the current `VehicleState`
  (x, y, z metres local NED, yaw radians, NED velocities, yaw rate).
  Cost: about 100 sub-steps per simulated second, roughly 1-2 ms of CPU.
- Measured with this model (tests/rov/test_vehicle_model.py checks them):
  5.49 m forward in 8 s at x=700; 4.68 m deeper in 8 s at z=150, then held within
  0.07 m; 147 (MANUAL) / 142 (STABILIZE) degrees in 4 s at r=600; a GUIDED target
  7.3 m away reached within 0.10 m in 15 s.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from rovlink.rov.ardusub import SubMode  # ArduSub's modes, from pymavlink (re-exported here)

# Modes that need a horizontal position estimate; ArduSub refuses them without one.
POSITION_MODES = frozenset({SubMode.GUIDED, SubMode.POSHOLD, SubMode.AUTO, SubMode.CIRCLE})
# Modes the model flies; others (ACRO, AUTO, ...) are refused by the simulator.
FLOWN_MODES = frozenset(
    {SubMode.STABILIZE, SubMode.ALT_HOLD, SubMode.GUIDED, SubMode.SURFACE, SubMode.POSHOLD, SubMode.MANUAL}
)


def _clamp(value: float, low: float, high: float) -> float:
    return low if value < low else high if value > high else value


def wrap_angle(angle_rad: float) -> float:
    """Angle folded into [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True)
class PilotInput:
    """MANUAL_CONTROL in ArduSub's ranges: x forward, y right, r clockwise in
    -1000..1000; z 0..1000 with 500 neutral, below 500 down."""

    x: int = 0
    y: int = 0
    z: int = 500
    r: int = 0

    @classmethod
    def from_velocity(cls, vx: float, vy: float, vz: float, vyaw: float) -> "PilotInput":
        """From a velocity wish in fractions of the maximum (-1..1; body frame, x
        forward, y right, z down, yaw clockwise).  NaN counts as zero."""

        def frac(value: float) -> float:
            value = float(value)
            return 0.0 if math.isnan(value) else _clamp(value, -1.0, 1.0)

        return cls(
            x=round(1000 * frac(vx)),
            y=round(1000 * frac(vy)),
            # z is down in the wish but "throttle up" in MANUAL_CONTROL.
            z=round(500 - 500 * frac(vz)),
            r=round(1000 * frac(vyaw)),
        )

    def clamped(self) -> "PilotInput":
        return PilotInput(
            x=int(_clamp(self.x, -1000, 1000)),
            y=int(_clamp(self.y, -1000, 1000)),
            z=int(_clamp(self.z, 0, 1000)),
            r=int(_clamp(self.r, -1000, 1000)),
        )


NEUTRAL = PilotInput()


@dataclass(frozen=True)
class PositionTarget:
    """A GUIDED target in local NED metres; yaw None keeps the current heading."""

    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float | None = None


@dataclass(frozen=True)
class Controls:
    pilot: PilotInput = NEUTRAL
    mode: int = SubMode.MANUAL
    armed: bool = False
    target: PositionTarget | None = None


@dataclass(frozen=True)
class VehicleState:
    """Pose and velocities in the local NED frame (x north, y east, z down)."""

    x_m: float = 0.0
    y_m: float = 0.0
    z_m: float = 0.0
    yaw_rad: float = 0.0
    vn_mps: float = 0.0  # velocity north
    ve_mps: float = 0.0  # velocity east
    vd_mps: float = 0.0  # velocity down
    yaw_rate_radps: float = 0.0
    roll_rad: float = 0.0
    pitch_rad: float = 0.0


@dataclass(frozen=True)
class BlueRovParams:
    """Masses include added mass; drag is linear + quadratic per axis.  Fitted so
    the SITL facts in the module docstring come out roughly right."""

    mass_surge_kg: float = 18.0
    mass_sway_kg: float = 22.0
    mass_heave_kg: float = 24.0
    inertia_yaw_kgm2: float = 0.9
    thrust_surge_n: float = 29.0
    thrust_sway_n: float = 35.0
    thrust_heave_n: float = 45.0
    torque_yaw_nm: float = 6.0
    drag_lin_surge: float = 6.0
    drag_quad_surge: float = 30.0
    drag_lin_sway: float = 8.0
    drag_quad_sway: float = 40.0
    drag_lin_heave: float = 8.0
    drag_quad_heave: float = 40.0
    drag_lin_yaw: float = 1.5
    drag_quad_yaw: float = 6.0
    buoyancy_n: float = 1.0  # net upward force: the vehicle floats up slowly if left alone
    # ArduSub-like controller settings
    climb_rate_max_mps: float = 0.86  # ALT_HOLD climb rate at full z stick
    yaw_rate_max_radps: float = 1.08  # STABILIZE family yaw rate at full r stick
    stick_deadzone: float = 0.05
    guided_speed_mps: float = 0.5  # horizontal speed limit in GUIDED
    guided_speed_z_mps: float = 0.5
    guided_pos_gain: float = 1.0  # 1/s
    guided_yaw_rate_radps: float = 0.8
    surface_rate_mps: float = 0.5
    substep_s: float = 0.01


class VehicleModel:
    """The vehicle plus ArduSub's controllers.  Pure: state in, state out."""

    def __init__(
        self,
        state: VehicleState | None = None,
        params: BlueRovParams | None = None,
        floor_depth_m: float | None = None,
    ) -> None:
        self.params = params or BlueRovParams()
        self.state = state or VehicleState()
        # Keep the vehicle's centre this far above the seabed (half its height).
        self.floor_depth_m = floor_depth_m
        self.floor_clearance_m = 0.15
        self._last_mode: int | None = None
        self._hold_depth_m: float | None = None
        self._hold_yaw_rad: float | None = None
        self._hold_xy: tuple[float, float] | None = None
        self._climb_integral = 0.0
        self._yaw_integral = 0.0

    def reset(self, state: VehicleState | None = None) -> None:
        self.state = state or VehicleState()
        self._last_mode = None
        self._release_holds()

    def _release_holds(self) -> None:
        self._hold_depth_m = None
        self._hold_yaw_rad = None
        self._hold_xy = None
        self._climb_integral = 0.0
        self._yaw_integral = 0.0

    # --- public --------------------------------------------------------------

    def step(self, dt_s: float, controls: Controls) -> VehicleState:
        dt_s = float(dt_s)
        if not (dt_s > 0.0) or math.isinf(dt_s):
            return self.state
        if controls.mode != self._last_mode:
            self._release_holds()
            self._last_mode = controls.mode
        if not controls.armed:
            self._release_holds()
        pilot = controls.pilot.clamped()
        n = max(1, math.ceil(dt_s / self.params.substep_s))
        h = dt_s / n
        for _ in range(n):
            self._substep(h, controls, pilot)
        return self.state

    # --- controllers -----------------------------------------------------------

    def _stick(self, value: float) -> float:
        """A stick fraction with ArduSub's deadzone taken out."""
        dz = self.params.stick_deadzone
        if abs(value) <= dz:
            return 0.0
        return math.copysign((abs(value) - dz) / (1.0 - dz), value)

    def _yaw_command(self, h: float, pilot: PilotInput, mode: int, target: PositionTarget | None) -> float:
        """Yaw torque command -1..1."""
        p, s = self.params, self.state
        if mode == SubMode.MANUAL:
            return pilot.r / 1000.0
        stick = self._stick(pilot.r / 1000.0)
        if stick != 0.0:
            self._hold_yaw_rad = None
            rate_wish = stick * p.yaw_rate_max_radps
        else:
            if mode == SubMode.GUIDED and target is not None and target.yaw_rad is not None:
                self._hold_yaw_rad = wrap_angle(target.yaw_rad)
            elif self._hold_yaw_rad is None:
                # Latch the heading once the turn has slowed, like ArduSub does.
                if abs(s.yaw_rate_radps) > 0.1:
                    return _clamp(-0.5 * s.yaw_rate_radps, -1.0, 1.0)
                self._hold_yaw_rad = s.yaw_rad
            limit = p.guided_yaw_rate_radps if mode == SubMode.GUIDED else p.yaw_rate_max_radps
            rate_wish = _clamp(2.0 * wrap_angle(self._hold_yaw_rad - s.yaw_rad), -limit, limit)
        return self._rate_loop_yaw(h, rate_wish)

    def _rate_loop_yaw(self, h: float, rate_wish: float) -> float:
        p, s = self.params, self.state
        error = rate_wish - s.yaw_rate_radps
        self._yaw_integral = _clamp(self._yaw_integral + error * h, -0.5, 0.5)
        # Feed-forward of the drag the wished rate meets, plus PI on the error.
        ff = (p.drag_lin_yaw * rate_wish + p.drag_quad_yaw * rate_wish * abs(rate_wish)) / p.torque_yaw_nm
        return _clamp(ff + 1.5 * error + 0.5 * self._yaw_integral, -1.0, 1.0)

    def _heave_for_rate(self, h: float, climb_wish_mps: float) -> float:
        """Heave thrust command (-1..1, positive up) for a climb rate."""
        p, s = self.params, self.state
        climb = -s.vd_mps
        error = climb_wish_mps - climb
        self._climb_integral = _clamp(self._climb_integral + error * h, -1.0, 1.0)
        w = climb_wish_mps
        ff = (p.drag_lin_heave * w + p.drag_quad_heave * w * abs(w)) / p.thrust_heave_n
        return _clamp(ff + 3.0 * error + 1.0 * self._climb_integral, -1.0, 1.0)

    def _depth_hold(self, h: float, pilot: PilotInput) -> float:
        p, s = self.params, self.state
        stick = self._stick((pilot.z - 500) / 500.0)
        if stick != 0.0:
            self._hold_depth_m = None
            return self._heave_for_rate(h, stick * p.climb_rate_max_mps)
        if self._hold_depth_m is None:
            if abs(s.vd_mps) > 0.05:
                # Brake first, then latch the depth where the vehicle stopped.
                return self._heave_for_rate(h, 0.0)
            self._hold_depth_m = s.z_m
        climb_wish = _clamp(1.0 * (s.z_m - self._hold_depth_m), -p.climb_rate_max_mps, p.climb_rate_max_mps)
        return self._heave_for_rate(h, climb_wish)

    def _horizontal_for_velocity(self, vn_wish: float, ve_wish: float) -> tuple[float, float]:
        """Surge and sway commands (-1..1) for a NED horizontal velocity."""
        p, s = self.params, self.state
        c, sn = math.cos(s.yaw_rad), math.sin(s.yaw_rad)
        u_wish, v_wish = c * vn_wish + sn * ve_wish, -sn * vn_wish + c * ve_wish
        u, v = c * s.vn_mps + sn * s.ve_mps, -sn * s.vn_mps + c * s.ve_mps
        ff_u = (p.drag_lin_surge * u_wish + p.drag_quad_surge * u_wish * abs(u_wish)) / p.thrust_surge_n
        ff_v = (p.drag_lin_sway * v_wish + p.drag_quad_sway * v_wish * abs(v_wish)) / p.thrust_sway_n
        return (
            _clamp(ff_u + 2.0 * (u_wish - u), -1.0, 1.0),
            _clamp(ff_v + 2.0 * (v_wish - v), -1.0, 1.0),
        )

    def _guided(self, h: float, target: PositionTarget | None) -> tuple[float, float, float]:
        p, s = self.params, self.state
        if target is None:
            # GUIDED without a target holds where it is, like ArduSub's position hold.
            if self._hold_xy is None:
                self._hold_xy = (s.x_m, s.y_m)
                self._hold_depth_m = s.z_m
            target = PositionTarget(self._hold_xy[0], self._hold_xy[1], self._hold_depth_m)
        dn, de = target.x_m - s.x_m, target.y_m - s.y_m
        dist = math.hypot(dn, de)
        # Speed: proportional near the target, square-root braking, capped.
        speed = min(p.guided_speed_mps, p.guided_pos_gain * dist, math.sqrt(2 * 0.4 * dist))
        vn, ve = (dn / dist * speed, de / dist * speed) if dist > 1e-6 else (0.0, 0.0)
        surge, sway = self._horizontal_for_velocity(vn, ve)
        dz = s.z_m - target.z_m
        climb = _clamp(p.guided_pos_gain * dz, -p.guided_speed_z_mps, p.guided_speed_z_mps)
        return surge, sway, self._heave_for_rate(h, climb)

    def _poshold_xy(self, pilot: PilotInput) -> tuple[float, float]:
        s = self.state
        if pilot.x != 0 or pilot.y != 0:
            self._hold_xy = None
            return pilot.x / 1000.0, pilot.y / 1000.0
        if self._hold_xy is None:
            if math.hypot(s.vn_mps, s.ve_mps) > 0.05:
                return self._horizontal_for_velocity(0.0, 0.0)
            self._hold_xy = (s.x_m, s.y_m)
        gain = self.params.guided_pos_gain
        vn = _clamp(gain * (self._hold_xy[0] - s.x_m), -0.3, 0.3)
        ve = _clamp(gain * (self._hold_xy[1] - s.y_m), -0.3, 0.3)
        return self._horizontal_for_velocity(vn, ve)

    def _commands(self, h: float, controls: Controls, pilot: PilotInput) -> tuple[float, float, float, float]:
        """surge, sway, heave (positive up), yaw commands, each -1..1."""
        if not controls.armed:
            return 0.0, 0.0, 0.0, 0.0
        mode = controls.mode
        yaw = self._yaw_command(h, pilot, mode, controls.target)
        if mode == SubMode.GUIDED:
            surge, sway, heave = self._guided(h, controls.target)
            return surge, sway, heave, yaw
        surge, sway = pilot.x / 1000.0, pilot.y / 1000.0
        if mode == SubMode.POSHOLD:
            surge, sway = self._poshold_xy(pilot)
        if mode in (SubMode.ALT_HOLD, SubMode.POSHOLD):
            heave = self._depth_hold(h, pilot)
        elif mode == SubMode.SURFACE:
            heave = self._heave_for_rate(h, self.params.surface_rate_mps) if self.state.z_m > 0.05 else 0.0
        else:  # MANUAL, STABILIZE: throttle straight to the vertical thrusters
            heave = (pilot.z - 500) / 500.0
        return surge, sway, heave, yaw

    # --- physics -------------------------------------------------------------

    def _substep(self, h: float, controls: Controls, pilot: PilotInput) -> None:
        p, s = self.params, self.state
        surge_cmd, sway_cmd, heave_cmd, yaw_cmd = self._commands(h, controls, pilot)
        c, sn = math.cos(s.yaw_rad), math.sin(s.yaw_rad)
        u, v = c * s.vn_mps + sn * s.ve_mps, -sn * s.vn_mps + c * s.ve_mps
        fu = p.thrust_surge_n * surge_cmd - p.drag_lin_surge * u - p.drag_quad_surge * u * abs(u)
        fv = p.thrust_sway_n * sway_cmd - p.drag_lin_sway * v - p.drag_quad_sway * v * abs(v)
        w = s.vd_mps
        fw = -p.thrust_heave_n * heave_cmd - p.buoyancy_n - p.drag_lin_heave * w - p.drag_quad_heave * w * abs(w)
        r = s.yaw_rate_radps
        tr = p.torque_yaw_nm * yaw_cmd - p.drag_lin_yaw * r - p.drag_quad_yaw * r * abs(r)
        # Semi-implicit Euler: velocities first, positions from the new velocities.
        u += fu / p.mass_surge_kg * h
        v += fv / p.mass_sway_kg * h
        w += fw / p.mass_heave_kg * h
        r += tr / p.inertia_yaw_kgm2 * h
        yaw = wrap_angle(s.yaw_rad + r * h)
        vn, ve = c * u - sn * v, sn * u + c * v
        z = s.z_m + w * h
        if z < 0.0:  # the surface: it floats there
            z, w = 0.0, max(w, 0.0)
        if self.floor_depth_m is not None and z > self.floor_depth_m - self.floor_clearance_m:
            z, w = self.floor_depth_m - self.floor_clearance_m, min(w, 0.0)
        self.state = dataclasses.replace(
            s,
            x_m=s.x_m + vn * h,
            y_m=s.y_m + ve * h,
            z_m=z,
            yaw_rad=yaw,
            vn_mps=vn,
            ve_mps=ve,
            vd_mps=w,
            yaw_rate_radps=r,
        )
