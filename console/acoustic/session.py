"""The operator's session on the acoustic link (docs/PROTOCOL.md §9).

Goals: at 64 bit/s and seconds of latency the pilot supervises: everything
shown carries its age and says when the next status is due; every order has
one path (here) and a visible fate (sent, taken, done, rejected with its
reason, cancelled, unknown after a ROV restart); STOP goes first, every time;
the thumbnail refines as its packets come and says "unverified" until its MAC
holds.

Plan: `AcousticSession` owns the sans-I/O `link.acoustic.AcousticOperator`
behind a lock.  `run()` (on the link thread's loop, never the web server's)
moves packets between it and the modem endpoint: received 8-byte packets in,
and, whenever the modem's transmit queue is empty (flushed first when the
machine asks, for a STOP), the machine's next packet out.  The web layer calls
the commands and `state()`; nothing else holds a copy of the state.
"""

from __future__ import annotations

import asyncio
import collections
import dataclasses
import io
import logging
import math
import threading
import time

from rovlink.console.session.recorder import Recorder
from rovlink.link import acoustic as ac
from rovlink.link.aio import recv_within
from rovlink.link.messages import Mode
from rovlink.link.transport import port_change, port_down_reason

log = logging.getLogger("rovlink.console.acoustic")

PACKET = 8
LOST_AFTER_S = 20.0  # no authentic frame this long: the link is lost (the operator then says HELLO again)
MODE_NAMES = {int(m): m.name for m in Mode if m is not Mode.UNKNOWN}
MODE_NAMES[0] = "unknown"
ORDER_OPS = {"hold": ac.OP_HOLD, "surface": ac.OP_SURFACE, "arm": ac.OP_ARM, "disarm": ac.OP_DISARM,
             "mode": ac.OP_MODE}


