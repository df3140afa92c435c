"""The bridge from the ROV node to ArduSub, over MAVLink with pymavlink.

Goals
- Turn the node's wishes (velocity, arm, mode, position orders, stop, failsafe)
  into what ArduSub understands, and ArduSub's telemetry into one small snapshot
  the node can put in its reply.  MAVLink stays on the ROV: it is far too heavy for
  the radio, so we ask the autopilot only for what the link needs.
- Never block the caller, never crash on bad input, survive the autopilot going
  away and coming back.  The same code drives the real vehicle (BlueOS
  `udpin:0.0.0.0:14550`, SITL `tcp:127.0.0.1:5760`, a serial device) and the
  simulator in `rov.simulator`.

Plan
- One I/O thread owns the pymavlink connection; the public methods only take a
  lock, record a wish or queue a request, and return.  The thread acts as a ground
  station (system id 255 by default): HEARTBEAT at 1 Hz; MAV_CMD_SET_MESSAGE_INTERVAL
  for ATTITUDE, LOCAL_POSITION_NED and SYS_STATUS (asked again when a stream goes
  quiet); MANUAL_CONTROL from the current velocity wish at 10 Hz whatever the radio
  does, since ArduSub disarms after 3 s without pilot input.
- Armed state and mode are read from the autopilot's HEARTBEAT, never assumed.
  Requests (arm, mode) go out as COMMAND_LONG, are resent every 0.5 s until
  answered by COMMAND_ACK (or seen in the HEARTBEAT), and resolve a `Ticket` the
  node can poll; without an answer within 5 s they fail.  A newer request of the
  same kind cancels the older one.
- A position order switches to GUIDED (if needed), resolves relative and body-frame
  offsets against the latest pose, and sends SET_POSITION_TARGET_LOCAL_NED
  (position and yaw, resent every second) once GUIDED is acknowledged.  ArduSub
  does not acknowledge targets, so "accepted" means: GUIDED confirmed and the
  target sent; a refused GUIDED (no position estimate) fails the order.  The order
  ends with STOP, another mode request, a newer order, or when the autopilot leaves
  GUIDED by itself.
- No HEARTBEAT for 3 s: AUTOPILOT is reported lost, and the connection is closed
  and reopened with a growing backoff (0.5 s doubling to 8 s), as is any
  connection that fails to open or breaks.

API (all methods thread-safe and non-blocking, safe to call from asyncio code)
    bridge = AutopilotBridge("udpin:0.0.0.0:14550", gcs_system_id=255)
    bridge.start() / bridge.stop()       # or `with AutopilotBridge(url) as bridge:`
    bridge.set_velocity(vx, vy, vz, vyaw) # floats -1..1, fraction of max; body frame:
                                          # x forward, y right, z down, yaw clockwise.
                                          # Out of range clamped, NaN -> 0.
    bridge.request_arm(True|False) -> Ticket
    bridge.request_mode("DEPTH_HOLD" | 3 | SubMode.ALT_HOLD) -> Ticket
        names MANUAL, STABILIZE, DEPTH_HOLD, POS_HOLD, GUIDED, SURFACE (also ArduSub's
        ALT_HOLD, POSHOLD); ints 1..6 are the protocol's MODE numbers; a SubMode is
        ArduSub's own number.  Anything else raises ValueError (a caller's bug).
    bridge.goto(x_m, y_m, z_m, yaw_rad=None, relative=False, body=False) -> GotoTicket
        absolute: local NED; relative: offsets from the current pose (yaw too);
        body (with relative): the x/y offset is in the vehicle's frame, else NED.
        yaw None keeps the heading.
        Non-finite numbers: failed at once; a relative order without a valid
        position: failed by the I/O thread (within ~20 ms).
    bridge.stop_motion() -> Ticket       # the protocol's STOP: neutral velocity,
                                          # cancel any position order, ALT_HOLD.
    bridge.failsafe(active)               # link lost: stop_motion() once, then hold
                                          # neutral velocity until failsafe(False).
    bridge.snapshot() -> AutopilotSnapshot   # frozen; see its fields.
  Ticket.status is "pending", "accepted", "failed" or "cancelled"; .reason says why;
  .done once it is not pending; .wait(timeout_s) blocks (threads and tests only).
  GotoTicket adds .target (the resolved absolute target) and .reached.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import math
import threading
import time
from dataclasses import dataclass

from rovlink.rov.mavurl import open_mavlink, parse_mavlink_url
from rovlink.rov.vehicle import PilotInput, SubMode, wrap_angle

log = logging.getLogger(__name__)

# The protocol's MODE numbers (PROTOCOL.md §2 VELOCITY, §5 reply) and ArduSub's.
PROTOCOL_TO_SUB = {
    1: SubMode.MANUAL,
    2: SubMode.STABILIZE,
    3: SubMode.ALT_HOLD,
    4: SubMode.POSHOLD,
    5: SubMode.GUIDED,
    6: SubMode.SURFACE,
}
SUB_TO_PROTOCOL = {int(sub): proto for proto, sub in PROTOCOL_TO_SUB.items()}
PROTOCOL_MODE_OTHER = 7
PROTOCOL_MODE_UNKNOWN = 0
MODE_NAMES = {
    "MANUAL": SubMode.MANUAL,
    "STABILIZE": SubMode.STABILIZE,
    "DEPTH_HOLD": SubMode.ALT_HOLD,
    "ALT_HOLD": SubMode.ALT_HOLD,
    "POS_HOLD": SubMode.POSHOLD,
    "POSHOLD": SubMode.POSHOLD,
    "GUIDED": SubMode.GUIDED,
    "SURFACE": SubMode.SURFACE,
}

# MAVLink numbers (common dialect).
MAV_TYPE_GCS = 6
MAV_AUTOPILOT_INVALID = 8
MAV_STATE_ACTIVE = 4
MAV_COMP_ID_MISSIONPLANNER = 190
MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MODE_FLAG_SAFETY_ARMED = 128
CMD_DO_SET_MODE = 176
CMD_COMPONENT_ARM_DISARM = 400
CMD_SET_MESSAGE_INTERVAL = 511
FRAME_LOCAL_NED = 1
TYPEMASK_POSITION_AND_YAW = 0b0000_1001_1111_1000  # ignore velocity, accel, yaw rate
TYPEMASK_YAW_IGNORE = 1024
MAV_RESULT_NAMES = {0: "accepted", 1: "temporarily rejected", 2: "denied", 3: "unsupported", 4: "failed", 5: "in progress"}

MSG_IDS = {"ATTITUDE": 30, "LOCAL_POSITION_NED": 32, "SYS_STATUS": 1}

HEARTBEAT_PERIOD_S = 1.0
MANUAL_CONTROL_PERIOD_S = 0.1  # 10 Hz: twice the 5 Hz ArduSub needs to feel "fed"
MANUAL_CONTROL_MIN_GAP_S = 0.02  # a changed wish goes out at once, but not faster than this
HEARTBEAT_TIMEOUT_S = 3.0
POSITION_TIMEOUT_S = 2.0
COMMAND_RESEND_S = 0.5
COMMAND_DEADLINE_S = 5.0
REACHED_DISTANCE_M = 0.3
REACHED_YAW_RAD = math.radians(10)
BACKOFF_FIRST_S = 0.5
BACKOFF_MAX_S = 8.0


def protocol_mode(custom_mode: int | None) -> int:
    """The protocol's reported MODE for an ArduSub custom mode (None: unknown)."""
    if custom_mode is None:
        return PROTOCOL_MODE_UNKNOWN
    return SUB_TO_PROTOCOL.get(int(custom_mode), PROTOCOL_MODE_OTHER)


