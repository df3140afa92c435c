"""A MAVLink ground-station gateway: QGroundControl or Cockpit on the console
as if the vehicle were on a tether.

Goal: the pilot's own ground station (joystick mapping, HUD, map, alerts)
drives the ROV through the narrow link.  MAVLink itself can't cross 1.9
kbit/s; the console can speak it locally, from what the replies say, and turn
what the ground station sends into rovlink orders.

What the ground station sees (system 1, component 1, MAVLink 2, an ArduSub
submarine: MAV_TYPE_SUBMARINE, MAV_AUTOPILOT_ARDUPILOTMEGA, ArduSub's custom
modes through rov.ardusub's one protocol<->ArduSub mode map):
- HEARTBEAT at 1 Hz with the armed flag and mode of the last reply; system
  status ACTIVE/STANDBY, CRITICAL while the link is lost or the ROV reports
  FAILSAFE, UNINIT before the first reply.
- ATTITUDE, LOCAL_POSITION_NED, GLOBAL_POSITION_INT (from `home`, flat-earth),
  VFR_HUD (heading, depth as negative altitude, speeds from successive
  replies) and SYS_STATUS, at ArduSub's default rates, changed by
  REQUEST_DATA_STREAM and SET_MESSAGE_INTERVAL.  Attitude and position are
  sent only while they are valid and the link is up: a ground station shows
  "no data" rather than a stale pose as current.  LOCAL/GLOBAL position only
  with POSITION_VALID, as ArduSub sends them only with a position estimate.
- STATUSTEXT for link loss and return, failsafe, rejected orders and new
  images.

What it may send (through the console's one command layer and its control
rules: the ground station is one client; it takes control when nobody holds
it, and is refused while a page holds it):
- MANUAL_CONTROL x, y, z, r (z 500 neutral, ArduSub's) -> the velocity wish,
  streamed: it falls back to neutral when the stream stops (the desk's dead man).
- COMMAND_LONG ARM_DISARM, DO_SET_MODE, SET_MODE -> arm/mode requests;
  SET_POSITION_TARGET_LOCAL_NED and a GUIDED "go to" (MISSION_ITEM_INT with
  current=2) -> POSITION; DO_PAUSE_CONTINUE (pause) -> STOP.
- Every command gets COMMAND_ACK IN_PROGRESS at once, then its real outcome,
  only when the vehicle has said it (console/session/fates.py): ACCEPTED when
  the replies show it done (or the ROV acknowledged the order), FAILED with a
  STATUSTEXT reason when the ROV rejected it (or the console never sent it),
  CANCELLED when superseded; DENIED while someone else holds control,
  TEMPORARILY_REJECTED while the link is lost.  An order the vehicle has not
  answered is never failed for it: after WAITING_SAID_S a STATUSTEXT says it
  still waits, and if it is followed late the ACCEPTED comes then, with a
  STATUSTEXT saying how late.  An unknown fate gets a STATUSTEXT and no final
  ACK (nobody can say whether it was done).
- Parameters and missions answer just enough that a ground station does not
  hang: a few read-only parameters, no mission items.
- Camera: the latest picture is the console's `/api/image/latest.png` (the
  README says so): MAVLink's video stream types are all video codecs, and a
  DEBT picture refines as trunks arrive, so it is not advertised as a stream.

Plan: one thread per connection (pymavlink is blocking); every order goes
through `DeskCommands`, a client of the console's one command layer
(`console.control.ControlDesk.submit`, as `Caller(via="gcs")`), and its
outcome is the fate the console gives the order (a `Fate`: acknowledged or
followed, rejected with a reason...), so the gateway holds no order state of
its own beyond the commands it is waiting to answer.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega

from rovlink.console.control import Arm, Caller, Drive, GoTo, NotHolder, SetMode, Stop, UnknownClient
from rovlink.console.session.fates import Fate, words
from rovlink.link.vocabulary import Mode
from rovlink.rov.ardusub import PROTOCOL_TO_SUB, SUB_TO_PROTOCOL, mode_name
from rovlink.rov.mavurl import bound_port, open_mavlink, parse_mavlink_url

log = logging.getLogger("rovlink.console.gcs")

EARTH_RADIUS_M = 6_378_137.0
WAITING_SAID_S = 15.0    # still no word from the vehicle: a STATUSTEXT says it waits (never FAILED for it)
AWAITED_KEPT_S = 600.0   # a command the vehicle never answered is no longer reported on after this
MANUAL_CONTROL_NEUTRAL_Z = 500



class CommandRefused(Exception):
    """An order the command layer refused: `result` is the MAV_RESULT to answer."""

    def __init__(self, result: int, reason: str) -> None:
        super().__init__(reason)
        self.result = result
        self.reason = reason


# ---------------------------------------------------------------------------
# What the gateway needs from the console
# ---------------------------------------------------------------------------


class DeskCommands:
    """The console's command layer (console/control.py) as the ground station
    uses it: typed orders submitted as one desk client, "ground station",
    which takes control when nobody holds it."""

    def __init__(self, desk, name: str = "ground station") -> None:
        self.desk = desk
        self.operator = desk.operator
        self.name = name
        self._client_id: str | None = None
        self._lock = threading.Lock()

    def _caller(self, need_control: bool = True):
        m = ardupilotmega
        with self._lock:
            status = self.desk.status(self._client_id)
            if not need_control or status.get("you"):
                return Caller(self._client_id, via="gcs")
            # Taken only if nobody holds it, decided under the desk's lock (a page may take it
            # between the status and here).  The joystick may be held off neutral already: it
            # drives once it has been centred.
            try:
                try:
                    client = self.desk.take(self._client_id, self.name, streams_input=True, unless_held=True)
                except UnknownClient:  # forgotten while it held nothing (idle): a new client
                    client = self.desk.take(None, self.name, streams_input=True, unless_held=True)
            except NotHolder as exc:
                raise CommandRefused(m.MAV_RESULT_DENIED, str(exc)) from None
            self._client_id = client.id
            return Caller(self._client_id, via="gcs")

    def heard(self) -> None:
        """The ground station is still there (its HEARTBEAT): keep its lease."""
        if self._client_id is not None:
            try:
                self.desk.touch(self._client_id)
            except Exception:  # a client the desk has forgotten: it takes control again when it orders
                self._client_id = None

    def release(self) -> None:
        with self._lock:
            if self._client_id is not None:
                try:
                    self.desk.release(self._client_id)
                except Exception:
                    pass
                self._client_id = None

    def velocity(self, vx: float, vy: float, vz: float, vyaw: float) -> None:
        self.desk.submit(Drive(vx, vy, vz, vyaw, streamed=True), self._caller())

    def arm(self, armed: bool) -> int:
        return self.desk.submit(Arm(armed), self._caller())

    def mode(self, name: str) -> int:
        return self.desk.submit(SetMode(name), self._caller())

    def goto(self, x_m: float, y_m: float, z_m: float, yaw_deg: float) -> int:
        return self.desk.submit(GoTo(x_m, y_m, z_m, yaw_deg), self._caller())

    def stop(self) -> int:
        return self.desk.submit(Stop(), self._caller(need_control=False))  # open to everyone

    def order_fate(self, order_id: int) -> tuple[Fate, str, dict] | None:
        """The order's fate as the console tracks it, its reason and its whole state."""
        for info in self.operator.orders_state():
            if info.get("id") == order_id:
                return Fate(info["state"]), str(info.get("reason", "")), info
        return None


