"""The operator's session on the acoustic link (docs/PROTOCOL.md §9), on the
same parts and the same contract as the radio one (console/session/contract.py).

Goals: at 64 bit/s and seconds of latency the pilot supervises, in the same
cockpit as on the radio link: the received pose with its age in the 3-D
scene, a go-to previewed then sent and followed to "arrived", STOP first
every time, the thumbnail refining and marked unverified until its MAC holds,
one holder of control (the control desk), one log, one recording that
`rovlink replay` plays back.  What the link cannot carry (sticks, "next
picture") is absent from `capabilities` and refused with a reason.

Plan: `AcousticSession` owns the sans-I/O `link.acoustic.AcousticOperator`
behind the session's lock.  `run()` (on the link thread's loop, never the web
server's) moves packets between it and the modem endpoint: received 8-byte
packets in, and whenever the modem's transmit queue is empty (flushed first
when the machine asks, for a STOP) the machine's next packet out.  What the
machine says happened is handed to the session's parts: each STATUS, made SI
by link/report.py, to the odometry (and the go-to watch, the trail, the
health: the link is lost after 20 s without an authentic frame); order fates
to the order book as the same `Fate`s as the radio's (queued, sent, acknowledged,
arrived, rejected with its reason...; an arm or mode is followed when a status shows it); thumbnails to the image receiver, as the radio
session's pictures.  Under `rovlink console` the machine, the modem and the
pacing run in a process of their own (`link=`: link/acoustic/process.py
AcousticLinkProcess, which stands in for the machine): `run()` then only takes
what it tells; its end is said at once (`link_process` in the link state, an
alert), what it held and the ROV had not answered is shown unknown, a STOP is
pressed again in the next one.  A replay (`rovlink replay` of an acoustic recording)
feeds the recorded statuses, thumbnails, orders and log lines back through
`replayed`, with no link and no key.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict
from typing import Any, Callable

from rovlink.console.session.base import NotNow, OrderError, SessionBase, mode_of
from rovlink.console.session.contract import Capabilities
from rovlink.console.session.fates import Fate
from rovlink.console.session.goto import GoToWatch
from rovlink.console.session.health import LinkHealth
from rovlink.console.session.images import ImageReceiver
from rovlink.console.session.odometry import History, LogLine, Odometry, Pose
from rovlink.console.session.orders import OrderBook
from rovlink.console.session.predictor import preview_path
from rovlink.console.session.recorder import Recorder
from rovlink.console.session.world import SeenWorld
from rovlink.link import acoustic as ac
from rovlink.link.acoustic.process import AcousticLinkProcess
from rovlink.link.acoustic.pump import AcousticPump
from rovlink.link.pictures import ImageAbandoned, ImageComplete, ImageProgress
from rovlink.link.process import LinkProcessDown, LinkProcessSlow
from rovlink.link.report import VehicleReport, report_from_status
from rovlink.link.transports.transport import port_down_reason
from rovlink.link.units import acoustic_goto
from rovlink.link.vocabulary import FollowRequest, PictureRequest

log = logging.getLogger("rovlink.console.acoustic")

PACKET = ac.PACKET_BYTES
LOST_AFTER_S = ac.SILENCE_RESYNC_S  # no authentic frame this long: the link is lost (the operator says HELLO again)
NEUTRAL = (0.0, 0.0, 0.0, 0.0)
DEFAULT_THUMB = PictureRequest(roi=None, shift=4, mono=True, budget_bytes=198)


class AcousticSession(SessionBase):
    """The operator's end of the acoustic link, as every surface of the console
    sees a session (console/session/contract.py), on the ground every session
    stands on (console/session/base.py).  `endpoint` None and `key` None: a
    replay.  `record`: a JSON-lines file of the session, or None."""

    _logger = log

    capabilities = Capabilities(profile="acoustic", velocity=False, next_image=False, follow=True, picture="thumbnail",
                                image_budget_max=ac.MAX_BUDGET, report_every_s=ac.STATUS_IDLE_S,
                                picture_px=(ac.THUMB_W, ac.THUMB_H), follow_newest_frame=0)

    def __init__(self, endpoint, key: bytes | None, *, clock: Callable[[], float] = time.monotonic,
                 pace_s: float = 1.0, record=None, link: AcousticLinkProcess | None = None) -> None:
        if link is not None:
            # The machine, the modem and the pacing run in the link process (link/acoustic/process.py),
            # on CLOCK_MONOTONIC: the session reads the same clock, so the machine's times are its own.
            endpoint, clock = endpoint or link.port, time.monotonic
        self.endpoint = endpoint
        self._start_session(clock, decoder="debt-decode (thumbnails)", warm_up="debt-warm-up (acoustic console)")
        self.pace_s = pace_s
        self.op: Any = link if link is not None else ac.AcousticOperator(key) if key is not None else None
        self._stop_pending = False  # a STOP pressed while no link process ran: pressed again in the next
        self.rov_failsafe_s = float(ac.FAILSAFE_S)  # until the ROV's SYNC says its own
        self.failsafe_action = "hold"
        self.link_version = "acoustic"
        self.bitrate_bps, self.delay_s = 64.0, 0.0  # what a replay's meta may carry; unused here
        self.packets_in = self.packets_out = 0
        self.recorder = Recorder(record, {"profile": "acoustic", "pace_s": pace_s,
                                          "started": time.strftime("%Y-%m-%dT%H:%M:%S"),
                                          "wall0": round(self.wall0, 3)})
        self._new_parts(replaying=False)

    def _new_parts(self, *, replaying: bool) -> None:
        self.history = History()
        self.health = LinkHealth(history=self.history, note=self.note, clear=self.clear_alerts)
        self.health.lost_after_s = LOST_AFTER_S
        self.health.replaying = replaying
        self.odometry = Odometry()
        self.images = ImageReceiver(lock=self._lock, now=self.now, wall=self.wall, fix=lambda: self.odometry.fix,
                                    record=self.recorder.write, publish=self._publish, note=self.note,
                                    decoder=self._decoder, settings=DEFAULT_THUMB)
        self.orders = OrderBook(lock=self._lock, record=self.recorder.write, publish=self._publish, note=self.note)
        self.goto = GoToWatch(self.orders)
        self.world = SeenWorld(lock=self._lock, record=self.recorder.write, publish=self._publish, note=self.note)
        self.requested_settings = DEFAULT_THUMB
        self._by_oid: dict[int, tuple[int, str, Any]] = {}  # OID -> (console order id, kind, settings)
        self._stop_order: int | None = None  # the console's id of the STOP being sent
        self._stop_no: int | None = None
        self._verified: dict[int, bool] = {}  # thumbnail OID -> its MAC held
        self._heard_at: float | None = None  # the machine's last authentic frame, as last handed to health
        self._alerting = False

    def _start_over(self) -> None:
        """`reset`'s: the parts made anew, a replay's switch kept (lock held)."""
        self._new_parts(replaying=self.health.replaying)

    def _noted(self, line: LogLine) -> None:
        """A log line is recorded (a replay shows it as it was) and said in the console's log."""
        self.recorder.write({"k": "note", "t": round(line.t, 3), "text": line.text, "level": line.level,
                             "cause": line.cause})
        (log.warning if line.level == "alert" else log.info)("%s", line.text)

    # ------------------------------------------------------------------
    # The link
    # ------------------------------------------------------------------

    async def run(self) -> None:
        if isinstance(self.op, AcousticLinkProcess):
            try:
                await self.op.run(on_packet=self._packet_in, on_sent=self._packet_out, on_events=self._events_in,
                                  on_turn=self._turn, on_up=self._link_process_up, on_down=self._link_process_down)
            finally:
                self._decoder.shutdown()
            return
        if self.op is None or self.endpoint is None:
            raise RuntimeError("no link: this session only replays")
        try:
            await self.pump().run()
        finally:
            self._decoder.shutdown()

    def pump(self) -> AcousticPump:
        """The machine kept here (the tests' stacks): the one pump of link/acoustic/pump.py, on
        the session's clock; what it tells comes in by the same doors as a link process's news."""
        return AcousticPump(self.op, self.endpoint, lock=self._lock, clock=self._clock, pace_s=self.pace_s,
                            on_received=self._packet_in, on_sent=self._packet_out, on_events=self._events_in,
                            before_tick=lambda now: self._turn())

    # -- what the link process (link/acoustic/process.py) or the pump tells -------
    # Times handed here are the machine's clock (the session's, CLOCK_MONOTONIC in a link process).

    def _packet_in(self, packet: bytes, events: list, now: float) -> None:
        t = now - self._t0
        with self._lock:
            self.packets_in += 1
            self.recorder.write({"k": "rx", "t": round(t, 4), "hex": packet.hex()})
            self.health.event(t, "rx", PACKET)
            self._heard(t)
            self._handle(events, t)

    def _packet_out(self, packet: bytes, now: float) -> None:
        t = now - self._t0
        with self._lock:
            self._mark_sending()
            self.packets_out += 1
            self.recorder.write({"k": "tx", "t": round(t, 4), "hex": packet.hex()})
            self.health.event(t, "tx", PACKET)

    def _events_in(self, events: list, now: float) -> None:
        with self._lock:
            self._handle(events, now - self._t0)

    def _turn(self) -> None:
        with self._lock:
            self._watch_port()
            self.health.watch(self.now())

    def _link_process_down(self, why: str) -> None:
        """The link process ended: said at once, and nothing its machine held is shown
        done.  Orders the ROV had not taken are unknown (it may have: they are not
        sent again), and those it took whose outcome only that machine would have
        told (a go-to is still followed from the statuses); a STOP not confirmed is
        pressed again in the next one; a thumbnail half in is abandoned."""
        t = self.now()
        self.note(f"LINK PROCESS DOWN: {why}; starting it again (nothing is sent to the ROV meanwhile)", "alert",
                  cause="process")
        with self._lock:
            for order_id, kind, _ in list(self._by_oid.values()):
                fate = self.orders.fate(order_id)
                if fate is None or fate.ended:
                    continue
                if fate is not Fate.ACKNOWLEDGED:
                    self.orders.set_state(order_id, Fate.UNKNOWN, t,
                                          "the link process ended before the ROV answered; not sent again")
                elif kind != "POSITION":
                    self.orders.set_state(order_id, Fate.UNKNOWN, t,
                                          "the link process ended before the ROV told its outcome")
            self._by_oid.clear()  # the next machine's OIDs are its own
            stop = self.orders.fate(self._stop_order)
            if stop is not None and stop.pending:
                self._stop_pending = True
                self.orders.set_state(self._stop_order, Fate.QUEUED, t)  # waits for the next link process
            self._heard_at = None
            v = self.images.view
            partial = v.img is not None and not v.complete and v.received_bytes > 0
            if partial:
                self.images.on_event(ImageAbandoned(v.img, v.received_bytes, "the link process ended"), t)
        self._publish("link", self.link_state())

    def _link_process_up(self, pid: int) -> None:
        t = self.now()
        self._link_starts += 1
        if self._link_starts > 1:
            self.note(f"link process started again (pid {pid})")
            self.clear_alerts("process")
        pressed = None
        with self._lock:
            again, self._stop_pending = self._stop_pending, False
            order_id = self._stop_order
        if again:  # a STOP the pilot pressed is never lost with a process
            try:
                pressed = self.op.stop(self._clock())
            except LinkProcessSlow as slow:
                slow.when_answered(lambda no: self._stop_told(order_id, int(no)),
                                   lambda text: self.orders.set_state(order_id, Fate.REFUSED, self.now(), text),
                                   lambda why: None)
            except (LinkProcessDown, ValueError) as exc:
                self.orders.set_state(order_id, Fate.UNKNOWN, t, f"not sent again ({exc})")
            else:
                with self._lock:
                    self._stop_no = pressed
                    self.orders.update(order_id, stop_no=pressed)
                    self.orders.set_state(order_id, Fate.SENT, t)
        if pressed is not None:
            self.note(f"STOP pressed again in the new link process (STOP {pressed}): sent first, in every slot "
                      "until confirmed")
        self._publish("link", self.link_state())

    def _heard(self, t: float) -> None:
        """An authentic frame came (the machine's clock moved): the link is up."""
        heard = self.op.last_authentic_at
        if heard is not None and heard != self._heard_at:
            self._heard_at = heard
            self.health.reply(t, None)
            self.health.watch(t)

    def _mark_sending(self) -> None:
        """The order on the air is "sent" (repeated until a STATUS names it)."""
        oid = self.op.sending_oid
        if oid is not None and oid in self._by_oid:
            self.orders.sent(self._by_oid[oid][0], self.now())

    # ------------------------------------------------------------------
    # What the machine says happened (lock held)
    # ------------------------------------------------------------------

    def _handle(self, events: list, t: float) -> None:
        for e in events:
            if isinstance(e, ac.SessionSynced):
                self.rov_failsafe_s = float(e.failsafe_s)
                self.failsafe_action = "surface" if e.failsafe_action == ac.FAILSAFE_SURFACE else "hold"
                self.recorder.write({"k": "synced", "t": round(t, 4), "restarted": e.restarted,
                                     "failsafe_s": e.failsafe_s, "failsafe_action": self.failsafe_action})
                if e.restarted:
                    self.follow_refused = None
                    self.note("ROV restarted (new BOOT): the fate of an order in flight is unknown", "alert")
                else:
                    self.note(f"link synchronised (the ROV {'surfaces' if self.failsafe_action == 'surface' else 'holds'}"
                              f" after {e.failsafe_s} s without us)")
            elif isinstance(e, ac.StatusReceived):
                # The machine dates it on its own clock: the same offset to session time (a link
                # process's clock is the session's, read when the packet came, not when told of it).
                made = (e.at - self._t0 if isinstance(self.op, AcousticLinkProcess)
                        else t - (self._clock() - e.at) if self.op is not None else e.at)
                report = report_from_status(e.status, sampled_at=made, arrived_at=t)
                self._status(report, e.status.uplink, t)
            elif isinstance(e, ac.OrderFate):
                self._fate(e.oid, e.state, e.reason, t)
            elif isinstance(e, ac.StopTaken):
                # (pressed_at is the machine's clock; t + t0 is when the packet that told it came)
                self._stop_fate(Fate.ACKNOWLEDGED, t, f"holding, {t + self._t0 - e.pressed_at:.1f} s after it was pressed")
            elif isinstance(e, ac.StopImpossible):
                self._stop_fate(Fate.NOT_CARRIED_OUT, t, "no autopilot holds the vehicle")
            elif isinstance(e, ac.ThumbnailProgress):
                self._thumbnail(e.oid, e.prefix, e.verified, t, complete=False)
            elif isinstance(e, ac.ThumbnailComplete):
                self._thumbnail(e.oid, e.object, e.verified, t, complete=True)
            elif isinstance(e, ac.ThumbnailRejected):
                self.recorder.write({"k": "thumb_rejected", "t": round(t, 4), "oid": e.oid})
                self.images.on_event(ImageAbandoned(e.oid, self.images.view.received_bytes,
                                                    "its MAC did not hold: discarded, asked for again"), t)
                self.note(f"thumbnail {e.oid} failed its MAC: discarded, asked for again", "alert")
            elif isinstance(e, ac.InauthenticPacket):
                self.health.inauthentic_frames += 1
                self.health.event(t, "forged")
                if e.alert and not self._alerting:
                    self.note("ALERT: packets fail authentication and no authentic one comes "
                              "(another key or operator, a forger, or heavy noise)", "alert")
                self._alerting = e.alert
            elif isinstance(e, ac.Resyncing):
                self.note(f"link lost ({e.why}): synchronising again", "alert", cause="link")
            elif isinstance(e, ac.SceneAltitude):  # §11.2: what the ROV measured of the world
                fix = self.odometry.fix
                self.world.altitude(e.altitude_m, t, None if fix is None else fix.report.z_m)
            elif isinstance(e, ac.SceneObjectReported):
                self.world.object_seen(e.obj, e.record_bytes, t)
            elif isinstance(e, ac.SceneObjectRemoved):
                self.world.object_removed(e.object_id, t)
            elif isinstance(e, ac.SceneRecordIgnored):
                self.world.record_ignored(e.record_hex, t)

    def _status(self, report: VehicleReport, uplink: bool | None, t: float) -> None:
        previous = self.odometry.take(report, None)
        self.world.depth(report.z_m)
        was = None if previous is None else previous.report
        pose = Pose.from_report(report)
        self.history.trail.append((t, pose.x_m, pose.y_m, pose.z_m))
        record = {"k": "status", "t": round(t, 4), **{k: (round(v, 3) if isinstance(v, float) else v)
                                                       for k, v in asdict(report).items()}}
        if uplink is not None:
            record["uplink"] = uplink
        self.recorder.write(record)
        self._changes(was, report, uplink)
        self.goto.on_reply(self.odometry.fix, t)
        self.orders.check_requests(self.odometry.fix, t)  # an arm or mode the status shows followed
        self._publish("pose", self.pose_state())

    def _changes(self, was: VehicleReport | None, now: VehicleReport, uplink: bool | None) -> None:
        """What a STATUS tells that the last one did not, into the log (only
        changes: a first STATUS without FAILSAFE says nothing of it)."""
        if now.failsafe and (was is None or not was.failsafe):
            action = "surfaces" if self.failsafe_action == "surface" else "holds position"
            self.note(f"ROV in FAILSAFE: it heard nothing from us for its failsafe time and {action}", "alert",
                      cause="failsafe")
        elif was is not None and was.failsafe and not now.failsafe:
            self.clear_alerts("failsafe")
            self.note("ROV out of FAILSAFE: it hears us again (HOLD stays until a new order)", "warn")
        if uplink is False and (self._last_uplink is not False):
            self.note("ROV does NOT hear us: it took nothing from us for 10 s", "alert")
        elif uplink and self._last_uplink is False:
            self.note("ROV hears us again")
        self._last_uplink = uplink
        if was is not None and was.autopilot != now.autopilot:
            if now.autopilot:
                self.note("ROV's autopilot is back")
            else:
                self.note("ROV reports its autopilot LOST: orders cannot be carried out", "alert")

    _last_uplink: bool | None = None

    def _fate(self, oid: int, state: str, reason: str, t: float) -> None:
        known = self._by_oid.get(oid)
        if known is None:
            return
        order_id, kind, settings = known
        fate = self.orders.fate(order_id)
        if fate is None or (fate.ended and not (fate is Fate.UNKNOWN and kind in ("ARM", "DISARM", "MODE"))):
            return
        if state == "taken":
            if fate is not Fate.ACKNOWLEDGED:
                self.orders.set_state(order_id, Fate.ACKNOWLEDGED, t)
                if kind == "IMAGE":
                    fix = self.odometry.fix
                    self.images.captured_after(t, None if fix is None else fix.pose)
                    self.images.confirmed_settings = settings
            if kind == "POSITION":
                self.goto.on_reply(self.odometry.fix, t)
        elif state == "done":
            if kind == "POSITION":
                if self.goto.active is not None and self.goto.active.order_id == order_id:
                    self.goto.active = None
                self.orders.set_state(order_id, Fate.ARRIVED, t)
            elif kind in ("ARM", "DISARM", "MODE"):
                self.orders.set_state(order_id, Fate.FOLLOWED, t)
            else:
                self.orders.set_state(order_id, Fate.DONE, t)
        elif state == "not sent":
            self.orders.set_state(order_id, Fate.CANCELLED, t, f"{reason or 'never sent'} (never sent)")
        elif state == "aborted" and kind == "POSITION":
            if self.goto.active is not None and self.goto.active.order_id == order_id:
                self.goto.abort(reason or "the ROV gave it up", t)
            else:
                self.orders.set_state(order_id, Fate.ABORTED, t, reason)
        elif state == "unknown" and kind in ("ARM", "DISARM", "MODE") and fate is Fate.UNKNOWN:
            return  # said already; the statuses may yet show it followed
        elif state == "untracked":
            # A later order took its place in STATUS.  A go-to, an arm or a mode is still
            # followed from the statuses and a thumbnail from its packets; anything else
            # will never be told.
            if kind not in ("POSITION", "ARM", "DISARM", "MODE", "IMAGE"):
                self.orders.set_state(order_id, Fate.UNKNOWN, t, reason)
        else:  # rejected, cancelled, aborted, unknown: the ROV's own word
            self.orders.set_state(order_id, Fate(state), t, reason)

    def _stop_fate(self, fate: Fate, t: float, reason: str) -> None:
        if self._stop_order is not None:
            self.orders.set_state(self._stop_order, fate, t, reason)
            if fate is Fate.ACKNOWLEDGED:
                self.note(f"STOP confirmed: {reason}")

    def _thumbnail(self, oid: int, obj: bytes, verified: bool, t: float, *, complete: bool) -> None:
        parts = ac.thumbnail_object(obj)  # the object's bytes read in link/, its track too (link/pictures.py)
        if parts is None:
            return
        total, stream = parts
        self._verified[oid] = bool(verified)
        self.recorder.write({"k": "thumb", "t": round(t, 4), "oid": oid, "hex": bytes(obj).hex(),
                             "verified": bool(verified), "complete": complete})
        view = self.images.view
        started = view.started_at if view.img == oid and view.started_at is not None else t
        self.images.on_event(ImageProgress(oid, len(stream), total, stream), t)
        if complete:
            self.images.on_event(ImageComplete(oid, stream, started, t), t)
            known = self._by_oid.get(oid)
            if known is not None:
                fate = self.orders.fate(known[0])
                if fate is not None and not fate.ended:
                    self.orders.set_state(known[0], Fate.DONE, t)

    # ------------------------------------------------------------------
    # Commands (any thread): one path each, through the control desk
    # ------------------------------------------------------------------

    def _send(self, body, kind: str, detail: dict, settings=None) -> int:
        t = self.now()
        if self.op is None:
            raise NotNow("a replay: there is no ROV to order")
        try:
            with self._machine_lock(self.op):
                oid = self.op.send_order(body, self._clock())
        except ac.OrderRefused as exc:
            raise NotNow(f"the acoustic link cannot take it now: {exc}") from None
        except LinkProcessSlow as slow:
            # Handed to the link process, which has not answered yet: queued, and
            # followed under its OID when the answer comes (never refused meanwhile).
            order_id = self.orders.new(kind, Fate.QUEUED, {**detail, "oid": None}, t)
            self.note(f"{kind} order {order_id}: {slow}", "warn")

            def answered(oid: int) -> None:
                with self._lock:
                    self.orders.update(order_id, oid=int(oid))
                    self._by_oid[int(oid)] = (order_id, kind, settings)

            slow.when_answered(answered,
                               lambda text: self.orders.set_state(order_id, Fate.REFUSED, self.now(), text),
                               lambda why: self.orders.set_state(order_id, Fate.UNKNOWN, self.now(), why))
            return order_id
        except LinkProcessDown as exc:
            raise NotNow(str(exc)) from None
        with self._lock:
            order_id = self.orders.new(kind, Fate.QUEUED, {**detail, "oid": oid}, t)
            self._by_oid[oid] = (order_id, kind, settings)
        return order_id

    def arm(self, armed: bool) -> int:
        order_id = self._send(ac.OrderBody(0, ac.OP_ARM if armed else ac.OP_DISARM, 0), "ARM" if armed else "DISARM",
                              {"armed": bool(armed)})
        self.orders.watch("arm", order_id, self.now())  # followed when a status shows it, however late
        self.note("arm requested" if armed else "disarm requested")
        return order_id

    def set_mode(self, mode: str | int) -> int:
        value = mode_of(mode)
        order_id = self._send(ac.OrderBody(0, ac.OP_MODE, int(value)), "MODE", {"mode": value.name})
        self.orders.watch("mode", order_id, self.now())
        self.note(f"mode {value.name} requested")
        return order_id

    def _queue_position(self, x_m: float, y_m: float, z_m: float, yaw_deg: float, *, relative: bool, body: bool,
                        detail: dict) -> int:
        try:
            target = acoustic_goto(x_m, y_m, z_m, yaw_deg, relative=relative, body=body)
        except ValueError as exc:
            raise OrderError(str(exc)) from None
        return self._send(target, "POSITION", detail)

    def stop(self) -> int:
        """STOP: first, ahead of anything queued, in every slot until confirmed."""
        if self.op is None:
            raise NotNow("a replay: there is no ROV to order")
        t = self.now()
        slow = None
        try:
            with self._machine_lock(self.op):
                no = self.op.stop(self._clock())
        except LinkProcessSlow as exc:  # handed over, its number not yet told
            no, slow = None, exc
        except LinkProcessDown:  # never refused: pressed again in the next link process
            no = None
        with self._lock:
            if no is None:
                earlier = self.orders.fate(self._stop_order)
                joined = earlier is not None and not earlier.ended and (self._stop_pending or self._stop_no is None)
                if not joined:
                    self._stop_no = None
                    self._stop_order = self.orders.new("STOP", Fate.QUEUED, {"stop_no": None}, t)
                self._stop_pending = slow is None
            else:
                joined = self._stop_no == no and self._stop_order is not None
                if not joined:
                    self._stop_no = no
                    self._stop_order = self.orders.new("STOP", Fate.SENT, {"stop_no": no}, t)
            self.goto.abort("STOP", t)
            order_id = self._stop_order
        if slow is not None:
            self.note(f"STOP order {order_id}: {slow}", "warn")
            slow.when_answered(lambda no: self._stop_told(order_id, int(no)),
                               lambda text: self.orders.set_state(order_id, Fate.REFUSED, self.now(), text),
                               lambda why: None)  # the process's end presses it again in the next one
        elif no is None:
            if not joined:
                self.note("STOP waits for the link process, which is being started again", "warn")
        elif not joined:
            self.note(f"STOP {no} pressed: sent first, in every slot until confirmed")
        return order_id

    def _stop_told(self, order_id: int, no: int) -> None:
        """A STOP the link process was slow to take: its number, now told."""
        with self._lock:
            if self._stop_order != order_id:
                return
            self._stop_no = no
            self.orders.update(order_id, stop_no=no)
            fate = self.orders.fate(order_id)
            if fate is Fate.QUEUED:
                self.orders.set_state(order_id, Fate.SENT, self.now())
        self.note(f"STOP {no} pressed: sent first, in every slot until confirmed")

    def cancel_stop(self) -> bool:
        if self.op is None:
            return False
        try:
            with self._machine_lock(self.op):
                done = bool(self.op.cancel_stop())
        except LinkProcessDown as exc:  # slow included: said, never guessed
            raise NotNow(str(exc)) from None
        with self._lock:
            if done and self._stop_order is not None:
                self.orders.set_state(self._stop_order, Fate.CANCELLED, self.now(), "by the pilot (no autopilot to hold)")
        if done:
            self.note("STOP cancelled by the pilot")
        return done

    def stopping(self) -> bool:
        return bool(self.op is not None and (self.op.stop_active or self._stop_pending))

    def set_image_settings(self, *, roi=None, shift: int | None = None, mono: bool | None = None,
                           budget_bytes: int | None = None) -> int:
        """A thumbnail (80x60 grey) on request: `roi` in its pixels, x1 and y1 exclusive.
        It ends a FOLLOW (its ROI stays where it is drawn), as an IMAGE order does on the radio link."""
        return self._ask_thumbnail(roi, shift, budget_bytes)

    def follow_roi(self, roi, *, keep: bool = True, drawn_on: int = 0, shift: int | None = None) -> int:
        """A thumbnail whose ROI follows its object (§9.3's THUMB with FOLLOW, §10): `roi`
        as drawn on the thumbnail whose OID is `drawn_on`; the ROV tracks it in every camera
        frame and codes the thumbnail with the ROI where the object is now.  Asking again
        with the same ROI and the same `drawn_on` goes on with the ROV's track."""
        if roi is None:
            raise OrderError("Follow needs an ROI drawn on a thumbnail")
        if isinstance(drawn_on, bool) or not isinstance(drawn_on, int) or not 0 <= drawn_on <= 255:
            raise OrderError(f"the thumbnail an ROI was drawn on is named by its OID, 0..255, not {drawn_on!r}")
        return self._ask_thumbnail(roi, shift, None, follow=(bool(keep), drawn_on))

    def _ask_thumbnail(self, roi, shift: int | None, budget_bytes: int | None, follow: tuple | None = None) -> int:
        current = self.requested_settings
        budget = current.budget_bytes if budget_bytes is None else budget_bytes
        if not isinstance(budget, int) or not ac.MIN_BUDGET <= budget <= ac.MAX_BUDGET:
            raise OrderError(f"a thumbnail's budget is {ac.MIN_BUDGET}..{ac.MAX_BUDGET} bytes on the acoustic link, "
                             f"not {budget!r}")
        if roi is not None:
            try:
                x0, y0, x1, y1 = (int(v) for v in roi)
            except (TypeError, ValueError):
                raise OrderError(f"roi must be [x0, y0, x1, y1], not {roi!r}") from None
            if not (0 <= x0 < x1 <= ac.THUMB_W and 0 <= y0 < y1 <= ac.THUMB_H):
                raise OrderError(f"roi must be x0 < x1 <= {ac.THUMB_W}, y0 < y1 <= {ac.THUMB_H}, none below 0 "
                                 f"(pixels of the {ac.THUMB_W}x{ac.THUMB_H} thumbnail), not {tuple(roi)}")
            roi = (x0, y0, x1, y1)
        shift = current.shift if shift is None else shift
        keep, drawn_on = follow if follow is not None else (False, 0)
        request = ac.ThumbRequest(0, budget, roi or (0, 0, 0, 0), shift if roi else 0, True,
                                  follow=follow is not None, keep=keep, drawn_on=drawn_on)
        bad = request.invalid()
        if bad:
            raise OrderError(f"thumbnail: {bad}")
        settings = PictureRequest(roi=roi, shift=shift if roi else current.shift, mono=True, budget_bytes=budget) \
            if follow is None else FollowRequest(roi=roi, shift=shift, mono=True, budget_bytes=budget, keep=keep,
                                                 drawn_on=drawn_on)
        detail = {"roi": list(roi) if roi else None, "shift": settings.shift, "mono": True, "budget_bytes": budget}
        if follow is not None:
            detail.update(follow=True, keep=keep, drawn_on=drawn_on)
        order_id = self._send(request, "IMAGE", detail, settings)
        with self._lock:
            self.requested_settings = settings
        return order_id

    def next_image(self) -> None:
        raise NotNow("the acoustic link sends a thumbnail on request, one at a time: there is no next picture "
                     "to skip to (ask for a thumbnail)")

    def set_velocity(self, vx: float, vy: float, vz: float, vyaw: float) -> None:
        if (vx, vy, vz, vyaw) != NEUTRAL:
            raise NotNow("the acoustic link carries no sticks (a packet a second, seconds of latency): "
                         "send a go-to, or STOP")

    def set_pilot_in_force(self, in_force: bool) -> None:
        """Nothing to do: no wish is sent on this link, so none can release a HOLD."""

    def set_attended(self, attended: bool) -> None:
        """Nothing to do: the acoustic link's pace does not depend on a pilot being there."""

    def recentred(self) -> None:
        """Nothing to do: there are no sticks on this link."""

    def velocity_wish(self) -> tuple[float, float, float, float]:
        return NEUTRAL

    def wish_state(self) -> dict:
        return {"vx": 0.0, "vy": 0.0, "vz": 0.0, "vyaw": 0.0}

    # ------------------------------------------------------------------
    # A replay: what was recorded, shown as it was
    # ------------------------------------------------------------------

    def replayed(self, record: dict) -> None:
        """One record of an acoustic recording (status, thumbnail, order, log line)."""
        kind = record.get("k")
        t = self.now()
        with self._lock:
            if kind == "status":
                fields = {k: record[k] for k in VehicleReport.__dataclass_fields__ if k in record}
                fields["sampled_at"] = record.get("sampled_at", t)
                fields["arrived_at"] = t
                self._heard_at = None
                self.health.reply(t, None)
                self._status(VehicleReport(**fields), record.get("uplink"), t)
            elif kind == "thumb":
                self._thumbnail(int(record["oid"]), bytes.fromhex(record["hex"]), bool(record.get("verified")), t,
                                complete=bool(record.get("complete")))
            elif kind == "synced":
                self.rov_failsafe_s = float(record.get("failsafe_s", self.rov_failsafe_s))
                self.failsafe_action = record.get("failsafe_action", self.failsafe_action)
            elif kind == "note":
                line = LogLine(t, str(record["text"]), str(record.get("level", "info")), record.get("cause"))
                self.history.log.append(line)
                self._publish("log", self._log_entry(line))
            elif kind in ("order", "order_state"):
                self.orders.replayed(record, t)
            elif kind in ("rx", "tx"):
                self.health.event(t, kind, PACKET)
            else:
                self.world.replayed(record, t)

    # ------------------------------------------------------------------
    # The read side (any thread; no side effects)
    # ------------------------------------------------------------------

    def predicted_pose(self, at: float | None = None) -> Pose | None:
        """Where the vehicle is now: with no sticks it holds where it was, or flies
        the go-to it has taken (GUIDED, as the preview), for the report's age."""
        with self._lock:
            fix = self.odometry.fix
            if fix is None:
                return None
            active = self.goto.active
            fate = None if active is None else self.orders.fate(active.order_id)
        pose = fix.pose
        age = max(0.0, (self.now() if at is None else at) - fix.sampled_at)
        if active is None or active.target is None or fate is not Fate.ACKNOWLEDGED \
                or not fix.report.armed or fix.report.hold or fix.report.failsafe or age <= 0.0:
            return pose
        x, y, z, yaw = active.target
        points = preview_path(pose, x, y, z, yaw, seconds=min(age, self.rov_failsafe_s), step_s=0.5)
        px, py, pz = points[-1]
        return Pose(px, py, pz, pose.roll_deg, pose.pitch_deg, pose.yaw_deg)

    def _may_move(self, report: VehicleReport) -> bool:
        return report.armed and not report.hold  # supervised: holding, it stays where it was

    def _pose_extra(self, report: VehicleReport) -> dict:
        return {"tilt_valid": report.tilt_valid, "going": report.going, "battery_v": report.battery_v,
                "next_report_in_s": self._next_status_in()}

    def _next_status_in(self) -> float | None:
        if self.op is None:
            return None
        due = self.op.next_status_at
        return None if due is None else round(max(0.0, due - self._clock()), 1)

    def image_state(self) -> dict:
        state = self.images.state()
        img = state.get("img")
        state["verified"] = self._verified.get(img) if img is not None else None
        state["waiting"] = self.picture_wait()
        return state

    _first_report = "status"

    def _picture_wait_on_link(self) -> str:
        if self.images.view.received_bytes:
            return "decoding the first bytes of the thumbnail"
        waiting = [o for o in self.orders.state() if o["kind"] == "IMAGE" and not Fate(o["state"]).ended]
        if waiting:
            return f"thumbnail asked for (order {waiting[-1]['id']}, {waiting[-1]['text']}): its first bytes come " \
                   f"after the next status, about a packet a second"
        return "no thumbnail yet: ask for one (pictures on the acoustic link come on request)"

    def _link_counts(self) -> dict:
        return {
            "sent": self.packets_out,
            "reports": self.odometry.fixes,
            "reports_lost": None,  # a status never asked for is not missed: nothing to count
            "bad_frames": self.health.inauthentic_frames,
            "protocol_errors": 0 if self.op is None else int(getattr(self.op.counters, "malformed", 0)),
            "bytes_sent": self.packets_out * PACKET,
            "bytes_received": self.packets_in * PACKET,
            "images_completed": self.images.view.images_completed,
            "port_error": port_down_reason(self.endpoint) if self._port_up is False else None,
            **self._link_process_state(self.op),
            "acoustic": {"synced": self.op is not None and not self.op.resyncing,
                         "next_report_in_s": self._next_status_in()},
        }