def sub_mode(mode: str | int | SubMode) -> SubMode:
    """ArduSub's mode for a protocol name, a protocol number or a SubMode."""
    if isinstance(mode, SubMode):
        return mode
    if isinstance(mode, str):
        key = mode.strip().upper().replace("-", "_").replace(" ", "_")
        if key in MODE_NAMES:
            return MODE_NAMES[key]
        raise ValueError(f"unknown mode name {mode!r}; expected one of {', '.join(MODE_NAMES)}")
    if isinstance(mode, int) and not isinstance(mode, bool) and mode in PROTOCOL_TO_SUB:
        return PROTOCOL_TO_SUB[mode]
    raise ValueError(f"unknown mode {mode!r}; expected a protocol mode 1..6 or a name")


@dataclass(frozen=True)
class AutopilotSnapshot:
    """What the node reports: the autopilot's own view, never the bridge's wishes."""

    x_m: float = 0.0  # local NED: north
    y_m: float = 0.0  # east
    z_m: float = 0.0  # down (depth)
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    yaw_rad: float = 0.0  # 0 north, clockwise positive
    vx_mps: float = 0.0  # NED velocities from LOCAL_POSITION_NED
    vy_mps: float = 0.0
    vz_mps: float = 0.0
    yaw_rate_radps: float = 0.0
    armed: bool = False  # HEARTBEAT base_mode SAFETY_ARMED; False while the autopilot is lost
    custom_mode: int | None = None  # ArduSub's mode number, None until known
    mode: int = PROTOCOL_MODE_UNKNOWN  # the protocol's MODE 0..7
    autopilot_alive: bool = False  # a HEARTBEAT within the last 3 s
    position_valid: bool = False  # LOCAL_POSITION_NED within the last 2 s
    connected: bool = False  # the MAVLink connection is open
    failsafe: bool = False  # failsafe(True) in force
    battery_v: float | None = None
    updated_s: float = 0.0  # time.monotonic() of the last telemetry received
    status_text: str = ""  # the autopilot's last STATUSTEXT


