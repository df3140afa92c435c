"""A simulated ArduSub: a MAVLink endpoint flying `rov.vehicle.VehicleModel`.

Goals
- Behave like ArduSub as far as the autopilot bridge can see, so that one bridge
  (`rov.autopilot`) drives both this and the real vehicle, and tests exercise the
  real pymavlink code over real sockets.
- Run embedded (a background thread on a loopback UDP port, the default of
  `rovlink rov`) or alone (`rovlink sim --mavlink URL`).

Plan
- One thread owns the pymavlink connection and the model: it waits for messages
  until the next tick (50 Hz), then steps the model by the real time elapsed,
  checks the pilot-input failsafe and sends whatever streams are due.
- What ArduSub does and we copy (../shared/ARDUSUB.md): HEARTBEAT at 1 Hz (or
  the interval a SET_MESSAGE_INTERVAL asks for) as MAV_TYPE_SUBMARINE with
  ArduSub's custom modes (base_mode carries CUSTOM_MODE_ENABLED and SAFETY_ARMED);
  COMMAND_LONG ARM_DISARM, DO_SET_MODE, SET_MESSAGE_INTERVAL, REQUEST_MESSAGE and
  the SET_MODE message, each answered by COMMAND_ACK (SET_MODE's ack names message
  id 11, as ArduPilot does); an accepted mode change is followed at once by an
  extra HEARTBEAT showing it; MANUAL_CONTROL addressed to us is the pilot input;
  without it for 3 s an armed vehicle disarms ("Lost manual control");
  SET_POSITION_TARGET_LOCAL_NED is taken only in GUIDED and only as a position
  (optionally with yaw), in LOCAL_NED, LOCAL_OFFSET_NED, BODY_NED or
  BODY_OFFSET_NED, otherwise silently ignored as ArduSub does; GUIDED and POSHOLD
  are refused without a position estimate: STATUSTEXT "GUIDED requires position"
  (as ArduSub says it; "POSHOLD requires position" is our guess) then ACK FAILED.
  The estimate comes `position_after_s` after start (ArduSub SITL: ~41 s; default
  0 here; None: never, like a BlueROV without DVL or underwater GPS), and
  `position_available` can take it away or give it back; without it no
  LOCAL_POSITION_NED is sent.  Disarmed, GUIDED is accepted (and the vehicle sits).
- Flying: the model's POSHOLD brakes and holds position; ALT_HOLD holds depth and
  coasts (0.6-0.9 m from ~0.6 m/s, as measured on ArduSub).
- ATTITUDE, LOCAL_POSITION_NED and SYS_STATUS are silent until asked for with
  MAV_CMD_SET_MESSAGE_INTERVAL, so the bridge has to ask like it must on the radio.
- Not simulated: ACRO, AUTO, CIRCLE (refused), velocity/acceleration targets,
  parameters, missions, the GCS-heartbeat failsafe (off by default in ArduSub).

API
    sim = SimulatedVehicle("udpin:127.0.0.1:0")   # port 0: pick a free port; starts at
                                                  # START_STATE, the seabed of rov.seabed is its floor
    sim.start()                 # background thread; sim.bridge_url -> "udpout:127.0.0.1:PORT"
    sim.truth()                 # SimTruth(state, armed, mode, pilot, target): ground truth
    sim.stop()                  # or use `with SimulatedVehicle(...) as sim:`
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass

from rovlink.rov.ardusub import TYPEMASK_POSITION_IGNORE, TYPEMASK_YAW_IGNORE, mavlink
from rovlink.rov.mavurl import bound_port, open_mavlink, parse_mavlink_url
from rovlink.rov.seabed import SEABED_DEPTH_M
from rovlink.rov.vehicle import (
    FLOWN_MODES,
    NEUTRAL,
    POSITION_MODES,
    Controls,
    PilotInput,
    PositionTarget,
    SubMode,
    VehicleModel,
    VehicleState,
)

log = logging.getLogger(__name__)

MSG_HEARTBEAT = mavlink.MAVLINK_MSG_ID_HEARTBEAT
MSG_SYS_STATUS = mavlink.MAVLINK_MSG_ID_SYS_STATUS
MSG_SET_MODE = mavlink.MAVLINK_MSG_ID_SET_MODE
MSG_ATTITUDE = mavlink.MAVLINK_MSG_ID_ATTITUDE
MSG_LOCAL_POSITION_NED = mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED
CMD_DO_SET_MODE = mavlink.MAV_CMD_DO_SET_MODE
CMD_COMPONENT_ARM_DISARM = mavlink.MAV_CMD_COMPONENT_ARM_DISARM
CMD_SET_MESSAGE_INTERVAL = mavlink.MAV_CMD_SET_MESSAGE_INTERVAL
CMD_REQUEST_MESSAGE = mavlink.MAV_CMD_REQUEST_MESSAGE
MODE_FLAG_CUSTOM_MODE_ENABLED = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
ACCEPTED, UNSUPPORTED, FAILED = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_UNSUPPORTED, mavlink.MAV_RESULT_FAILED
IN_PROGRESS = mavlink.MAV_RESULT_IN_PROGRESS

PILOT_TIMEOUT_S = 3.0  # ArduSub's FS_PILOT_TIMEOUT default
# By default the vehicle starts 2 m above the simulated seabed, facing north, with
# the amphorae of `rov.seabed` in view ahead and the wreck to the north-west.
START_STATE = VehicleState(z_m=SEABED_DEPTH_M - 2.0)
TICK_S = 0.02
HEARTBEAT_INTERVAL_S = 1.0  # ArduSub's default stream rate
RANGE_INTERVAL_S = 1 / 3  # RANGEFINDER and DISTANCE_SENSOR: ArduSub streams them at 3 Hz unasked
RANGE_MAX_CM = 5000  # a Ping2's range: 50 m
STREAMABLE = (MSG_SYS_STATUS, MSG_ATTITUDE, MSG_LOCAL_POSITION_NED)


@dataclass(frozen=True)
class SimTruth:
    """What the simulator knows for sure (tests and the simulated camera use it)."""

    state: VehicleState
    armed: bool
    mode: int
    pilot: PilotInput
    target: PositionTarget | None


class SimulatedVehicle:
    def __init__(
        self,
        url: str = "udpin:127.0.0.1:0",
        *,
        system_id: int = 1,
        component_id: int = 1,
        initial_state: VehicleState | None = None,
        floor_depth_m: float | None = SEABED_DEPTH_M,
        has_position: bool = True,
        has_rangefinder: bool = True,
        position_after_s: float | None = 0.0,
        pilot_timeout_s: float = PILOT_TIMEOUT_S,
        mode: int = SubMode.MANUAL,
        arm_delay_s: float = 0.0,
    ) -> None:
        self._url = parse_mavlink_url(url)
        self.system_id = system_id
        self.component_id = component_id
        # When the position estimate comes (seconds after start), None: never.
        self.position_after_s = position_after_s if has_position else None
        self._position_override: bool | None = None
        # A downward echosounder (a Ping2) over the seabed at floor_depth_m: the altitude.
        self.has_rangefinder = has_rangefinder and floor_depth_m is not None
        self.floor_depth_m = floor_depth_m
        self.pilot_timeout_s = pilot_timeout_s
        # A vehicle that arms late (its checks or its motors take this long): ARM is
        # answered IN_PROGRESS at once, ACCEPTED when it is armed.  0: at once, as ArduSub.
        self.arm_delay_s = float(arm_delay_s)
        self._arming_at: float | None = None
        self._model = VehicleModel(state=initial_state or START_STATE, floor_depth_m=floor_depth_m)
        self._lock = threading.Lock()
        self._armed = False
        self._mode = int(mode)
        self._pilot = NEUTRAL
        self._target: PositionTarget | None = None
        self._last_pilot_s = -math.inf
        self._intervals_s: dict[int, float] = {}
        self._next_send_s: dict[int, float] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._conn = None
        self._boot_s = time.monotonic()
        self._heartbeat_interval_s = HEARTBEAT_INTERVAL_S
        self._last_gcs_s = -math.inf
        self._tcp_client = None
        self._tcp_client_since_s = 0.0
        self.port: int | None = None

    # --- lifecycle -----------------------------------------------------------

    def start(self) -> "SimulatedVehicle":
        """Open the endpoint and run the loop in a daemon thread."""
        if self._thread is not None:
            return self
        self._stop.clear()
        self._open()
        self._thread = threading.Thread(target=self._run, name="rov-sim", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)
        self._thread = None

    def __enter__(self) -> "SimulatedVehicle":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def bridge_url(self) -> str:
        """The URL a ground station (the bridge) uses to reach this simulator."""
        kind = self._url.kind
        host = self._url.host if self._url.host not in ("0.0.0.0", "") else "127.0.0.1"
        port = self.port or self._url.port
        return {"udpin": f"udpout:{host}:{port}", "udpout": f"udpin:{host}:{port}", "tcpin": f"tcp:{host}:{port}"}.get(
            kind, f"{kind}:{host}:{port}"
        )

    @property
    def position_available(self) -> bool:
        """The simulated EKF has a horizontal position now."""
        if self._position_override is not None:
            return self._position_override
        after = self.position_after_s
        return after is not None and self._now() - self._boot_s >= after

    @position_available.setter
    def position_available(self, value: bool) -> None:
        self._position_override = bool(value)

    def stream_intervals(self) -> dict[int, float]:
        """Message id -> seconds between sends, as ground stations asked (HEARTBEAT included)."""
        with self._lock:
            return {**self._intervals_s, MSG_HEARTBEAT: self._heartbeat_interval_s}

    def truth(self) -> SimTruth:
        with self._lock:
            return SimTruth(self._model.state, self._armed, self._mode, self._pilot, self._target)

    def set_state(self, state: VehicleState) -> None:
        """Teleport the vehicle (tests, demos)."""
        with self._lock:
            self._model.reset(state)

    # --- the loop ------------------------------------------------------------

    def _open(self) -> None:
        if self._conn is None:
            self._conn = open_mavlink(self._url, self.system_id, self.component_id)
            self.port = bound_port(self._conn) or self._url.port
            log.info("simulated ArduSub on %s (system %d)", self._url.device.replace(":0", f":{self.port}"), self.system_id)

    def _now(self) -> float:
        return time.monotonic()

    def _run(self) -> None:
        conn = self._conn
        last_step = self._now()
        next_tick = last_step
        next_heartbeat = last_step
        next_range = last_step
        try:
            while not self._stop.is_set():
                now = self._now()
                if now < next_tick:
                    try:
                        msg = conn.recv_match(blocking=True, timeout=next_tick - now)
                    except (OSError, ValueError) as exc:  # a broken peer must not end the simulator
                        log.debug("receive error: %s", exc)
                        msg = None
                        time.sleep(0.005)
                    if msg is not None:
                        self._handle(msg, self._now())
                    continue
                next_tick = max(next_tick + TICK_S, now)
                with self._lock:
                    self._model.step(now - last_step, self._controls())
                    last_step = now
                    self._check_pilot_failsafe(now)
                    arming = self._arming_at is not None and now >= self._arming_at
                if arming:
                    self._set_armed(True, now)
                    self._ack(CMD_COMPONENT_ARM_DISARM, ACCEPTED)
                    self._send_heartbeat()
                self._drop_silent_tcp_client(now)
                if now >= next_heartbeat:
                    next_heartbeat = now + self._heartbeat_interval_s
                    self._send_heartbeat()
                if self.has_rangefinder and now >= next_range:
                    next_range = now + RANGE_INTERVAL_S
                    self._send_range()
                self._send_streams(now)
        finally:
            try:
                conn.close()
            except OSError:
                pass
            self._conn = None

    def _drop_silent_tcp_client(self, now: float) -> None:
        """pymavlink's tcpin never notices a client that went away, and so never
        accepts the next one; after 5 s of silence let the next one in."""
        conn = self._conn
        if self._url.kind != "tcpin":
            return
        client = getattr(conn, "port", None)
        if client is not self._tcp_client:
            self._tcp_client, self._tcp_client_since_s = client, now
        if client is None or now - max(self._last_gcs_s, self._tcp_client_since_s) < 5.0:
            return
        try:
            conn.port.close()
        except OSError:
            pass
        conn.port = None
        conn.fd = conn.listen.fileno()
        log.info("TCP client silent for 5 s: waiting for the next one")

    def _controls(self) -> Controls:
        return Controls(pilot=self._pilot, mode=self._mode, armed=self._armed, target=self._target)

    def _check_pilot_failsafe(self, now: float) -> None:
        if self._armed and now - self._last_pilot_s > self.pilot_timeout_s:
            self._armed = False
            log.warning("no pilot input for %.1f s: disarmed", self.pilot_timeout_s)
            self._send_text(mavlink.MAV_SEVERITY_WARNING, "Lost manual control")

    # --- incoming ------------------------------------------------------------

    def _for_us(self, target_system: int) -> bool:
        return target_system in (0, self.system_id)

    def _handle(self, msg, now: float) -> None:
        kind = msg.get_type()
        if kind != "BAD_DATA":
            if now - self._last_gcs_s > 2.0:
                # A new (or returning) ground station: greet it at once rather than
                # at the next 1 Hz heartbeat, so it finds us without delay.
                self._last_gcs_s = now
                self._send_heartbeat()
            self._last_gcs_s = now
        try:
            if kind == "MANUAL_CONTROL":
                if msg.target == self.system_id:
                    pilot = PilotInput(int(msg.x), int(msg.y), int(msg.z), int(msg.r)).clamped()
                    with self._lock:
                        self._pilot = pilot
                        self._last_pilot_s = now
            elif kind == "COMMAND_LONG":
                if self._for_us(msg.target_system):
                    self._command_long(msg, now)
            elif kind == "SET_MODE":
                if self._for_us(msg.target_system):
                    ok = bool(msg.base_mode & MODE_FLAG_CUSTOM_MODE_ENABLED) and self._set_mode(int(msg.custom_mode))
                    self._ack(MSG_SET_MODE, ACCEPTED if ok else FAILED)
                    if ok:
                        self._send_heartbeat()
            elif kind == "SET_POSITION_TARGET_LOCAL_NED":
                if self._for_us(msg.target_system):
                    self._position_target(msg)
        except (TypeError, ValueError, OverflowError) as exc:
            log.warning("ignored malformed %s: %s", kind, exc)

    def _set_armed(self, arm: bool, now: float) -> None:
        with self._lock:
            if arm and not self._armed:
                # A grace period from arming on: the pilot gets 3 s to start
                # sending MANUAL_CONTROL before the failsafe disarms again.
                self._last_pilot_s = max(self._last_pilot_s, now)
            self._armed = arm
            self._arming_at = None  # a disarm calls off an arming under way
        log.info("%s", "armed" if arm else "disarmed")

    def _command_long(self, msg, now: float) -> None:
        cmd = int(msg.command)
        try:
            self._command(cmd, msg, now)
        except (TypeError, ValueError, OverflowError) as exc:  # NaN or absurd parameters
            log.info("refused command %d: %s", cmd, exc)
            self._ack(cmd, 4)

    def _command(self, cmd: int, msg, now: float) -> None:
        if cmd == CMD_COMPONENT_ARM_DISARM:
            if msg.param1 not in (0.0, 1.0):
                self._ack(cmd, UNSUPPORTED)  # like ArduPilot: only exactly 1 (arm) or 0 (disarm)
                return
            arm = msg.param1 == 1.0
            if arm and self.arm_delay_s > 0 and not self._armed:
                with self._lock:
                    if self._arming_at is None:
                        self._arming_at = now + self.arm_delay_s
                log.info("arming in %.1f s", self.arm_delay_s)
                self._ack(cmd, IN_PROGRESS)
                return
            self._set_armed(arm, now)
            self._ack(cmd, ACCEPTED)
        elif cmd == CMD_DO_SET_MODE:
            ok = (int(msg.param1) & MODE_FLAG_CUSTOM_MODE_ENABLED) and self._set_mode(int(msg.param2))
            self._ack(cmd, ACCEPTED if ok else FAILED)
            if ok:  # ArduSub sends the new mode at once, not at the next beat
                self._send_heartbeat()
        elif cmd == CMD_SET_MESSAGE_INTERVAL:
            msg_id, interval_us = int(msg.param1), float(msg.param2)
            if msg_id not in STREAMABLE and msg_id != MSG_HEARTBEAT:
                self._ack(cmd, FAILED)
                return
            with self._lock:
                if msg_id == MSG_HEARTBEAT:
                    self._heartbeat_interval_s = (
                        max(interval_us * 1e-6, TICK_S) if interval_us > 0 else HEARTBEAT_INTERVAL_S
                    )
                elif interval_us <= 0:  # -1 disables; 0 means "default", which is off here
                    self._intervals_s.pop(msg_id, None)
                else:
                    self._intervals_s[msg_id] = max(interval_us * 1e-6, TICK_S)
                    self._next_send_s[msg_id] = now
            self._ack(cmd, ACCEPTED)
        elif cmd == CMD_REQUEST_MESSAGE:
            msg_id = int(msg.param1)
            if msg_id in STREAMABLE or msg_id == MSG_HEARTBEAT:
                self._ack(cmd, ACCEPTED)
                self._send_message(msg_id)
            else:
                self._ack(cmd, FAILED)
        else:
            self._ack(cmd, UNSUPPORTED)

    def _set_mode(self, custom_mode: int) -> bool:
        try:
            mode = SubMode(custom_mode)
        except ValueError:
            log.info("refused unknown mode %d", custom_mode)
            return False
        if mode not in FLOWN_MODES:
            log.info("refused mode %s: not simulated", mode.name)
            return False
        if mode in POSITION_MODES and not self.position_available:
            log.info("refused mode %s: no position estimate", mode.name)
            self._send_text(mavlink.MAV_SEVERITY_WARNING, f"{mode.name} requires position")
            return False
        with self._lock:
            if mode != self._mode:
                self._target = None
            self._mode = int(mode)
        log.info("mode %s", mode.name)
        return True

    def _position_target(self, msg) -> None:
        with self._lock:
            if self._mode != SubMode.GUIDED:
                return  # ArduSub ignores targets outside GUIDED, without an answer
            if msg.type_mask & TYPEMASK_POSITION_IGNORE:
                return  # velocity/acceleration targets: not simulated
            values = (msg.x, msg.y, msg.z, msg.yaw)
            if not all(math.isfinite(v) for v in values):
                return
            s = self._model.state
            x, y, z = float(msg.x), float(msg.y), float(msg.z)
            frame = int(msg.coordinate_frame)
            if frame in (mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED):
                c, sn = math.cos(s.yaw_rad), math.sin(s.yaw_rad)
                x, y = c * x - sn * y, sn * x + c * y
            if frame in (mavlink.MAV_FRAME_LOCAL_OFFSET_NED, mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED):
                x, y, z = s.x_m + x, s.y_m + y, s.z_m + z
            elif frame != mavlink.MAV_FRAME_LOCAL_NED:
                return
            yaw = None if msg.type_mask & TYPEMASK_YAW_IGNORE else float(msg.yaw)
            if yaw is not None and frame == mavlink.MAV_FRAME_BODY_OFFSET_NED:
                yaw = s.yaw_rad + yaw
            self._target = PositionTarget(x, y, max(z, 0.0), yaw)

    # --- outgoing ------------------------------------------------------------

    def _time_boot_ms(self) -> int:
        return int((self._now() - self._boot_s) * 1000) & 0xFFFFFFFF

    def _ack(self, command: int, result: int) -> None:
        self._conn.mav.command_ack_send(command, result)

    def _send_text(self, severity: int, text: str) -> None:
        self._conn.mav.statustext_send(severity, text.encode()[:50])

    def _send_heartbeat(self) -> None:
        with self._lock:
            armed, mode = self._armed, self._mode
        base = (
            MODE_FLAG_CUSTOM_MODE_ENABLED
            | mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
            | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
        )
        self._conn.mav.heartbeat_send(
            mavlink.MAV_TYPE_SUBMARINE, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, base, mode,
            mavlink.MAV_STATE_ACTIVE if armed else mavlink.MAV_STATE_STANDBY,
        )

    def _send_streams(self, now: float) -> None:
        for msg_id, interval in list(self._intervals_s.items()):
            if now >= self._next_send_s.get(msg_id, now):
                # Keep the cadence but never try to catch up on missed slots.
                self._next_send_s[msg_id] = max(self._next_send_s.get(msg_id, now) + interval, now)
                self._send_message(msg_id)

    def slant_range_m(self) -> float:
        """What the downward echosounder measures: along the body's down axis to the seabed."""
        with self._lock:
            s = self._model.state
        cos_tilt = math.cos(s.roll_rad) * math.cos(s.pitch_rad)
        return max(0.0, self.floor_depth_m - s.z_m) / max(cos_tilt, 0.2)

    def _send_range(self) -> None:
        """RANGEFINDER and DISTANCE_SENSOR, as ArduSub sends them for its first rangefinder."""
        range_m = self.slant_range_m()
        mav = self._conn.mav
        mav.rangefinder_send(range_m, 0.0)
        mav.distance_sensor_send(self._time_boot_ms(), 20, RANGE_MAX_CM, min(int(round(range_m * 100)), 65535),
                                 mavlink.MAV_DISTANCE_SENSOR_ULTRASOUND, 0, mavlink.MAV_SENSOR_ROTATION_PITCH_270, 0)

    def _send_message(self, msg_id: int) -> None:
        with self._lock:
            s = self._model.state
        mav = self._conn.mav
        if msg_id == MSG_HEARTBEAT:
            self._send_heartbeat()
        elif msg_id == MSG_ATTITUDE:
            mav.attitude_send(self._time_boot_ms(), s.roll_rad, s.pitch_rad, s.yaw_rad, 0.0, 0.0, s.yaw_rate_radps)
        elif msg_id == MSG_LOCAL_POSITION_NED:
            if self.position_available:
                mav.local_position_ned_send(self._time_boot_ms(), s.x_m, s.y_m, s.z_m, s.vn_mps, s.ve_mps, s.vd_mps)
        elif msg_id == MSG_SYS_STATUS:
            # gyro|accel|mag|pressure(depth)|motor outputs; battery 16 V, 50 %.
            sensors = (
                mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
                | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
                | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
                | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
                | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
            )
            mav.sys_status_send(sensors, sensors, sensors, 150, 16000, 200, 50, 0, 0, 0, 0, 0, 0)