# ---------------------------------------------------------------------------
# The gateway
# ---------------------------------------------------------------------------


@dataclass
class _Awaited:
    command: int | None  # the COMMAND_LONG to answer, if any
    order_id: int
    asked_at: float
    what: str
    said: Fate | None = None  # the pending or unknown fate a STATUSTEXT told already


# Messages the gateway streams, with ArduSub's default rates (Hz) and the
# REQUEST_DATA_STREAM group each belongs to.
STREAMS = {
    "ATTITUDE": (10.0, "EXTRA1"),
    "VFR_HUD": (10.0, "EXTRA2"),
    "LOCAL_POSITION_NED": (3.0, "POSITION"),
    "GLOBAL_POSITION_INT": (3.0, "POSITION"),
    "SYS_STATUS": (2.0, "EXTENDED_STATUS"),
}
PARAMETERS = (("SYSID_THISMAV", 1.0), ("FS_GCS_ENABLE", 0.0), ("RL_LINK_BPS", 1900.0))


class GcsLink:
    """One ground-station connection (a pymavlink connection string)."""

    def __init__(self, url: str, operator, commands, *, home: tuple[float, float] = (0.0, 0.0),
                 clock: Callable[[], float] = time.monotonic) -> None:

        self.url = parse_mavlink_url(url)
        self.operator = operator
        self.commands = commands
        self.home = home
        self._clock = clock
        self._t0 = clock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._conn = None
        self._periods = {name: 1.0 / hz for name, (hz, _) in STREAMS.items()}
        self._next_at = {name: 0.0 for name in STREAMS}
        self._next_heartbeat = 0.0
        self._heartbeat_said = None  # (armed, mode, autopilot, failsafe) the last HEARTBEAT told
        self._awaited: list[_Awaited] = []
        self._alerted = {"lost": False, "failsafe": False, "autopilot_lost": False, "centre": False}
        self._last_image = None
        self._goto_told: set = set()  # go-to ids whose end was told
        self._unsubscribe = None
        self.sent: dict[str, int] = {}
        self.received: dict[str, int] = {}

    # -- life ---------------------------------------------------------------

    def start(self) -> "GcsLink":

        conn = open_mavlink(self.url, source_system=1, source_component=1)
        # MAVLink 2 whatever pymavlink's process-wide default: ArduSub speaks it.
        m = ardupilotmega
        conn.mav = m.MAVLink(conn, srcSystem=1, srcComponent=1, use_native=False)
        conn.mav.robust_parsing = True
        self._conn = conn
        self._unsubscribe = self.operator.subscribe(self._on_event)
        self._thread = threading.Thread(target=self._run, name=f"gcs {self.url.device}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._unsubscribe:
            self._unsubscribe()
        if self._thread:
            self._thread.join(5)
        if self._conn is not None:
            try:
                self._conn.close()
            except OSError:
                pass
        self.commands.release()

    @property
    def port(self) -> int | None:

        return bound_port(self._conn) if self._conn is not None else None

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self._conn.recv_match(blocking=True, timeout=0.02)
            except (OSError, ConnectionError) as exc:
                log.warning("ground station %s: %s", self.url.device, exc)
                time.sleep(0.5)
                msg = None
            if msg is not None:
                try:
                    self._handle(msg)
                except Exception:  # one bad message must not stop the gateway
                    log.exception("ground station message %s", msg.get_type())
            try:
                self._send_due()
                self._check_awaited()
            except OSError as exc:
                # udpout with nobody listening yet, a vanished peer: keep going.
                log.debug("ground station %s: %s", self.url.device, exc)
            except Exception:
                log.exception("ground station %s", self.url.device)

    def now(self) -> float:
        return self._clock() - self._t0

    def _send(self, name: str, *args, **kwargs) -> None:
        getattr(self._conn.mav, f"{name.lower()}_send")(*args, **kwargs)
        self.sent[name] = self.sent.get(name, 0) + 1

    def statustext(self, severity: int, text: str) -> None:
        self._send("STATUSTEXT", severity, text.encode()[:50])

    # -- what the replies say ---------------------------------------------

    def _link_lost(self) -> bool:
        """The session's own definition (console.session.health), as the page shows it;
        before the first reply nothing is known of the vehicle either."""
        return self.operator.link_condition()[0] in ("lost", "starting")

    def _on_event(self, topic: str, payload) -> None:  # operator's thread
        m = ardupilotmega
        try:
            if topic == "image" and payload.get("complete") and payload.get("serial") != self._last_image:
                self._last_image = payload.get("serial")  # the picture's number, as the page and log say it
                self.statustext(m.MAV_SEVERITY_INFO, f"rovlink: picture #{payload.get('serial')} complete")
            elif topic == "control":
                centre = bool(payload.get("centre_to_drive")) and payload.get("holder") == getattr(self.commands, "name", None)
                if centre and not self._alerted["centre"]:
                    self.statustext(m.MAV_SEVERITY_WARNING, "rovlink: centre the sticks to drive")
                self._alerted["centre"] = centre
            elif topic == "order":
                self._order_news(payload)
        except (OSError, AttributeError):
            pass

    def _order_news(self, info: dict) -> None:
        """What the ground station hears of an order's fate beside its COMMAND_ACK."""
        m = ardupilotmega
        fate, reason, kind = Fate(info["state"]), str(info.get("reason", "")), info.get("kind")
        if fate in (Fate.REJECTED, Fate.CANCELLED):
            self.statustext(m.MAV_SEVERITY_WARNING, f"rovlink: {kind} {words(fate, reason)}"[:50])
        elif fate is Fate.FOLLOWED and ("t_waiting" in info or "t_unknown" in info):
            # Followed after the console had said it waits: the vehicle did it, late.
            self.statustext(m.MAV_SEVERITY_INFO, f"rovlink: {kind} followed, {reason}"[:50])
        elif kind == "POSITION" and fate in (Fate.ARRIVED, Fate.ABORTED) and info.get("id") not in self._goto_told:
            # The go-to's end, as the page shows it (the ROV acknowledges a go-to
            # when GUIDED takes it; arriving or giving up comes later).
            self._goto_told.add(info.get("id"))
            self.statustext(m.MAV_SEVERITY_INFO if fate is Fate.ARRIVED else m.MAV_SEVERITY_WARNING,
                            f"rovlink: go-to #{info.get('id')} {words(fate, reason)}"[:50])

    def _speeds(self) -> tuple[float, float, float]:
        """North, east, down m/s: the session's own measure (the page shows the same)."""
        v = self.operator.ned_velocity()
        return (0.0, 0.0, 0.0) if v is None else v[:3]

    def _send_due(self) -> None:
        t = self.now()
        reply = self.operator.vehicle()
        lost = self._link_lost()
        said = None if reply is None else (reply.armed, reply.mode, reply.autopilot, reply.failsafe)
        if t >= self._next_heartbeat or (said != self._heartbeat_said and not lost):
            # 1 Hz, and at once when a reply shows a change (ArduSub too sends an extra
            # HEARTBEAT on a mode change): the ground station is no later than the page.
            self._heartbeat_said = said
            self._next_heartbeat = t + 1.0
            self._heartbeat(reply, lost)
            self._alerts(reply, lost)
        time_ms = int(t * 1000) & 0xFFFFFFFF
        for name, period in self._periods.items():
            if period is None or t < self._next_at[name]:
                continue
            self._next_at[name] = t + period
            if name == "SYS_STATUS":
                self._sys_status(reply, lost)
                continue
            if reply is None or lost:
                continue  # nothing current to say
            if name == "ATTITUDE":
                self._send("ATTITUDE", time_ms, math.radians(reply.roll_deg), math.radians(reply.pitch_deg),
                           math.radians(reply.yaw_deg), 0.0, 0.0, 0.0)
            elif name == "VFR_HUD":
                vn, ve, vd = self._speeds()
                self._send("VFR_HUD", 0.0, math.hypot(vn, ve), int(round(reply.yaw_deg)) % 360, 0, -reply.z_m, -vd)
            elif not reply.position_valid:
                continue
            elif name == "LOCAL_POSITION_NED":
                vn, ve, vd = self._speeds()
                self._send("LOCAL_POSITION_NED", time_ms, reply.x_m, reply.y_m, reply.z_m, vn, ve, vd)
            elif name == "GLOBAL_POSITION_INT":
                # MAVLink's own units: degE7, millimetres, cm/s, centidegrees.
                lat, lon = self._lat_lon(reply.x_m, reply.y_m)
                vn, ve, vd = self._speeds()
                self._send("GLOBAL_POSITION_INT", time_ms, int(round(lat * 1e7)), int(round(lon * 1e7)),
                           int(round(-reply.z_m * 1000)), int(round(-reply.z_m * 1000)),
                           int(round(vn * 100)), int(round(ve * 100)), int(round(vd * 100)),
                           int(round(reply.yaw_deg * 100)) % 36000)

    def _lat_lon(self, north_m: float, east_m: float) -> tuple[float, float]:
        lat0, lon0 = self.home
        lat = lat0 + math.degrees(north_m / EARTH_RADIUS_M)
        lon = lon0 + math.degrees(east_m / (EARTH_RADIUS_M * max(1e-6, math.cos(math.radians(lat0)))))
        return lat, lon

    def _ned_from_lat_lon(self, lat: float, lon: float) -> tuple[float, float]:
        lat0, lon0 = self.home
        north = math.radians(lat - lat0) * EARTH_RADIUS_M
        east = math.radians(lon - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
        return north, east

    def _heartbeat(self, reply, lost: bool) -> None:
        """ArduSub's HEARTBEAT as the replies tell it.  A mode is claimed only when
        known: with the autopilot lost on the ROV (ArduSub's own heartbeat would be
        absent) or a mode the protocol cannot name, the custom mode flag is off
        (custom_mode 0 would read as STABILIZE) and the state says the rest."""

        m = ardupilotmega
        base = 0
        custom = 0
        if reply is None:
            status = m.MAV_STATE_UNINIT
        elif not reply.autopilot:
            status = m.MAV_STATE_CRITICAL  # nothing on the ROV flies it: no mode, not armed that we know
        else:
            if reply.mode in PROTOCOL_TO_SUB:
                base |= m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
                custom = int(PROTOCOL_TO_SUB[reply.mode])
            if reply.armed:
                base |= m.MAV_MODE_FLAG_SAFETY_ARMED
            if lost or reply.failsafe:
                status = m.MAV_STATE_CRITICAL
            else:
                status = m.MAV_STATE_ACTIVE if reply.armed else m.MAV_STATE_STANDBY
        self._send("HEARTBEAT", m.MAV_TYPE_SUBMARINE, m.MAV_AUTOPILOT_ARDUPILOTMEGA, base, custom, status)

    def _sys_status(self, reply, lost: bool) -> None:
        m = ardupilotmega
        sensors = m.MAV_SYS_STATUS_SENSOR_3D_GYRO | m.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
        health = 0 if (reply is None or lost or not reply.autopilot) else sensors
        # No fence on a ROV: never breached (ground stations alarm on a fence bit going unhealthy).
        health |= m.MAV_SYS_STATUS_GEOFENCE
        link = self.operator.link_state()
        sent, lost_reports = link.get("sent") or 0, link.get("reports_lost") or 0
        drop = int(10000 * lost_reports / sent) if sent else 0
        self._send("SYS_STATUS", sensors, sensors, health, 0, 65535, -1, -1, min(10000, drop),
                   int(link.get("bad_frames") or 0) & 0xFFFF, 0, 0, 0, 0)

    def _alerts(self, reply, lost: bool) -> None:
        m = ardupilotmega
        if reply is None:
            return
        if lost != self._alerted["lost"]:
            self._alerted["lost"] = lost
            if lost:
                self.statustext(m.MAV_SEVERITY_CRITICAL, "rovlink: link to ROV lost; data stale")
            else:
                self.statustext(m.MAV_SEVERITY_NOTICE, "rovlink: link to ROV restored")
        failsafe = bool(reply.failsafe)
        if failsafe != self._alerted["failsafe"]:
            self._alerted["failsafe"] = failsafe
            if failsafe:
                self.statustext(m.MAV_SEVERITY_CRITICAL, "rovlink: ROV in FAILSAFE (link loss)")
        autopilot_lost = not reply.autopilot
        if not lost and autopilot_lost != self._alerted["autopilot_lost"]:  # a stale reply says nothing new
            self._alerted["autopilot_lost"] = autopilot_lost
            if autopilot_lost:
                self.statustext(m.MAV_SEVERITY_CRITICAL, "rovlink: autopilot lost on the ROV")
            else:
                self.statustext(m.MAV_SEVERITY_NOTICE, "rovlink: autopilot back on the ROV")

    # -- what the ground station says ------------------------------------

    def _handle(self, msg) -> None:
        m = ardupilotmega
        kind = msg.get_type()
        if kind == "BAD_DATA":
            return
        self.received[kind] = self.received.get(kind, 0) + 1
        target_system = getattr(msg, "target_system", 1)
        if target_system not in (0, 1):
            return
        if kind == "HEARTBEAT":
            self.commands.heard()
        elif kind == "MANUAL_CONTROL":
            self._manual_control(msg)
        elif kind == "COMMAND_LONG":
            self._command_long(msg)
        elif kind == "SET_MODE":
            self._do(m.MAV_CMD_DO_SET_MODE, lambda: self._mode_by_number(msg.custom_mode))
        elif kind == "SET_POSITION_TARGET_LOCAL_NED":
            self._position_target(msg)
        elif kind == "MISSION_ITEM_INT" and msg.current == 2:
            self._guided_goto(msg)
        elif kind == "REQUEST_DATA_STREAM":
            self._request_data_stream(msg)
        elif kind == "PARAM_REQUEST_LIST":
            for i, (name, value) in enumerate(PARAMETERS):
                self._send("PARAM_VALUE", name.encode(), value, m.MAV_PARAM_TYPE_REAL32, len(PARAMETERS), i)
        elif kind in ("PARAM_REQUEST_READ", "PARAM_SET"):
            wanted = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode(errors="replace")
            for i, (name, value) in enumerate(PARAMETERS):
                if name == wanted.rstrip("\x00") or (kind == "PARAM_REQUEST_READ" and msg.param_index == i):
                    # Read-only: a PARAM_SET is answered with the value that stays.
                    self._send("PARAM_VALUE", name.encode(), value, m.MAV_PARAM_TYPE_REAL32, len(PARAMETERS), i)
                    break
        elif kind == "MISSION_REQUEST_LIST":
            self._send("MISSION_COUNT", msg.get_srcSystem(), msg.get_srcComponent(), 0,
                       getattr(msg, "mission_type", 0))

    def _manual_control(self, msg) -> None:
        def frac(v: float) -> float:
            return max(-1.0, min(1.0, v))

        vx, vy, vyaw = frac(msg.x / 1000), frac(msg.y / 1000), frac(msg.r / 1000)
        vz = frac((MANUAL_CONTROL_NEUTRAL_Z - msg.z) / 500)  # z above 500 is up; the wish's z is down
        try:
            self.commands.velocity(vx, vy, vz, vyaw)
        except CommandRefused:
            pass  # no answer exists for MANUAL_CONTROL; the HEARTBEAT shows nothing moves
        except Exception as exc:  # an order the layer refuses: counted, never raised here
            log.debug("MANUAL_CONTROL refused: %s", exc)

    def _ack(self, command: int | None, result: int, progress: int = 0) -> None:
        if command is not None:
            self._send("COMMAND_ACK", command, result, progress)

    def _do(self, command: int | None, action: Callable[[], _Awaited]) -> None:
        """Run an order; answer IN_PROGRESS and await its outcome.  `command`
        None: a message with no COMMAND_ACK of its own (a position target):
        its outcome goes out as STATUSTEXT only."""
        m = ardupilotmega
        if self._link_lost() and command != m.MAV_CMD_DO_PAUSE_CONTINUE:
            self._ack(command, m.MAV_RESULT_TEMPORARILY_REJECTED)
            self.statustext(m.MAV_SEVERITY_WARNING, "rovlink: link to ROV lost; order not sent")
            return
        try:
            awaited = action()
        except CommandRefused as exc:
            self._ack(command, exc.result)
            self.statustext(m.MAV_SEVERITY_WARNING, f"rovlink: {exc.reason}"[:50])
            return
        except Exception as exc:  # OrderError and the like: the order is invalid
            self._ack(command, m.MAV_RESULT_DENIED)
            self.statustext(m.MAV_SEVERITY_WARNING, f"rovlink: {exc}"[:50])
            return
        self._ack(command, m.MAV_RESULT_IN_PROGRESS)
        self._awaited.append(awaited)

    def _check_awaited(self) -> None:
        """Each command's final COMMAND_ACK once the vehicle has said its fate;
        meanwhile a STATUSTEXT when it has waited long, or its fate is unknown."""
        m = ardupilotmega
        t = self.now()
        for awaited in list(self._awaited):
            known = self.commands.order_fate(awaited.order_id)
            if known is None:  # gone from the console's list: nothing more will be told
                self._awaited.remove(awaited)
                continue
            fate, reason, _ = known
            if fate.outcome == "done":
                self._ack(awaited.command, m.MAV_RESULT_ACCEPTED, 100)
                if awaited.command is None:
                    self.statustext(m.MAV_SEVERITY_INFO, f"rovlink: {awaited.what} acknowledged by the ROV")
            elif fate is Fate.CANCELLED:
                self._ack(awaited.command, m.MAV_RESULT_CANCELLED)
            elif fate.ended and fate is not Fate.UNKNOWN:  # rejected, refused, not carried out, aborted
                self._ack(awaited.command, m.MAV_RESULT_FAILED)
                self.statustext(m.MAV_SEVERITY_WARNING, f"rovlink: {awaited.what} {words(fate, reason)}"[:50])
            elif t - awaited.asked_at > AWAITED_KEPT_S:
                self.statustext(m.MAV_SEVERITY_WARNING, f"rovlink: {awaited.what} {fate.value}; no longer reported")
            else:
                if fate is Fate.UNKNOWN and awaited.said is not Fate.UNKNOWN:
                    awaited.said = Fate.UNKNOWN  # no final ACK: nobody can say whether it was done
                    self.statustext(m.MAV_SEVERITY_WARNING, f"rovlink: {awaited.what} fate unknown: {reason}"[:50])
                elif fate.pending and awaited.said is None and t - awaited.asked_at > WAITING_SAID_S:
                    awaited.said = fate
                    self.statustext(m.MAV_SEVERITY_WARNING,
                                    f"rovlink: {awaited.what} waiting for the vehicle ({t - awaited.asked_at:.0f} s)"[:50])
                continue
            self._awaited.remove(awaited)

    def _command_long(self, msg) -> None:
        m = ardupilotmega
        cmd = msg.command
        if cmd == m.MAV_CMD_COMPONENT_ARM_DISARM:
            self._do(cmd, lambda: self._arm(msg.param1 >= 0.5))
        elif cmd == m.MAV_CMD_DO_SET_MODE:
            self._do(cmd, lambda: self._mode_by_number(int(msg.param2)))
        elif cmd == m.MAV_CMD_DO_PAUSE_CONTINUE:
            if msg.param1 == 0:
                self._do(cmd, self._stop_order)
            else:
                self._ack(cmd, m.MAV_RESULT_UNSUPPORTED)  # nothing to continue: the pilot drives again
        elif cmd == m.MAV_CMD_SET_MESSAGE_INTERVAL:
            self._ack(cmd, self._set_interval(int(msg.param1), msg.param2))
        elif cmd == m.MAV_CMD_REQUEST_MESSAGE and int(msg.param1) == m.MAVLINK_MSG_ID_HEARTBEAT:
            self._ack(cmd, m.MAV_RESULT_ACCEPTED)
            self._heartbeat(self.operator.vehicle(), self._link_lost())
        else:
            self._ack(cmd, m.MAV_RESULT_UNSUPPORTED)

    def _arm(self, armed: bool) -> _Awaited:
        m = ardupilotmega
        order_id = self.commands.arm(armed)
        return _Awaited(m.MAV_CMD_COMPONENT_ARM_DISARM, order_id, self.now(), "arm" if armed else "disarm")

    def _mode_by_number(self, custom_mode: int) -> _Awaited:

        m = ardupilotmega
        sub_name = mode_name(custom_mode)
        if custom_mode not in SUB_TO_PROTOCOL:
            raise CommandRefused(m.MAV_RESULT_DENIED, f"mode {sub_name} not offered over the link")
        order_id = self.commands.mode(Mode(SUB_TO_PROTOCOL[custom_mode]).name)
        return _Awaited(m.MAV_CMD_DO_SET_MODE, order_id, self.now(), f"mode {sub_name}")

    def _stop_order(self) -> _Awaited:
        m = ardupilotmega
        order_id = self.commands.stop()
        return _Awaited(m.MAV_CMD_DO_PAUSE_CONTINUE, order_id, self.now(), "STOP")

    def _goto(self, command: int | None, x: float, y: float, z: float, yaw_deg: float) -> _Awaited:
        order_id = self.commands.goto(x, y, z, yaw_deg)
        return _Awaited(command, order_id, self.now(), "go to")

    def _position_target(self, msg) -> None:
        m = ardupilotmega
        if msg.coordinate_frame != m.MAV_FRAME_LOCAL_NED or msg.type_mask & 0b111:
            self.statustext(m.MAV_SEVERITY_WARNING, "rovlink: only LOCAL_NED position targets")
            return
        reply = self.operator.vehicle()
        yaw = math.degrees(msg.yaw) if not msg.type_mask & m.POSITION_TARGET_TYPEMASK_YAW_IGNORE else (
            reply.yaw_deg if reply else 0.0)
        # No COMMAND_LONG to answer: the outcome goes out as STATUSTEXT.
        self._do(None, lambda: self._goto(None, msg.x, msg.y, msg.z, yaw))

    def _guided_goto(self, msg) -> None:
        m = ardupilotmega
        north, east = self._ned_from_lat_lon(msg.x / 1e7, msg.y / 1e7)
        reply = self.operator.vehicle()
        if msg.frame in (m.MAV_FRAME_GLOBAL_RELATIVE_ALT, m.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                         m.MAV_FRAME_GLOBAL, m.MAV_FRAME_GLOBAL_INT):
            depth = -msg.z
        else:
            depth = reply.z_m if reply else 0.0
        yaw = reply.yaw_deg if reply else 0.0
        self._send("MISSION_ACK", msg.get_srcSystem(), msg.get_srcComponent(), m.MAV_MISSION_ACCEPTED,
                   getattr(msg, "mission_type", 0))
        self._do(None, lambda: self._goto(None, north, east, depth, yaw))

    def _set_interval(self, message_id: int, interval_us: float) -> int:
        m = ardupilotmega
        names = {getattr(m, f"MAVLINK_MSG_ID_{name}"): name for name in STREAMS}
        if message_id == m.MAVLINK_MSG_ID_HEARTBEAT:
            return m.MAV_RESULT_ACCEPTED if interval_us in (0, 1_000_000) else m.MAV_RESULT_DENIED
        if message_id not in names:
            return m.MAV_RESULT_UNSUPPORTED
        name = names[message_id]
        if interval_us < 0:
            self._periods[name] = None
        elif interval_us == 0:
            self._periods[name] = 1.0 / STREAMS[name][0]
        else:
            self._periods[name] = max(0.02, interval_us / 1e6)  # at most 50 Hz
        self._next_at[name] = 0.0
        return m.MAV_RESULT_ACCEPTED

    def _request_data_stream(self, msg) -> None:
        groups = {0: None, 2: "EXTENDED_STATUS", 6: "POSITION", 10: "EXTRA1", 11: "EXTRA2"}
        group = groups.get(msg.req_stream_id, "other")
        for name, (_, its_group) in STREAMS.items():
            if group is None or its_group == group:
                if not msg.start_stop or msg.req_message_rate == 0:
                    self._periods[name] = None
                else:
                    self._periods[name] = 1.0 / min(50, msg.req_message_rate)
                self._next_at[name] = 0.0


class GcsGateway:
    """Every `--gcs` connection of one console."""

    def __init__(self, urls, operator, commands, *, home=(0.0, 0.0)) -> None:
        self.links = [GcsLink(url, operator, commands, home=home) for url in urls]

    def start(self) -> "GcsGateway":
        started = []
        try:
            for link in self.links:
                started.append(link.start())
        except Exception:
            for link in started:
                link.stop()
            raise
        return self

    def stop(self) -> None:
        for link in self.links:
            link.stop()