class Ticket:
    """A request the node can poll.  Resolved once by the I/O thread."""

    PENDING, ACCEPTED, FAILED, CANCELLED = "pending", "accepted", "failed", "cancelled"

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self._status = Ticket.PENDING
        self._reason = ""
        self._event = threading.Event()

    @property
    def status(self) -> str:
        return self._status

    @property
    def reason(self) -> str:
        return self._reason

    @property
    def done(self) -> bool:
        return self._status != Ticket.PENDING

    @property
    def ok(self) -> bool:
        return self._status == Ticket.ACCEPTED

    def wait(self, timeout_s: float | None = None) -> str:
        """Block until resolved (not for the asyncio loop: poll `.status` there)."""
        self._event.wait(timeout_s)
        return self._status

    def _resolve(self, status: str, reason: str = "") -> bool:
        if self._status != Ticket.PENDING:
            return False
        self._reason = reason
        self._status = status
        self._event.set()
        if status == Ticket.FAILED:
            log.warning("%s failed: %s", self.kind, reason)
        return True

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.kind} {self._status}{': ' + self._reason if self._reason else ''}>"


class GotoTicket(Ticket):
    def __init__(self, kind: str) -> None:
        super().__init__(kind)
        self.target: tuple[float, float, float, float | None] | None = None  # x, y, z m, yaw rad
        self.reached = False


@dataclass
class _Request:
    """A COMMAND_LONG in flight."""

    ticket: Ticket
    command: int
    params: tuple[float, ...]
    created_s: float
    sent_s: float = -math.inf
    sends: int = 0
    acked: bool = False
    want_mode: int | None = None  # resolve when the HEARTBEAT shows this mode
    want_armed: bool | None = None


@dataclass
class _Goto:
    ticket: GotoTicket
    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float | None
    relative: bool
    body: bool
    created_s: float
    mode_request: _Request | None = None
    target_sent_s: float = -math.inf
    seen_guided: bool = False