class AcousticSession:
    """The operator's end of the acoustic link as the page, the ground station
    and the recording see it.  `record`: a JSON-lines file of the session
    ("meta" first, then every packet sent and received as hex, every STATUS
    taken and every line of the log, each with its session time `t`), or None."""

    def __init__(self, endpoint, key: bytes, *, clock=time.monotonic, pace_s: float = 1.0,
                 record=None) -> None:
        self.endpoint = endpoint
        self.clock = clock
        self.pace_s = pace_s
        self.op = ac.AcousticOperator(key)
        self._lock = threading.Lock()
        self._start = clock()
        self.orders: dict[int, dict] = {}  # oid -> its record, as the page shows it
        self._order_seq: list[int] = []
        self.stop_state = {"no": 0, "state": "none", "pressed_at": None, "confirmed_at": None}
        self.status: ac.Status | None = None
        self.status_at: float | None = None  # when it was made (estimated)
        self.status_arrival: float | None = None
        self.synced: dict | None = None
        self.thumb: dict | None = None
        self._thumb_png: bytes | None = None
        self.log: collections.deque = collections.deque(maxlen=200)
        self.inauthentic = 0
        self.alert = False
        self._last_sent = -math.inf
        self.packets_in = self.packets_out = 0
        self._subscribers: list = []
        self._port_up: bool | None = None  # the local modem's port as last seen (None: not yet)
        self.recorder = Recorder(record, {"profile": "acoustic", "pace_s": pace_s,
                                          "started": time.strftime("%Y-%m-%dT%H:%M:%S"),
                                          "wall0": round(time.time(), 3)})

    def close(self) -> None:
        """Close the recording (the link itself belongs to whoever opened it)."""
        self.recorder.close()

    def _t(self, now: float) -> float:
        return round(now - self._start, 3)

    def subscribe(self, callback):
        """callback(topic, payload) for every order fate ("order") and alert ("log"); returns the unsubscribe."""
        self._subscribers.append(callback)
        return lambda: self._subscribers.remove(callback) if callback in self._subscribers else None

    def _publish(self, topic: str, payload: dict) -> None:
        for cb in list(self._subscribers):
            try:
                cb(topic, payload)
            except Exception:  # a subscriber's bug never stops the link
                log.exception("acoustic subscriber failed")

    # -- the link --------------------------------------------------------------

    async def run(self) -> None:
        pump = asyncio.create_task(self._pump())
        try:
            while True:
                data = await recv_within(self.endpoint, 0.1)
                if not data:
                    continue
                now = self.clock()
                for i in range(0, len(data) - PACKET + 1, PACKET):
                    packet = bytes(data[i:i + PACKET])
                    with self._lock:
                        self.packets_in += 1
                        self.recorder.write({"k": "rx", "t": self._t(now), "hex": packet.hex()})
                        events = self.op.receive(packet, now)
                        self._handle(events, now)
        finally:
            pump.cancel()

    def _watch_port(self) -> None:
        """The local modem's port going down (unplugged, its adapter gone) is said at
        once, loudly, with the transport's reason, not 20 s later as a lost link;
        and its coming back.  (Lock held.)"""
        self._port_up, news = port_change(self.endpoint, self._port_up)
        if news is not None:
            self._note(news, "info" if self._port_up else "alert")

    async def _pump(self) -> None:
        while True:
            now = self.clock()
            with self._lock:
                self._watch_port()
                self._handle(self.op.tick(now), now)
                if self.op.wants_flush:
                    flush = getattr(self.endpoint, "flush", None)
                    if flush is not None:
                        flush()
                ready = self.op.wants_flush or ac.modem_idle(self.endpoint, now, self._last_sent, self.pace_s)
                packet = self.op.next_packet(now) if ready else None
            if packet is not None:
                self.endpoint.send(packet)
                self._last_sent = now
                self.packets_out += 1
                self.recorder.write({"k": "tx", "t": self._t(now), "hex": packet.hex()})
            await asyncio.sleep(0.1)

    # -- what happened ---------------------------------------------------------

    def _note(self, text: str, level: str = "info") -> None:
        now = self.clock()
        self.log.append({"t": round(now - self._start, 1), "text": text, "level": level})
        self.recorder.write({"k": "note", "t": self._t(now), "text": text, "level": level})
        (log.warning if level == "alert" else log.info)("%s", text)

    def _handle(self, events: list, now: float) -> None:
        for e in events:
            if isinstance(e, ac.Synced):
                self.synced = {"boot": e.boot.hex(), "failsafe_s": e.failsafe_s,
                               "failsafe_action": "surface" if e.failsafe_action == ac.FAILSAFE_SURFACE else "hold",
                               "at": now}
                self._note("ROV restarted (new BOOT): the fate of an order in flight is unknown"
                           if e.restarted else "link synchronised", "alert" if e.restarted else "info")
            elif isinstance(e, ac.StatusReceived):
                self._status_changes(self.status, e.status)
                self.recorder.write({"k": "status", "t": self._t(now), "made_t": self._t(e.at), "ctr": e.ctr,
                                     **dataclasses.asdict(e.status)})
                self.status, self.status_at, self.status_arrival = e.status, e.at, now
            elif isinstance(e, ac.OrderFate):
                rec = self.orders.get(e.oid)
                if rec is not None and (rec["state"] != e.state or rec["reason"] != e.reason):
                    rec.update(state=e.state, reason=e.reason, settled_at=now)
                    self._publish("order", {"kind": rec["text"], "state": e.state + (f": {e.reason}" if e.reason else "")})
                    self._note(f"{rec['text']}: {e.state}" + (f" ({e.reason})" if e.reason else ""),
                               "warn" if e.state in ("rejected", "aborted", "unknown", "cancelled") else "info")
            elif isinstance(e, ac.StopConfirmed):
                self.stop_state.update(state="confirmed", confirmed_at=now)
                self._note(f"STOP confirmed: holding, {now - e.pressed_at:.1f} s after it was pressed")
            elif isinstance(e, ac.StopNotCarriedOut):
                self.stop_state.update(state="not carried out")
                self._note("STOP not carried out: no autopilot holds the vehicle", "alert")
            elif isinstance(e, ac.ThumbnailProgress):
                self._thumb_update(e.oid, e.prefix, e.verified, now)
            elif isinstance(e, ac.ThumbnailComplete):
                self._thumb_update(e.oid, e.object, e.verified, now)
                self._note(f"thumbnail {e.oid} complete, {len(e.object)} bytes, verified")
            elif isinstance(e, ac.ThumbnailRejected):
                self.thumb = None
                self._thumb_png = None
                self._note(f"thumbnail {e.oid} failed its MAC: discarded, asked for again", "alert")
            elif isinstance(e, ac.InauthenticPacket):
                self.inauthentic += 1
                if e.alert and not self.alert:
                    self._note("ALERT: packets fail authentication and no authentic one comes "
                               "(another key or operator, a forger, or heavy noise)", "alert")
                self.alert = e.alert
            elif isinstance(e, ac.Resyncing):
                self._note(f"link lost ({e.why}): synchronising again", "alert")

    def _status_changes(self, was: ac.Status | None, now: ac.Status) -> None:
        """What a STATUS tells that the last one did not, into the log: the
        FAILSAFE (shown in one STATUS after a spell, so that it is never missed),
        the ROV not hearing us, the autopilot lost.  The status table shows only
        the present; the log keeps what happened."""
        def changed(flag: str) -> bool | None:
            value = getattr(now, flag)
            return value if was is None or getattr(was, flag) != value else None

        failsafe = changed("failsafe")
        if failsafe:
            action = "surfaces" if (self.synced or {}).get("failsafe_action") == "surface" else "holds position"
            self._note(f"ROV in FAILSAFE: it heard nothing from us for its failsafe time and {action}", "alert")
        elif failsafe is False and was is not None:  # only a way out of a FAILSAFE it showed
            self._note("ROV out of FAILSAFE: it hears us again (HOLD stays until a new order)", "warn")
        hears = changed("uplink")
        if hears is False:
            self._note("ROV does NOT hear us: it took nothing from us for 10 s", "alert")
        elif hears and was is not None:
            self._note("ROV hears us again")
        autopilot = changed("autopilot")
        if autopilot is False:
            self._note("ROV reports its autopilot LOST: orders cannot be carried out", "alert")
        elif autopilot and was is not None:
            self._note("ROV's autopilot is back")

    def _thumb_update(self, oid: int, obj: bytes, verified: bool, now: float) -> None:
        total = int.from_bytes(obj[:2], "big") + 2 if len(obj) >= 2 else None
        self.thumb = {"oid": oid, "bytes": len(obj), "total": total, "verified": verified, "at": now,
                      "requested_at": (self.orders.get(oid) or {}).get("sent_at")}
        self._thumb_png = _png(obj) if len(obj) > 2 else None

    # -- the pilot's orders: one path ------------------------------------------

    def press_stop(self) -> dict:
        with self._lock:
            now = self.clock()
            no = self.op.stop(now)
            self.stop_state.update(no=no, state="sent", pressed_at=now, confirmed_at=None)
            for rec in self.orders.values():
                if rec["state"] in ("queued",):
                    rec.update(state="not sent", reason="a STOP cancelled it", settled_at=now)
        self._note(f"STOP {no} pressed: sent first, in every slot until confirmed")
        return dict(self.stop_state)

    def order(self, what: str, mode: str | None = None) -> dict:
        if what not in ORDER_OPS:
            raise ValueError(f"unknown order {what!r}: one of {', '.join(ORDER_OPS)}")
        arg = 0
        text = what
        if what == "mode":
            names = {n.lower(): v for v, n in MODE_NAMES.items() if v}
            if mode is None or mode.lower() not in names:
                raise ValueError(f"mode must be one of {', '.join(sorted(names))}")
            arg = names[mode.lower()]
            text = f"mode {mode.upper()}"
        return self._send(ac.Order(0, ORDER_OPS[what], arg), text)

    def goto(self, x_m: float, y_m: float, z_m: float, yaw_deg: float | None = None, *, relative: bool = False,
             body: bool = False) -> dict:
        for name, v in (("x", x_m), ("y", y_m), ("z", z_m)):
            if not math.isfinite(v) or abs(v) > 3276.7:
                raise ValueError(f"{name} must be a finite number of metres within ±3276.7")
        if yaw_deg is not None and not (math.isfinite(yaw_deg) and -180.0 <= yaw_deg <= 180.0):
            raise ValueError("yaw must be within -180..180 degrees")
        if body and not relative:
            raise ValueError("a body-frame go-to is relative")
        target = ac.GoTo(0, round(x_m * 10), round(y_m * 10), round(z_m * 10),
                         0 if yaw_deg is None else round(yaw_deg * 100), relative, body, yaw_deg is not None)
        text = (f"go to {'+' if relative else ''}({x_m:.1f}, {y_m:.1f}, {z_m:.1f}) m"
                + ("" if yaw_deg is None else f", yaw {yaw_deg:.0f}°") + (" body" if body else ""))
        return self._send(target, text, target={"x_m": x_m, "y_m": y_m, "z_m": z_m, "yaw_deg": yaw_deg,
                                                 "relative": relative, "body": body})

    def thumbnail(self, budget: int = 198, roi: tuple[int, int, int, int] | None = None, shift: int = 4) -> dict:
        if not ac.MIN_BUDGET <= budget <= ac.MAX_BUDGET:
            raise ValueError(f"budget must be {ac.MIN_BUDGET}..{ac.MAX_BUDGET} bytes")
        if roi is not None:
            x0, y0, x1, y1 = roi
            if not (0 <= x0 < x1 <= ac.THUMB_W and 0 <= y0 < y1 <= ac.THUMB_H):
                raise ValueError(f"roi must be x0 < x1 <= {ac.THUMB_W}, y0 < y1 <= {ac.THUMB_H}, none below 0 "
                                 f"(pixels of the {ac.THUMB_W}x{ac.THUMB_H} thumbnail, x1 and y1 exclusive), "
                                 f"not {tuple(roi)}")
        req = ac.ThumbRequest(0, budget, roi or (0, 0, 0, 0), shift if roi else 0, True)
        bad = req.invalid()
        if bad:
            raise ValueError(f"thumbnail: {bad}")
        return self._send(req, f"thumbnail {budget} B" + (f", ROI {roi}" if roi else ""))

    def _send(self, body, text: str, target: dict | None = None) -> dict:
        with self._lock:
            now = self.clock()
            try:
                oid = self.op.send_order(body, now)
            except ac.OrderRefused as exc:
                raise PermissionError(str(exc)) from None
            rec = {"oid": oid, "text": text, "state": "queued", "reason": "", "sent_at": now, "settled_at": None,
                   "target": target}
            self.orders[oid] = rec
            self._order_seq.append(oid)
            for old in self._order_seq[:-50]:
                self.orders.pop(old, None)
            del self._order_seq[:-50]
        self._note(f"{text}: queued (order {oid})")
        return dict(rec)

    # -- what the page shows ---------------------------------------------------

    def _shown(self, rec: dict) -> dict:
        out = dict(rec)
        if rec["state"] == "queued" and self.op.sending_oid == rec["oid"]:
            out["state"] = "sending"  # on the air, repeated until a status names it
        return out

    def thumbnail_png(self) -> bytes | None:
        return self._thumb_png

    def state(self) -> dict:
        with self._lock:
            now = self.clock()
            op = self.op
            heard = op.last_authentic_at
            silent = None if heard is None else now - heard
            link = ("starting" if heard is None and now - self._start < LOST_AFTER_S else
                    "lost" if silent is None or silent >= LOST_AFTER_S else "up")
            status = None
            if self.status is not None:
                s = self.status
                status = {
                    "x_m": s.x_dm / 10, "y_m": s.y_dm / 10, "depth_m": s.z_dm / 10, "heading_deg": s.heading_cdeg / 100,
                    "armed": s.armed, "hold": s.hold, "failsafe": s.failsafe, "position_valid": s.position_valid,
                    "attitude_valid": s.attitude_valid, "autopilot": s.autopilot, "going": s.going,
                    "rov_hears_us": s.uplink,
                    "mode": MODE_NAMES.get(s.mode, str(s.mode)),
                    "battery_v": s.battery_dv / 10 if s.battery_dv else None,
                    "age_s": round(now - self.status_at, 1) if self.status_at is not None else None,
                    "stale": self.status_arrival is None or now - self.status_arrival > 10.0,
                }
            next_at = op.next_status_at
            return {
                "profile": "acoustic",
                "t": round(now - self._start, 1),
                "link": {"state": link, "since_authentic_s": None if silent is None else round(silent, 1),
                         "port": "down" if self._port_up is False else "up",
                         "port_error": port_down_reason(self.endpoint) if self._port_up is False else None,
                         "synced": self.synced is not None and not op.resyncing,
                         "packets_in": self.packets_in, "packets_out": self.packets_out,
                         "inauthentic": self.inauthentic, "alert": self.alert},
                "rov": self.synced,
                "status": status,
                "next_status_in_s": None if next_at is None else round(max(0.0, next_at - now), 1),
                "stop": dict(self.stop_state),
                "orders": [self._shown(self.orders[o]) for o in self._order_seq if o in self.orders][-20:],
                "ready": op.ready,
                "thumbnail": None if self.thumb is None else dict(self.thumb, age_s=round(now - self.thumb["at"], 1)),
                "log": list(self.log)[-30:],
            }


def _png(obj: bytes) -> bytes | None:
    """The picture a thumbnail object's prefix holds, as PNG (None if it holds none yet)."""
    try:
        import numpy as np
        from PIL import Image

        from rovlink import debt

        picture = np.asarray(debt.decode(bytes(obj[2:])))
        out = io.BytesIO()
        Image.fromarray(picture.astype(np.uint8)).resize((picture.shape[1] * 4, picture.shape[0] * 4),
                                                          Image.NEAREST).save(out, "PNG")
        return out.getvalue()
    except Exception:  # a prefix too short to be a picture yet
        return None
