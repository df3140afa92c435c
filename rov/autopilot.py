"""The bridge from the ROV node to ArduSub, over MAVLink with pymavlink: the I/O part.

Goals
- Turn the node's wishes (velocity, arm, mode, position orders, brake, failsafe)
  into what ArduSub understands, and ArduSub's telemetry into one small snapshot
  the node can put in its reply.  MAVLink stays on the ROV: it is far too heavy for
  the radio, so we ask the autopilot only for what the link needs.
- Never block the caller, never crash on bad input, survive the autopilot going
  away and coming back.  The same code drives the real vehicle (BlueOS
  `udpin:0.0.0.0:14550`, SITL `tcp:127.0.0.1:5760`, a serial device) and the
  simulator in `rov.simulator`.

Plan (the logic lives in sans-I/O modules; this one owns the socket and the thread)
- `rov.commands.CommandTracker`: arm, mode and message-interval requests,
  resent every 0.5 s until COMMAND_ACK, failed after 2 s; `Ticket`s for the node.
- `rov.telemetry.Telemetry`: the autopilot's state with its freshness, and the
  `AutopilotSnapshot`.
- `rov.goto.GotoDriver`: the position order in GUIDED.
- Here: one I/O thread owns the pymavlink connection; the public methods take a
  lock, record a wish or queue a request, and return.  The thread acts as a ground
  station (system id 255 by default): HEARTBEAT at 1 Hz; MANUAL_CONTROL from the
  current velocity wish at 10 Hz whatever the radio does, since ArduSub disarms
  after 3 s without pilot input; SET_MESSAGE_INTERVAL for HEARTBEAT (5 Hz),
  ATTITUDE and LOCAL_POSITION_NED (10 Hz) and SYS_STATUS (1 Hz) whenever an
  autopilot is (re)found or a stream goes quiet.
- No HEARTBEAT for 3 s, a connection that fails to open, or one the peer closes
  (pymavlink's TCP EOF, turned into `MavlinkClosed` by `rov.mavurl`): the
  connection is closed and reopened with a growing backoff (0.5 s doubling to
  8 s, back to 0.5 s once a heartbeat is heard), one log line per attempt.

Decisions
- The reported mode (and armed state) is taken from an accepted DO_SET_MODE's
  (ARM_DISARM's) COMMAND_ACK at once (ArduSub acknowledges after the change), and from every HEARTBEAT, asked at 5 Hz,
  so a change the bridge did not make shows within 0.2 s plus the poll.  MAVLink's
  ACK names no request: two mode requests in flight (a STOP right after a
  POSITION) can be credited in the wrong order; the next heartbeat corrects it.
- Braking (STOP, failsafe): neutral sticks first (sent at once), then POSHOLD when
  the position estimate is valid, else ALT_HOLD; a refused POSHOLD falls back to
  ALT_HOLD.  ArduSub's ALT_HOLD holds depth but coasts (0.6-0.9 m measured);
  POSHOLD brakes.
- A position order is refused by the bridge itself (REASON 1) while disarmed,
  without a position estimate or without an autopilot; see `rov.goto`.

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
        yaw None keeps the heading.  Failed at once (reject_reason 1) when
        disarmed, without a position estimate or autopilot; non-finite numbers:
        failed at once (reject_reason 0).
    bridge.brake() -> BrakeTicket         # the protocol's STOP: neutral velocity, cancel
                                          # any position order, POSHOLD with a valid position
                                          # estimate, else ALT_HOLD (ticket.hold_mode says which).
    bridge.failsafe(active)               # link lost: brake() once, then hold neutral
                                          # velocity until failsafe(False).
    bridge.snapshot() -> AutopilotSnapshot   # frozen; see rov.telemetry.
  Ticket.status is "pending", "accepted", "failed" or "cancelled"; .reason says why
  in words; .reject_reason is docs/PROTOCOL.md §3's REASON for a failed one (1 impossible
  now, 2 the autopilot refused or did not answer within 2 s); .done once it is not
  pending; .wait(timeout_s) blocks (threads and tests only).  GotoTicket adds
  .target (the resolved absolute target) and .reached.  "cancelled" means
  abandoned (a newer request, STOP, the failsafe, the bridge stopping).
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time

from rovlink.link.radio.messages import Reason
from rovlink.rov.ardusub import (
    MAV_RESULT_NAMES,
    TYPEMASK_POSITION_AND_YAW,
    TYPEMASK_YAW_IGNORE,
    SubMode,
    mavlink,
    mode_name,
    sub_mode,
)
from rovlink.rov.commands import CommandTracker, GotoTicket, Ticket
from rovlink.rov.goto import GotoDriver, GotoOrder, goto_refusal
from rovlink.rov.mavurl import open_mavlink, parse_mavlink_url
from rovlink.rov.telemetry import HEARTBEAT_TIMEOUT_S, AutopilotSnapshot, Telemetry
from rovlink.rov.vehicle import PilotInput

log = logging.getLogger(__name__)

HEARTBEAT_PERIOD_S = 1.0
MANUAL_CONTROL_PERIOD_S = 0.1  # 10 Hz: twice the 5 Hz ArduSub needs to feel "fed"
MANUAL_CONTROL_MIN_GAP_S = 0.02  # a changed wish goes out at once, but not faster than this
AUTOPILOT_HEARTBEAT_INTERVAL_S = 0.2  # asked of the autopilot: a mode change shows within 0.2 s
BACKOFF_FIRST_S = 0.5
BACKOFF_MAX_S = 8.0


class BrakeTicket(Ticket):
    def __init__(self) -> None:
        super().__init__("brake")
        self.hold_mode: SubMode | None = None  # POSHOLD or ALT_HOLD, once chosen


class AutopilotBridge:
    def __init__(
        self,
        url: str,
        *,
        gcs_system_id: int = 255,
        gcs_component_id: int = mavlink.MAV_COMP_ID_MISSIONPLANNER,
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
        # Shared with the caller, under the lock:
        self._telemetry = Telemetry()
        self._pilot = PilotInput()
        self._pilot_changed = False
        self._failsafe = False
        self._queue: collections.deque = collections.deque()
        # The I/O thread's own:
        self._conn = None
        self._tracker = CommandTracker()
        self._goto = GotoDriver(self._tracker)
        self._brake: tuple[BrakeTicket, Ticket] | None = None  # the node's ticket, the mode request's
        self._target_system = target_system if target_system is not None else 1
        self._target_component = 1
        self._last_seen_s: dict[int, float] = {}
        self._stream_asked_s: dict[int, float] = {}
        self._opened_s = 0.0
        self._backoff_s = BACKOFF_FIRST_S
        self._reopen_at_s = 0.0
        self._next_heartbeat_s = 0.0
        self._next_manual_s = 0.0
        self._last_manual_s = -math.inf
        self.manual_controls_sent = 0  # counters for tests and diagnostics
        self.reconnects = 0
        self.heartbeats_received = 0

    # --- lifecycle -------------------------------------------------------------

    def start(self) -> "AutopilotBridge":
        if self._thread is None:
            self._stop_event.clear()
            self._thread = threading.Thread(target=self._run, name="rov-autopilot", daemon=True)
            self._thread.start()
        return self

    def stop(self, timeout_s: float = 3.0) -> None:
        """Send neutral sticks, close the connection, cancel what is pending."""
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
            ticket.fail("target is not a finite number", Reason.INVALID)
            return ticket
        # Impossible now: refuse at once, before anything is asked of the autopilot
        # (the I/O thread checks again when it takes the order).
        why = goto_refusal(self.snapshot())
        if why is not None:
            ticket.fail(why, Reason.IMPOSSIBLE)
            return ticket
        order = GotoOrder(float(x_m), float(y_m), float(z_m), None if yaw_rad is None else float(yaw_rad),
                          bool(relative), bool(body))
        with self._lock:
            self._set_pilot(PilotInput())  # a position order replaces the velocity wish
            self._queue.append(("goto", order, ticket))
        return ticket

    def brake(self) -> BrakeTicket:
        """STOP: neutral at once, any position order cancelled, then POSHOLD when the
        position estimate is valid, else ALT_HOLD.  Accepted once the autopilot
        confirms the hold mode."""
        ticket = BrakeTicket()
        with self._lock:
            self._set_pilot(PilotInput())
            self._queue.append(("brake", None, ticket))
        return ticket

    def failsafe(self, active: bool) -> None:
        with self._lock:
            was, self._failsafe = self._failsafe, bool(active)
            if active:
                self._set_pilot(PilotInput())
        if active and not was:
            log.warning("failsafe: neutral and brake")
            self.brake()
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
            return self._telemetry.snapshot(now, connected=self._conn is not None, failsafe=self._failsafe)

    # --- the I/O thread ---------------------------------------------------------

    def _run(self) -> None:
        try:
            while not self._stop_event.is_set():
                now = time.monotonic()
                if self._conn is None:
                    self._take_queue(now)
                    self._tracker.expire(now, reachable=False)
                    self._step_brake(now)
                    if now < self._reopen_at_s:
                        self._stop_event.wait(min(self._reopen_at_s - now, 0.1))
                        continue
                    self._open(now)
                    continue
                try:
                    msg = self._conn.recv_match(blocking=True, timeout=0.02)
                except Exception as exc:  # closed by the peer, serial unplugged, parser trouble
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
                neutral = PilotInput()
                self._conn.mav.manual_control_send(self._target_system, neutral.x, neutral.y, neutral.z, neutral.r, 0)
        except Exception as exc:
            log.debug("could not send the final neutral input: %s", exc)

    def _open(self, now: float) -> None:
        try:
            conn = open_mavlink(self.url, self.gcs_system_id, self.gcs_component_id)
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
            self._conn = conn

    def _schedule_reopen(self, now: float) -> None:
        self._reopen_at_s = now + self._backoff_s
        self._backoff_s = min(self._backoff_s * 2.0, BACKOFF_MAX_S)

    def _close(self) -> None:
        with self._lock:
            conn, self._conn = self._conn, None
            self._telemetry.lost()
        if conn is not None:
            try:
                conn.close()
            except Exception:
                pass

    def _drop(self, why: str) -> None:
        """The one log line of a failed attempt: why, and when the next comes."""
        log.warning("%s: closing %s, reopening in %.1f s", why, self.url.device, self._backoff_s)
        self._close()
        self.reconnects += 1
        self._schedule_reopen(time.monotonic())

    # incoming

    def _handle(self, msg, now: float) -> None:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self._on_heartbeat(msg, now)
            return
        if kind == "BAD_DATA" or msg.get_srcSystem() != self._target_system:
            return
        msg_id = msg.get_msgId()
        self._last_seen_s[msg_id] = now
        if kind == "ATTITUDE":
            with self._lock:
                self._telemetry.on_attitude(float(msg.roll), float(msg.pitch), float(msg.yaw), float(msg.yawspeed), now)
        elif kind == "LOCAL_POSITION_NED":
            with self._lock:
                self._telemetry.on_position(float(msg.x), float(msg.y), float(msg.z),
                                            float(msg.vx), float(msg.vy), float(msg.vz), now)
        elif kind == "RANGEFINDER":  # ArduPilot's own: metres, the first downward rangefinder
            with self._lock:
                self._telemetry.on_range(float(msg.distance), now)
        elif kind == "DISTANCE_SENSOR":
            if msg.orientation == mavlink.MAV_SENSOR_ROTATION_PITCH_270:  # facing down; others are not altitude
                cm = int(msg.current_distance)
                valid = msg.min_distance <= cm <= msg.max_distance
                with self._lock:
                    self._telemetry.on_range(cm / 100.0 if valid else math.nan, now)
        elif kind == "SYS_STATUS":
            volts = None if msg.voltage_battery in (0, 0xFFFF) else msg.voltage_battery / 1000.0
            with self._lock:
                self._telemetry.on_battery(volts, now)
        elif kind == "COMMAND_ACK":
            self._on_ack(msg, now)
        elif kind == "STATUSTEXT":
            text = msg.text if isinstance(msg.text, str) else bytes(msg.text).decode(errors="replace")
            text = text.rstrip("\x00")
            log.info("autopilot says: %s", text)
            with self._lock:
                self._telemetry.on_text(text, now)

    def _on_heartbeat(self, msg, now: float) -> None:
        if msg.type == mavlink.MAV_TYPE_GCS or msg.autopilot == mavlink.MAV_AUTOPILOT_INVALID:
            return  # another ground station, or a companion component
        system = msg.get_srcSystem()
        if self._fixed_target is not None and system != self._fixed_target:
            return
        armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        custom = int(msg.custom_mode) if msg.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED else None
        with self._lock:
            before = self._telemetry.values
            found = self._telemetry.on_heartbeat(system, armed, custom, now)
        if found:
            log.info("autopilot found: system %d component %d", system, msg.get_srcComponent())
            self._stream_asked_s.clear()  # a (re)found autopilot gets asked for streams
        if armed != before.armed:
            log.info("autopilot %s", "armed" if armed else "disarmed")
        if custom != before.custom_mode:
            log.info("autopilot mode %s", mode_name(custom))
        self._target_system = system
        self._target_component = msg.get_srcComponent()
        self._last_seen_s[mavlink.MAVLINK_MSG_ID_HEARTBEAT] = now
        self.heartbeats_received += 1
        self._backoff_s = BACKOFF_FIRST_S
        self._tracker.on_state(armed, custom)

    def _on_ack(self, msg, now: float) -> None:
        command, result = int(msg.command), int(msg.result)
        with self._lock:
            detail = self._telemetry.recent_text(now)
        request = self._tracker.on_ack(command, result, now, detail)
        if request is None:
            return
        if command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL and result != mavlink.MAV_RESULT_ACCEPTED:
            log.warning("autopilot refused a message interval: %s", MAV_RESULT_NAMES.get(result, result))
        if command == mavlink.MAV_CMD_DO_SET_MODE and result == mavlink.MAV_RESULT_ACCEPTED:
            # ArduSub acknowledges after the change: report it now, not at the next beat.
            with self._lock:
                self._telemetry.on_mode_accepted(request.want_mode, now)
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM and result == mavlink.MAV_RESULT_ACCEPTED:
            with self._lock:
                self._telemetry.on_armed_accepted(request.want_armed, now)

    # outgoing

    def _alive(self, now: float) -> bool:
        with self._lock:
            return self._telemetry.alive(now)

    def _periodic(self, now: float) -> None:
        conn = self._conn
        alive = self._alive(now)
        if not alive:
            with self._lock:
                last_heartbeat_s = self._telemetry.last_heartbeat_s
            if now - max(last_heartbeat_s, self._opened_s) >= HEARTBEAT_TIMEOUT_S:
                self._drop("no heartbeat for %.0f s" % HEARTBEAT_TIMEOUT_S)
                return
        if now >= self._next_heartbeat_s:
            self._next_heartbeat_s = now + HEARTBEAT_PERIOD_S
            conn.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE)
        with self._lock:
            changed = self._pilot_changed and now - self._last_manual_s >= MANUAL_CONTROL_MIN_GAP_S
        if now >= self._next_manual_s or changed:
            self._send_manual(now)
        if alive:
            self._ask_streams(now)
        self._take_queue(now)
        snap = self.snapshot()
        target = self._goto.step(snap, now)
        if target is not None:
            self._send_target(target)
        if self._goto.brake_wanted:
            self._goto.brake_wanted = False
            self._start_brake(BrakeTicket(), now)
        if alive:  # nobody to talk to otherwise; the deadlines run meanwhile
            for request in self._tracker.due(now):
                conn.mav.command_long_send(self._target_system, self._target_component, request.command, 0,
                                           *request.params)
        self._tracker.expire(now, reachable=alive)
        self._step_brake(now)

    def _send_manual(self, now: float) -> None:
        if self._conn is None:
            return
        with self._lock:
            pilot = PilotInput() if self._failsafe else self._pilot
            self._pilot_changed = False
        self._next_manual_s = max(self._next_manual_s + MANUAL_CONTROL_PERIOD_S, now - MANUAL_CONTROL_PERIOD_S)
        self._last_manual_s = now
        self._conn.mav.manual_control_send(self._target_system, pilot.x, pilot.y, pilot.z, pilot.r, 0)
        self.manual_controls_sent += 1

    def _ask_streams(self, now: float) -> None:
        rates = {
            mavlink.MAVLINK_MSG_ID_HEARTBEAT: AUTOPILOT_HEARTBEAT_INTERVAL_S,
            mavlink.MAVLINK_MSG_ID_ATTITUDE: self.telemetry_interval_s,
            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self.telemetry_interval_s,
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
        }
        for msg_id, interval_s in rates.items():
            asked = self._stream_asked_s.get(msg_id)
            last = max(self._last_seen_s.get(msg_id, -math.inf), -math.inf if asked is None else asked)
            # Asked when an autopilot is (re)found, again when the stream goes quiet
            # (an autopilot restarted within the heartbeat timeout forgets them).
            if asked is None or now - last > 3 * interval_s + 1.0:
                self._stream_asked_s[msg_id] = now
                self._tracker.request(
                    Ticket(f"interval {msg_id}"), mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                    (msg_id, interval_s * 1e6), now, kind=f"interval {msg_id}",
                )

    def _send_target(self, target: tuple[float, float, float, float | None]) -> None:
        x, y, z, yaw = target
        mask = TYPEMASK_POSITION_AND_YAW | (TYPEMASK_YAW_IGNORE if yaw is None else 0)
        self._conn.mav.set_position_target_local_ned_send(
            0, self._target_system, self._target_component, mavlink.MAV_FRAME_LOCAL_NED, mask,
            x, y, z, 0, 0, 0, 0, 0, 0, 0.0 if yaw is None else yaw, 0,
        )

    def _take_queue(self, now: float) -> None:
        while True:
            with self._lock:
                if not self._queue:
                    return
                kind, value, ticket = self._queue.popleft()
            if kind == "arm":
                self._tracker.arm(ticket, value, now)
            elif kind == "mode":
                self._goto.cancel("another mode was requested")
                self._cancel_brake("another mode was requested")
                self._tracker.mode(ticket, value, now)
            elif kind == "brake":
                self._start_brake(ticket, now)
            elif kind == "goto":
                self._cancel_brake("a position order was taken")
                self._goto.start(ticket, value, self.snapshot(), now)

    def _start_brake(self, ticket: BrakeTicket, now: float) -> None:
        self._send_manual(now)  # neutral before the mode change, whatever the 10 Hz slot
        self._goto.cancel("stopped")
        self._cancel_brake("a newer brake")
        snap = self.snapshot()
        hold = SubMode.POSHOLD if snap.position_valid else SubMode.ALT_HOLD
        ticket.hold_mode = hold
        self._brake = (ticket, self._tracker.mode(Ticket(f"mode {hold.name} to brake"), hold, now).ticket)

    def _step_brake(self, now: float) -> None:
        if self._brake is None:
            return
        ticket, request = self._brake
        if not request.done:
            return
        if request.status == Ticket.FAILED and ticket.hold_mode == SubMode.POSHOLD:
            log.warning("POSHOLD refused (%s): braking in ALT_HOLD", request.reason)
            ticket.hold_mode = SubMode.ALT_HOLD
            self._brake = (ticket, self._tracker.mode(Ticket("mode ALT_HOLD to brake"), SubMode.ALT_HOLD, now).ticket)
            return
        self._brake = None
        if request.status == Ticket.FAILED:
            ticket.fail(request.reason, request.reject_reason)
        else:
            ticket._resolve(request.status, request.reason)

    def _cancel_brake(self, why: str) -> None:
        brake, self._brake = self._brake, None
        if brake is not None:
            brake[0]._resolve(Ticket.CANCELLED, why)

    def _cancel_all(self, why: str) -> None:
        self._goto.cancel(why)
        self._cancel_brake(why)
        self._tracker.cancel_all(why)
        with self._lock:
            queued = list(self._queue)
            self._queue.clear()
        for _, _, ticket in queued:
            ticket._resolve(Ticket.CANCELLED, why)