class AutopilotBridge:
    def __init__(
        self,
        url: str,
        *,
        gcs_system_id: int = 255,
        gcs_component_id: int = MAV_COMP_ID_MISSIONPLANNER,
        target_system: int | None = None,
        telemetry_hz: float = 10.0,
    ) -> None:
        self.url = parse_mavlink_url(url)  # ValueError now rather than in the thread
        if not 1 <= int(gcs_system_id) <= 255:
            raise ValueError("gcs_system_id must be 1..255")
        self.gcs_system_id = int(gcs_system_id)
        self.gcs_component_id = int(gcs_component_id)
        self._fixed_target = target_system
        self.telemetry_interval_s = 1.0 / max(0.5, min(float(telemetry_hz), 50.0))
        self._lock = threading.Lock()
        self._stop_event = threading.Event()
        self._thread: threading.Thread | None = None
        self._snap = AutopilotSnapshot()
        self._pilot = PilotInput()
        self._pilot_changed = False
        self._last_manual_s = -math.inf
        self._failsafe = False
        self._queue: collections.deque = collections.deque()
        # I/O-thread state below (touched only by the thread, or under the lock)
        self._conn = None
        self._target_system = target_system if target_system is not None else 1
        self._target_component = 1
        self._last_heartbeat_s = -math.inf
        self._last_position_s = -math.inf
        self._last_seen_s: dict[str, float] = {}
        self._stream_asked_s: dict[str, float] = {}
        self._requests: list[_Request] = []
        self._goto: _Goto | None = None
        self._opened_s = 0.0
        self._backoff_s = BACKOFF_FIRST_S
        self._reopen_at_s = 0.0
        self._next_heartbeat_s = 0.0
        self._next_manual_s = 0.0
        self.manual_controls_sent = 0  # counters for tests and diagnostics
        self.reconnects = 0

    # --- lifecycle -------------------------------------------------------------

    def start(self) -> "AutopilotBridge":
        if self._thread is None:
            self._stop_event.clear()
            self._thread = threading.Thread(target=self._run, name="rov-autopilot", daemon=True)
            self._thread.start()
        return self

    def stop(self, timeout_s: float = 3.0) -> None:
        self._stop_event.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout_s)

    def __enter__(self) -> "AutopilotBridge":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # --- the node's API -------------------------------------------------------

    def set_velocity(self, vx: float, vy: float, vz: float, vyaw: float) -> None:
        try:
            pilot = PilotInput.from_velocity(vx, vy, vz, vyaw)
        except (TypeError, ValueError):
            log.warning("ignored bad velocity wish %r", (vx, vy, vz, vyaw))
            return
        with self._lock:
            if not self._failsafe:
                self._set_pilot(pilot)

    def request_arm(self, arm: bool) -> Ticket:
        ticket = Ticket("arm" if arm else "disarm")
        with self._lock:
            self._queue.append(("arm", bool(arm), ticket))
        return ticket

    def request_mode(self, mode: str | int | SubMode) -> Ticket:
        target = sub_mode(mode)
        ticket = Ticket(f"mode {target.name}")
        with self._lock:
            self._queue.append(("mode", target, ticket))
        return ticket

    def goto(
        self,
        x_m: float,
        y_m: float,
        z_m: float,
        yaw_rad: float | None = None,
        relative: bool = False,
        body: bool = False,
    ) -> GotoTicket:
        ticket = GotoTicket("goto")
        try:
            values = [float(x_m), float(y_m), float(z_m)] + ([] if yaw_rad is None else [float(yaw_rad)])
        except (TypeError, ValueError):
            values = [math.nan]
        if not all(math.isfinite(v) for v in values):
            ticket._resolve(Ticket.FAILED, "target is not a finite number")
            return ticket
        order = _Goto(
            ticket, float(x_m), float(y_m), float(z_m), None if yaw_rad is None else float(yaw_rad),
            bool(relative), bool(body), time.monotonic(),
        )
        with self._lock:
            self._set_pilot(PilotInput())  # a position order replaces the velocity wish
            self._queue.append(("goto", order, ticket))
        return ticket

    def stop_motion(self) -> Ticket:
        ticket = Ticket("stop")
        with self._lock:
            self._set_pilot(PilotInput())
            self._queue.append(("stop", None, ticket))
        return ticket

    def failsafe(self, active: bool) -> None:
        with self._lock:
            was, self._failsafe = self._failsafe, bool(active)
            self._snap = dataclasses.replace(self._snap, failsafe=self._failsafe)
        if active and not was:
            log.warning("failsafe: stopping and holding depth")
            self.stop_motion()
        elif was and not active:
            log.info("failsafe cleared")

    def _set_pilot(self, pilot: PilotInput) -> None:
        """Under the lock: a changed wish goes out at once, not at the next 10 Hz slot,
        so that a stop reaches the autopilot before the mode change that follows it."""
        if pilot != self._pilot:
            self._pilot = pilot
            self._pilot_changed = True

    def snapshot(self) -> AutopilotSnapshot:
        now = time.monotonic()
        with self._lock:
            snap = self._snap
            alive = now - self._last_heartbeat_s < HEARTBEAT_TIMEOUT_S
            position_valid = alive and now - self._last_position_s < POSITION_TIMEOUT_S
        if alive:
            return dataclasses.replace(snap, autopilot_alive=True, position_valid=position_valid)
        # Without a fresh heartbeat we know nothing about arming or mode.
        return dataclasses.replace(
            snap, autopilot_alive=False, position_valid=False, armed=False,
            custom_mode=None, mode=PROTOCOL_MODE_UNKNOWN,
        )

    # --- the I/O thread ---------------------------------------------------------

    def _run(self) -> None:
        try:
            while not self._stop_event.is_set():
                now = time.monotonic()
                if self._conn is None:
                    if now < self._reopen_at_s:
                        self._stop_event.wait(min(self._reopen_at_s - now, 0.1))
                        self._expire_requests(now)
                        continue
                    self._open(now)
                    continue
                try:
                    msg = self._conn.recv_match(blocking=True, timeout=0.02)
                except Exception as exc:  # serial unplugged, socket error, parser trouble
                    self._drop(f"receive failed: {exc}")
                    continue
                now = time.monotonic()
                if msg is not None:
                    try:
                        self._handle(msg, now)
                    except Exception:  # a malformed message must not stop the bridge
                        log.exception("error handling %s", msg.get_type())
                try:
                    self._periodic(now)
                except OSError as exc:
                    self._drop(f"send failed: {exc}")
        finally:
            self._send_neutral()
            self._close()
            self._cancel_all("bridge stopped")

    def _send_neutral(self) -> None:
        """On the way out: leave the vehicle with neutral sticks rather than coasting
        on the last wish until ArduSub's 3 s pilot-input failsafe."""
        if self._conn is None:
            return
        try:
            for _ in range(2):  # two datagrams: one loss must not leave the stick deflected
                self._conn.mav.manual_control_send(self._target_system, 0, 0, 500, 0, 0)
        except Exception as exc:
            log.debug("could not send the final neutral input: %s", exc)

    def _open(self, now: float) -> None:
        try:
            self._conn = open_mavlink(self.url, self.gcs_system_id, self.gcs_component_id)
        except Exception as exc:
            log.warning("cannot open %s: %s; retrying in %.1f s", self.url.device, exc, self._backoff_s)
            self._schedule_reopen(now)
            return
        log.info("MAVLink connection open: %s", self.url.device)
        self._opened_s = now
        self._next_heartbeat_s = now
        self._next_manual_s = now
        self._last_seen_s.clear()
        self._stream_asked_s.clear()
        with self._lock:
            self._snap = dataclasses.replace(self._snap, connected=True)

    def _schedule_reopen(self, now: float) -> None:
        self._reopen_at_s = now + self._backoff_s
        self._backoff_s = min(self._backoff_s * 2.0, BACKOFF_MAX_S)

    def _close(self) -> None:
        conn, self._conn = self._conn, None
        if conn is not None:
            try:
                conn.close()
            except Exception:
                pass
        with self._lock:
            self._snap = dataclasses.replace(self._snap, connected=False)

    def _drop(self, why: str) -> None:
        log.warning("%s: closing %s, reopening in %.1f s", why, self.url.device, self._backoff_s)
        self._close()
        self.reconnects += 1
        self._schedule_reopen(time.monotonic())

    # incoming

    def _from_autopilot(self, msg) -> bool:
        return msg.get_srcSystem() == self._target_system

    def _handle(self, msg, now: float) -> None:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self._on_heartbeat(msg, now)
            return
        if kind == "BAD_DATA" or not self._from_autopilot(msg):
            return
        self._last_seen_s[kind] = now
        if kind == "ATTITUDE":
            with self._lock:
                self._snap = dataclasses.replace(
                    self._snap, roll_rad=float(msg.roll), pitch_rad=float(msg.pitch),
                    yaw_rad=float(msg.yaw), yaw_rate_radps=float(msg.yawspeed), updated_s=now,
                )
        elif kind == "LOCAL_POSITION_NED":
            values = (msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz)
            if all(math.isfinite(v) for v in values):
                with self._lock:
                    self._last_position_s = now
                    self._snap = dataclasses.replace(
                        self._snap, x_m=float(msg.x), y_m=float(msg.y), z_m=float(msg.z),
                        vx_mps=float(msg.vx), vy_mps=float(msg.vy), vz_mps=float(msg.vz), updated_s=now,
                    )
        elif kind == "SYS_STATUS":
            volts = None if msg.voltage_battery in (0, 0xFFFF) else msg.voltage_battery / 1000.0
            with self._lock:
                self._snap = dataclasses.replace(self._snap, battery_v=volts, updated_s=now)
        elif kind == "COMMAND_ACK":
            self._on_ack(msg)
        elif kind == "STATUSTEXT":
            text = msg.text if isinstance(msg.text, str) else bytes(msg.text).decode(errors="replace")
            text = text.rstrip("\x00")
            log.info("autopilot says: %s", text)
            with self._lock:
                self._snap = dataclasses.replace(self._snap, status_text=text)

    def _on_heartbeat(self, msg, now: float) -> None:
        if msg.type == MAV_TYPE_GCS or msg.autopilot == MAV_AUTOPILOT_INVALID:
            return  # another ground station, or a companion component
        system = msg.get_srcSystem()
        if self._fixed_target is not None and system != self._fixed_target:
            return
        if now - self._last_heartbeat_s >= HEARTBEAT_TIMEOUT_S or system != self._target_system:
            log.info("autopilot found: system %d component %d", system, msg.get_srcComponent())
            self._stream_asked_s.clear()  # a (re)found autopilot gets asked for streams
        self._target_system = system
        self._target_component = msg.get_srcComponent()
        self._last_heartbeat_s = now
        self._backoff_s = BACKOFF_FIRST_S
        armed = bool(msg.base_mode & MODE_FLAG_SAFETY_ARMED)
        custom = int(msg.custom_mode) if msg.base_mode & MODE_FLAG_CUSTOM_MODE_ENABLED else None
        with self._lock:
            if armed != self._snap.armed:
                log.info("autopilot %s", "armed" if armed else "disarmed")
            if custom != self._snap.custom_mode:
                log.info("autopilot mode %s", _mode_name(custom))
            self._snap = dataclasses.replace(
                self._snap, armed=armed, custom_mode=custom, mode=protocol_mode(custom), updated_s=now
            )
        self._check_requests(now)

    def _on_ack(self, msg) -> None:
        command, result = int(msg.command), int(msg.result)
        if command == CMD_SET_MESSAGE_INTERVAL and result != 0:
            log.warning("autopilot refused a message interval: %s", MAV_RESULT_NAMES.get(result, result))
        for request in list(self._requests):
            if request.command != command or request.acked:
                continue
            if result == 0:
                # ArduSub acknowledges after the change took effect; the HEARTBEAT
                # that shows it may come a second later (and the snapshot waits for it).
                request.acked = True
                request.ticket._resolve(Ticket.ACCEPTED)
                self._requests.remove(request)
            elif result == 5:  # in progress: keep waiting
                request.acked = True
            else:
                request.ticket._resolve(Ticket.FAILED, f"autopilot answered {MAV_RESULT_NAMES.get(result, result)}")
                self._requests.remove(request)
            break
        self._check_requests(time.monotonic())

    def _check_requests(self, now: float) -> None:
        """Resolve requests whose effect the HEARTBEAT now shows."""
        with self._lock:
            snap = self._snap
        for request in list(self._requests):
            done = (request.want_mode is not None and snap.custom_mode == request.want_mode) or (
                request.want_armed is not None and snap.armed == request.want_armed
            )
            if done and (request.acked or request.sends > 0):
                request.ticket._resolve(Ticket.ACCEPTED)
                self._requests.remove(request)

    # outgoing

    def _periodic(self, now: float) -> None:
        conn = self._conn
        alive = now - self._last_heartbeat_s < HEARTBEAT_TIMEOUT_S
        if not alive and now - max(self._last_heartbeat_s, self._opened_s) >= HEARTBEAT_TIMEOUT_S:
            with self._lock:
                was_known = self._snap.custom_mode is not None
            if was_known or self._last_heartbeat_s > self._opened_s:
                log.warning("autopilot heartbeat lost")
            self._drop("no heartbeat for %.0f s" % HEARTBEAT_TIMEOUT_S)
            return
        if now >= self._next_heartbeat_s:
            self._next_heartbeat_s = now + HEARTBEAT_PERIOD_S
            conn.mav.heartbeat_send(MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID, 0, 0, MAV_STATE_ACTIVE)
        with self._lock:
            changed = self._pilot_changed and now - self._last_manual_s >= MANUAL_CONTROL_MIN_GAP_S
            if now >= self._next_manual_s or changed:
                pilot = PilotInput() if self._failsafe else self._pilot
                self._pilot_changed = False
            else:
                pilot = None
        if pilot is not None:
            self._next_manual_s = max(self._next_manual_s + MANUAL_CONTROL_PERIOD_S, now - MANUAL_CONTROL_PERIOD_S)
            self._last_manual_s = now
            conn.mav.manual_control_send(self._target_system, pilot.x, pilot.y, pilot.z, pilot.r, 0)
            self.manual_controls_sent += 1
        if alive:
            self._ask_streams(now)
        self._take_queue(now)
        self._drive_goto(now)
        self._send_requests(now)
        self._expire_requests(now)

    def _ask_streams(self, now: float) -> None:
        rates = {
            "ATTITUDE": self.telemetry_interval_s,
            "LOCAL_POSITION_NED": self.telemetry_interval_s,
            "SYS_STATUS": 1.0,
        }
        for name, interval_s in rates.items():
            quiet_s = now - max(self._last_seen_s.get(name, -math.inf), self._stream_asked_s.get(name, -math.inf))
            if quiet_s > 3 * interval_s + 1.0:
                self._stream_asked_s[name] = now
                self._command(CMD_SET_MESSAGE_INTERVAL, (MSG_IDS[name], interval_s * 1e6, 0, 0, 0, 0, 0))

    def _command(self, command: int, params: tuple[float, ...]) -> None:
        self._conn.mav.command_long_send(self._target_system, self._target_component, command, 0, *params)

    def _take_queue(self, now: float) -> None:
        while True:
            with self._lock:
                if not self._queue:
                    return
                kind, value, ticket = self._queue.popleft()
            if kind == "arm":
                self._supersede("arm")
                self._add_request(ticket, CMD_COMPONENT_ARM_DISARM, (1.0 if value else 0.0,), now, want_armed=value)
            elif kind == "mode":
                self._cancel_goto("another mode was requested")
                self._request_mode(ticket, value, now)
            elif kind == "stop":
                self._cancel_goto("stopped")
                self._request_mode(ticket, SubMode.ALT_HOLD, now)
            elif kind == "goto":
                self._cancel_goto("replaced by a newer position order")
                self._goto = value

    def _request_mode(self, ticket: Ticket, mode: SubMode, now: float) -> _Request:
        self._supersede("mode")
        return self._add_request(
            ticket, CMD_DO_SET_MODE, (float(MODE_FLAG_CUSTOM_MODE_ENABLED), float(mode)), now, want_mode=int(mode)
        )

    def _add_request(self, ticket, command, params, now, want_mode=None, want_armed=None) -> _Request:
        params = tuple(params) + (0.0,) * (7 - len(params))
        request = _Request(ticket, command, params, now, want_mode=want_mode, want_armed=want_armed)
        self._requests.append(request)
        return request

    def _supersede(self, what: str) -> None:
        command = CMD_COMPONENT_ARM_DISARM if what == "arm" else CMD_DO_SET_MODE
        for request in list(self._requests):
            if request.command == command:
                request.ticket._resolve(Ticket.CANCELLED, "superseded by a newer request")
                self._requests.remove(request)

    def _send_requests(self, now: float) -> None:
        if now - self._last_heartbeat_s >= HEARTBEAT_TIMEOUT_S:
            return  # nobody to talk to yet; the deadline runs meanwhile
        for request in self._requests:
            if not request.acked and now - request.sent_s >= COMMAND_RESEND_S:
                request.sent_s = now
                request.sends += 1
                self._command(request.command, request.params)
        self._check_requests(now)

    def _expire_requests(self, now: float) -> None:
        for request in list(self._requests):
            if now - request.created_s > COMMAND_DEADLINE_S:
                alive = now - self._last_heartbeat_s < HEARTBEAT_TIMEOUT_S
                why = "autopilot did not confirm" if alive else "autopilot not reachable"
                request.ticket._resolve(Ticket.FAILED, why)
                self._requests.remove(request)
        goto = self._goto
        if goto is not None and not goto.ticket.done and now - goto.created_s > COMMAND_DEADLINE_S + 1.0:
            goto.ticket._resolve(Ticket.FAILED, "GUIDED not confirmed in time")
            self._goto = None

    def _cancel_goto(self, why: str) -> None:
        goto, self._goto = self._goto, None
        if goto is not None:
            goto.ticket._resolve(Ticket.CANCELLED, why)
            if goto.mode_request is not None and goto.mode_request in self._requests:
                self._requests.remove(goto.mode_request)

    def _cancel_all(self, why: str) -> None:
        self._cancel_goto(why)
        for request in self._requests:
            request.ticket._resolve(Ticket.CANCELLED, why)
        self._requests.clear()
        with self._lock:
            queued = list(self._queue)
            self._queue.clear()
        for _, _, ticket in queued:
            ticket._resolve(Ticket.CANCELLED, why)

    def _drive_goto(self, now: float) -> None:
        goto = self._goto
        if goto is None:
            return
        snap = self.snapshot()
        ticket = goto.ticket
        if ticket.target is None:
            if goto.relative and not snap.position_valid:
                ticket._resolve(Ticket.FAILED, "no position estimate to resolve a relative order")
                self._goto = None
                return
            ticket.target = self._resolve_target(goto, snap)
        if goto.mode_request is None and snap.custom_mode != SubMode.GUIDED:
            goto.mode_request = self._request_mode(Ticket("mode GUIDED for goto"), SubMode.GUIDED, now)
        if goto.mode_request is not None and goto.mode_request.ticket.status in (Ticket.FAILED, Ticket.CANCELLED):
            ticket._resolve(Ticket.FAILED, f"autopilot refused GUIDED ({goto.mode_request.ticket.reason})")
            self._goto = None
            return
        if snap.custom_mode == SubMode.GUIDED:
            goto.seen_guided = True
        elif goto.seen_guided:
            # The autopilot left GUIDED on its own (a failsafe, another ground
            # station): the order is over; do not keep sending targets it ignores.
            log.info("autopilot left GUIDED: position order ended")
            self._goto = None
            return
        guided_acked = goto.mode_request is not None and goto.mode_request.ticket.status == Ticket.ACCEPTED
        if snap.custom_mode != SubMode.GUIDED and not guided_acked:
            return
        # Resend the target every second: ArduSub keeps it, and a lost datagram costs one second.
        if now - goto.target_sent_s >= 1.0:
            goto.target_sent_s = now
            x, y, z, yaw = ticket.target
            mask = TYPEMASK_POSITION_AND_YAW | (TYPEMASK_YAW_IGNORE if yaw is None else 0)
            self._conn.mav.set_position_target_local_ned_send(
                0, self._target_system, self._target_component, FRAME_LOCAL_NED, mask,
                x, y, z, 0, 0, 0, 0, 0, 0, 0.0 if yaw is None else yaw, 0,
            )
            if ticket._resolve(Ticket.ACCEPTED):
                log.info("GUIDED target sent: x %.2f y %.2f z %.2f m yaw %s", x, y, z,
                         "keep" if yaw is None else f"{math.degrees(yaw):.0f} deg")
        if snap.position_valid:
            x, y, z, yaw = ticket.target
            close = math.dist((snap.x_m, snap.y_m, snap.z_m), (x, y, z)) < REACHED_DISTANCE_M
            facing = yaw is None or abs(wrap_angle(yaw - snap.yaw_rad)) < REACHED_YAW_RAD
            ticket.reached = close and facing

    @staticmethod
    def _resolve_target(goto: _Goto, snap: AutopilotSnapshot) -> tuple[float, float, float, float | None]:
        x, y, z, yaw = goto.x_m, goto.y_m, goto.z_m, goto.yaw_rad
        if goto.relative:
            if goto.body:
                c, s = math.cos(snap.yaw_rad), math.sin(snap.yaw_rad)
                x, y = c * x - s * y, s * x + c * y
            x, y, z = snap.x_m + x, snap.y_m + y, snap.z_m + z
            yaw = wrap_angle(snap.yaw_rad + yaw) if yaw is not None else None
        elif yaw is not None:
            yaw = wrap_angle(yaw)
        # The vehicle cannot fly above the surface; ArduSub would clamp too.
        return x, y, max(z, 0.0), yaw


def _mode_name(custom_mode: int | None) -> str:
    if custom_mode is None:
        return "unknown"
    try:
        return SubMode(custom_mode).name
    except ValueError:
        return str(custom_mode)
