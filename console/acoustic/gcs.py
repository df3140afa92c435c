"""The MAVLink ground-station gateway (console/gcs.py) over the acoustic link.

Goal: the pilot's own ground station (QGroundControl, Cockpit) on the acoustic
profile as on the radio one: a HEARTBEAT with the last status's arming and
mode, the position and depth while they are fresh, STATUSTEXT for link loss
and refused orders; ARM/DISARM, modes, a GUIDED go-to or a position target,
and DO_PAUSE_CONTINUE as STOP, each answered with its real fate.  There are no
sticks at 64 bit/s: MANUAL_CONTROL moves nothing (the HEARTBEAT shows it).

Plan: the gateway reads a session through five things (`subscribe`,
`link_condition`, `last_reply`, `link_state`, `orders_state`) and orders through
a commands object; `AcousticGcsView` and `AcousticCommands` give it those from
an `AcousticSession`, whose one command path every order still takes.  The
status becomes a version 1.1 `Reply` the gateway already reads: its heading as
the yaw, roll and pitch unknown (the acoustic status carries none), so no
ATTITUDE is made up; a status older than 10 s counts as a lost link, so
nothing stale is streamed as current.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega

from rovlink.console.gcs import CommandRefused
from rovlink.link.messages import Reply

from .session import AcousticSession

STATE_FOR_GCS = {"done": "acknowledged", "taken": "taken", "queued": "sent", "sending": "sent"}


class AcousticGcsView:
    def __init__(self, session: AcousticSession) -> None:
        self.session = session

    def subscribe(self, callback):
        return self.session.subscribe(callback)

    def link_condition(self) -> tuple[str, float | None]:
        st = self.session.state()
        status = st["status"]
        if st["link"]["state"] == "up" and status is not None and not status["stale"]:
            return "up", st["link"]["since_authentic_s"]
        return ("starting" if st["link"]["state"] == "starting" else "lost"), st["link"]["since_authentic_s"]

    @property
    def last_reply(self) -> Reply | None:
        s = self.session.status
        if s is None:
            return None
        yaw = s.heading_cdeg if s.heading_cdeg <= 18000 else s.heading_cdeg - 36000
        clamp = lambda v: max(-32768, min(32767, v))  # noqa: E731
        return Reply(armed=s.armed, mode=s.mode, x_cm=clamp(s.x_dm * 10), y_cm=clamp(s.y_dm * 10),
                     z_cm=clamp(s.z_dm * 10), yaw_cdeg=yaw, autopilot=s.autopilot, failsafe=s.failsafe,
                     position_valid=s.position_valid, attitude_valid=False, hold=s.hold)

    def link_state(self) -> dict:
        st = self.session.state()["link"]
        return {"polls_sent": st["packets_out"], "replies_lost": 0, "crc_errors": st["inauthentic"]}

    def orders_state(self) -> list[dict]:
        out = []
        for rec in self.session.state()["orders"]:
            state = STATE_FOR_GCS.get(rec["state"], rec["state"])
            if rec["state"] in ("rejected", "aborted", "cancelled", "not sent", "unknown", "untracked"):
                state = ("refused" if rec["state"] == "aborted" else rec["state"]) + (f": {rec['reason']}" if rec["reason"] else "")
            out.append({"id": rec["oid"], "state": state, "kind": rec["text"]})
        stop = self.session.state()["stop"]
        if stop["no"]:
            state = {"confirmed": "acknowledged", "not carried out": "not carried out"}.get(stop["state"], "sent")
            out.append({"id": -stop["no"], "state": state, "kind": "STOP"})
        return out


class AcousticCommands:
    """The gateway's orders, through the acoustic session's one path."""

    name = "ground station"

    def __init__(self, session: AcousticSession) -> None:
        self.session = session

    def _refused(self, exc: Exception) -> CommandRefused:
        m = ardupilotmega
        return CommandRefused(m.MAV_RESULT_TEMPORARILY_REJECTED if isinstance(exc, PermissionError)
                              else m.MAV_RESULT_DENIED, str(exc))

    def velocity(self, vx: float, vy: float, vz: float, vyaw: float) -> None:
        raise CommandRefused(ardupilotmega.MAV_RESULT_DENIED, "no sticks on the acoustic link: send targets")

    def arm(self, armed: bool) -> int:
        try:
            return self.session.order("arm" if armed else "disarm")["oid"]
        except (ValueError, PermissionError) as exc:
            raise self._refused(exc) from None

    def mode(self, name: str) -> int:
        try:
            return self.session.order("mode", name)["oid"]
        except (ValueError, PermissionError) as exc:
            raise self._refused(exc) from None

    def goto(self, x_m: float, y_m: float, z_m: float, yaw_deg: float) -> int:
        try:
            return self.session.goto(x_m, y_m, z_m, yaw_deg)["oid"]
        except (ValueError, PermissionError) as exc:
            raise self._refused(exc) from None

    def stop(self) -> int:
        return -self.session.press_stop()["no"]

    def order_state(self, order_id: int) -> str | None:
        for info in AcousticGcsView(self.session).orders_state():
            if info["id"] == order_id:
                return info["state"]
        return None

    def heard(self) -> None:
        pass

    def release(self) -> None:
        pass
