"""The operator's session: what the pilot wants in, what the ROV says out.

Goals: one place that holds the console's truth, shared by the viser scene,
the web API, the ground-station gateway and the recorder, with memory flat
however long the session.  Every method may be called from any thread (viser
runs callbacks in a thread pool, FastAPI in its own); getters have no side
effects.

Plan: `Operator.run()` drives the master with `link.aio.run_master` (the one
master loop) on an Endpoint, under the session's lock; commands take the
same lock and talk to the master directly.  What the master says happened
(its events: polls sent, replies, image trunks, orders' fates) is handed to
the session's parts, one job each (console/session/): the odometry, the
predictor (the ghost), the image receiver (decode thread, capture window,
pictures to look back at), the order book, the link's health, the recorder.
Subscribers get `(topic, payload)` callbacks: "pose", "image",
"image_progress", "order", "link", "log", "wish" (and what the command layer
publishes); they must be quick and must not raise.  A replay feeds recorded
events through the same `handle_events` and starts over with `reset`.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from pathlib import Path
from typing import Callable, Iterator

from rovlink.link.aio import CONSOLE_POLL_FLOOR_S, run_master
from rovlink.link.process import LinkProcessDown, LinkProcessSlow, MasterProcess
from rovlink.link.radio.events import AltitudeReported, ObjectRecordIgnored, ObjectRemoved, ObjectReported
from rovlink.link.radio.frame import MAX_FRAME
from rovlink.link.radio.master import (
    ImageAbandoned,
    ImageComplete,
    ImageProgress,
    Master,
    OrderAcknowledged,
    OrderCancelled,
    OrderFateUnknown,
    OrderNotSent,
    OrderRejected,
    PollSent,
    PoseReceived,
    ReplyLost,
    RequestExpired,
    StopConfirmed,
    StopNotCarriedOut,
)
from rovlink.link.radio.messages import (
    FAILSAFE_S,
    MAX_BUDGET,
    NO_IMAGE_DATA,
    VELOCITY_LAPSE_S,
    FollowSettings,
    ImageSettings,
    ProtocolError,
    Reply,
    Stop,
    Velocity,
)
from rovlink.link.radio.replay import ReplyReplayer
from rovlink.link.radio.secure import InauthenticFrame, LateReply, SecureMaster, Synced, poll_sent_from_frame
from rovlink.link.report import report_from_reply
from rovlink.link.transports.transport import Endpoint, port_down_reason
from rovlink.link.units import position_order, velocity_ints, wish_fractions, wish_of

from .base import MAX_SPEED_MPS, NotNow, OrderError, SessionBase, mode_of
from .contract import Capabilities
from .fates import Fate
from .goto import GoToWatch
from .health import LinkHealth
from .images import ImageReceiver
from .odometry import History, Odometry, Pose
from .orders import MODE_NAMES, REPORTED_MODE_NAMES, OrderBook
from .predictor import NEUTRAL_WISH, Predictor
from .recorder import Recorder
from .world import SeenWorld

__all__ = ["MAX_SPEED_MPS", "MODE_NAMES", "NotNow", "Operator", "OrderError", "Pose"]

log = logging.getLogger("rovlink.console.session.radio")


class Operator(SessionBase):
    """The radio profile's session (console/session/contract.py's VehicleSession),
    on the ground every session stands on (console/session/base.py)."""

    _logger = log

    capabilities = Capabilities(profile="radio", velocity=True, next_image=True, follow=True, picture="stream",
                                image_budget_max=MAX_BUDGET, report_every_s=0.3)

    def __init__(
        self,
        endpoint: Endpoint | None,
        *,
        bitrate_bps: float = 1900.0,
        delay_s: float = 0.085,
        record: str | Path | None = None,
        image_settings: ImageSettings | None = None,
        master: Master | None = None,
        clock: Callable[[], float] | None = None,
    ) -> None:
        if isinstance(master, MasterProcess) and endpoint is None:
            endpoint = master.port  # the link process's transport, as it says it is
        self.endpoint = endpoint
        self._start_session(clock or time.monotonic, decoder="debt-decode", warm_up="debt-warm-up (console)")
        max_frame = (endpoint.max_frame if endpoint is not None else None) or MAX_FRAME
        self.master = master or Master(bitrate_bps=bitrate_bps, delay_s=delay_s, max_frame=max_frame)
        # The protocol machine itself (in version 2 `master` is the SecureMaster around it).
        self.protocol_master = self.master
        # Nobody's input is in force until the command layer says a pilot's is: a
        # console that starts releases no HOLD (docs/PROTOCOL.md §5, decided).
        self.master.set_pilot_in_force(False)
        self.bitrate_bps = bitrate_bps
        self.delay_s = delay_s
        self.rov_failsafe_s = FAILSAFE_S  # the ROV's (docs/PROTOCOL.md §3); create_app may say otherwise
        self._initial_settings = image_settings
        self._stops_to_resend: list[int] = []  # STOPs a link process took with it, for the next one
        self._wish_lock = threading.Lock()
        self._link_down_said: str | None = None  # the link process's end last said, until it runs again
        if isinstance(self.master, MasterProcess):
            self.master.t0 = self._t0  # one session clock in both processes
        self.recorder = Recorder(record, {"bitrate_bps": bitrate_bps, "delay_s": delay_s,
                                          "started": time.strftime("%Y-%m-%dT%H:%M:%S"),
                                          "wall0": round(self.wall0, 3)})
        self._replayer = None  # a replay's: link/radio/replay.py ReplyReplayer, made at its first record
        self._new_parts(replaying=False, lost_after_s=None)

    def _new_parts(self, *, replaying: bool, lost_after_s: float | None) -> None:
        """The session's state, as at its start (caller holds the lock, or nobody else has the operator yet)."""
        self.history = History()
        self.health = LinkHealth(history=self.history, note=self.note, clear=self.clear_alerts)
        self.health.replaying = replaying
        if lost_after_s is not None:
            self.health.lost_after_s = lost_after_s
        self.odometry = Odometry()
        self._last_reply: Reply | None = None
        self.predictor = Predictor(velocity_lapse_s=VELOCITY_LAPSE_S)
        self.images = ImageReceiver(lock=self._lock, now=self.now, wall=self.wall, fix=lambda: self.odometry.fix,
                                    record=self.recorder.write, publish=self._publish, note=self.note,
                                    decoder=self._decoder, settings=self._initial_settings)
        self.orders = OrderBook(lock=self._lock, record=self.recorder.write, publish=self._publish, note=self.note)
        self.goto = GoToWatch(self.orders)
        self.world = SeenWorld(lock=self._lock, record=self.recorder.write, publish=self._publish, note=self.note)
        # The settings the pilot last asked for: the base for the pilot's edits.
        self.requested_settings = self._initial_settings or ImageSettings(mono=True, budget_bytes=2000)
        self._wish = NEUTRAL_WISH  # fractions -1..1
        # The velocity in the last poll, until a reply proves it arrived: (arrival, vx..vyaw).
        self._last_poll_velocity: tuple | None = None
        # "1.1" until `authenticate` puts version 2 around the master (a replay: its recording says).
        self.link_version = "2" if isinstance(self.master, SecureMaster) else "1.1"

    def _start_over(self) -> None:
        """`reset`'s: the parts made anew, a replay's switches kept (lock held)."""
        self._new_parts(replaying=self.health.replaying, lost_after_s=self.health.lost_after_s)
        self.link_version = "1.1"
        self._replayer = None  # a replay's reassembly starts again with the recording

    def _publish_settled(self) -> None:
        super()._publish_settled()
        self._publish("wish", self.wish_state())

    # ------------------------------------------------------------------
    # The link driver
    # ------------------------------------------------------------------

    async def run(self) -> None:
        """Drive the link until cancelled."""
        if isinstance(self.master, MasterProcess):
            try:
                await self.master.run(self.handle_events, clock=self.now, on_bytes=self.bytes_received,
                                      on_turn=self._turn, on_up=self._link_process_up,
                                      on_down=self._link_process_down)
            finally:
                self._decoder.shutdown()
            return
        if self.endpoint is None:
            raise RuntimeError("no link endpoint: this operator only replays")
        try:
            await run_master(self.master, self.endpoint, self.handle_events, clock=self.now, lock=self._lock,
                             on_bytes=self.bytes_received, on_turn=self._turn, poll_floor_s=CONSOLE_POLL_FLOOR_S)
        finally:
            self._decoder.shutdown()

    # -- the link in a process of its own (link/process.py) -------------------

    def _link_process_down(self, why: str, t: float) -> None:
        """The link process ended: said at once, and nothing it held is shown done.
        Orders it had not settled are unknown (the ROV may have taken them: they
        are not sent again), but a STOP, which goes again with the next process;
        a picture half in is abandoned."""
        # Said once per spell: one that cannot start is tried again every second.
        if why != self._link_down_said:
            self._link_down_said = why
            self.note(f"LINK PROCESS DOWN: {why}; starting it again (no poll leaves meanwhile)", "alert",
                      cause="process")
        with self._lock:
            stops = self.orders.link_ended(t, "the link process ended before the ROV answered; not sent again")
            self._stops_to_resend = sorted(set(self._stops_to_resend) | set(stops))
            v = self.images.view
            partial = v.img is not None and not v.complete and v.received_bytes > 0
            abandoned = ImageAbandoned(v.img, v.received_bytes, "the link process ended") if partial else None
        if abandoned is not None:
            self.handle_events([abandoned], t)
        self._publish("link", self.link_state())

    def _link_process_up(self, pid: int, t: float) -> None:
        self._link_starts += 1
        self._link_down_said = None
        if self._link_starts > 1:
            self.note(f"link process started again (pid {pid})")
            self.clear_alerts("process")
        with self._lock:
            stops, self._stops_to_resend = self._stops_to_resend, []
        for order_id in stops:  # a STOP the pilot pressed is never lost with a process
            try:
                self._handed(order_id, self.master.send_order(Stop()))
            except LinkProcessSlow as slow:
                self._answer_awaited(slow, order_id, "STOP")
            except (LinkProcessDown, ValueError) as exc:
                self.orders.set_state(order_id, Fate.UNKNOWN, t, f"not sent again ({exc})")
        self._publish("link", self.link_state())

    @contextlib.contextmanager
    def _link_call(self, *, may_be_slow: bool = False) -> Iterator[None]:
        """A call into the link process: its absence is the pilot's 409, with why; so
        is its slowness (its words say it may yet be done), unless `may_be_slow`: the
        caller then says what follows."""
        try:
            yield
        except LinkProcessSlow as exc:
            if may_be_slow:
                raise
            raise NotNow(str(exc)) from None
        except LinkProcessDown as exc:
            raise NotNow(str(exc)) from None

    def _turn(self, t: float) -> None:
        """Once per turn of the link loop: the timers of the session."""
        self.orders.check_requests(self.odometry.fix, t)
        self.health.watch(t)
        self._watch_port()

    def bytes_received(self, data: bytes, t: float) -> None:
        self.recorder.write({"k": "rx", "t": round(t, 4), "hex": data.hex()})
        self.health.event(t, "rx", len(data))

    def authenticate(self, key: bytes) -> None:
        """Protocol version 2 (docs/PROTOCOL.md §8): every frame authenticated with
        `key`.  Call before `run`.  The recording then also keeps the reply
        payloads the master was given ("reply": authentic, timely, tag
        removed), which is what a replay may show."""

        def record_reply(payload: bytes, sync: bool, now: float) -> None:
            self.recorder.write({"k": "reply", "t": round(now, 4), "hex": payload.hex(), "sync": sync})

        with self._lock:
            if isinstance(self.master, MasterProcess):
                self.master.authenticate(key)  # the link process makes its SecureMaster
            else:
                self.master = SecureMaster(self.master, key)
            self.master.on_reply = record_reply
            self.link_version = "2"
        self.recorder.write({"k": "link", "t": round(self.now(), 4), "version": 2})

    # ------------------------------------------------------------------
    # What happened on the link (the master's events, or a replay's)
    # ------------------------------------------------------------------

    def handle_events(self, events: list, t: float) -> None:
        with self._lock:
            crc = self.master.decoder.crc_errors
        self.health.crc_errors(crc, t)
        orders = self.orders
        for event in events:
            if isinstance(event, PoseReceived):
                self._pose(event, t)
            elif isinstance(event, PollSent):
                self._poll_sent(event, t)
            elif isinstance(event, (ImageProgress, ImageComplete, ImageAbandoned)):
                self.images.on_event(event, t)
            elif isinstance(event, OrderAcknowledged):
                self._settled(event.order_id, Fate.ACKNOWLEDGED, t)
            elif isinstance(event, OrderCancelled):
                self._settled(event.order_id, Fate.CANCELLED, t, event.reason)
            elif isinstance(event, OrderRejected):
                self._settled(event.order_id, Fate.REJECTED, t, event.reason_text)
            elif isinstance(event, OrderNotSent):
                self._settled(event.order_id, Fate.CANCELLED, t, f"{event.reason} (never sent)")
            elif isinstance(event, StopConfirmed):
                mode = REPORTED_MODE_NAMES.get(int(event.mode), str(event.mode))
                self._settled(event.order_id, Fate.ACKNOWLEDGED, t, f"holding in {mode}")
            elif isinstance(event, StopNotCarriedOut):
                self._settled(event.order_id, Fate.NOT_CARRIED_OUT, t, "no autopilot holds the vehicle")
            elif isinstance(event, OrderFateUnknown):
                self._settled(event.order_id, Fate.UNKNOWN, t, "the ROV restarted before its answer came (not resent)")
            elif isinstance(event, ReplyLost):
                self.health.event(t, "lost")
                self._publish("link", {"t": t, "lost": True})
            elif isinstance(event, InauthenticFrame):
                self.health.inauthentic(t)
            elif isinstance(event, LateReply):
                self.health.late(t)
            elif isinstance(event, (AltitudeReported, ObjectReported, ObjectRemoved, ObjectRecordIgnored)):
                if not self.health.replaying:  # a replay lays the world from its own records
                    self._scene(event, t)
            elif isinstance(event, Synced):
                restarted = event.restarted and not event.first
                self.note("ROV restarted (new BOOT): link synchronised again" if restarted else "link synchronised",
                          "alert" if restarted else "info")
                if restarted:
                    self.follow_refused = None
                    self._resend_image_settings()
            elif isinstance(event, RequestExpired):
                orders.request_unrepeated(event.what, t, "the link repeated it for its 3 s")

    def _scene(self, event, t: float) -> None:
        """§11.1: what the ROV measured of the world, to the world part (SI)."""
        if isinstance(event, AltitudeReported):
            fix = self.odometry.fix
            self.world.altitude(event.altitude_m, t, None if fix is None else fix.report.z_m)
        elif isinstance(event, ObjectReported):
            self.world.object_seen(event.obj, event.record_bytes, t)
        elif isinstance(event, ObjectRemoved):
            self.world.object_removed(event.object_id, t)
        else:
            self.world.record_ignored(event.record_hex, t)

    def _settled(self, master_id: int, fate: Fate, t: float, reason: str = "") -> None:
        settings = self.orders.settled(master_id, fate, t, reason)
        if settings is not None:
            with self._lock:
                self.images.confirmed_settings = settings  # applies from the next picture on

    def _poll_sent(self, sent: PollSent, t: float) -> None:
        """What the master said it sent: recorded, and the orders it carried marked sent."""
        frame = sent.frame
        record = {"k": "tx", "t": round(t, 4), "hex": frame.hex()}
        if sent.poll is not None:
            # Version 2 may leave the image request out of the frame (§8.1): the poll
            # as the master made it is kept beside it, for a replay.
            record["poll"] = sent.poll.encode().hex()
        self.recorder.write(record)
        self.health.event(t, "tx", len(frame))
        self._last_poll_velocity = None
        poll = sent.poll
        if poll is None:  # a HELLO: no order in it
            return
        order = poll.order
        if poll.offset != NO_IMAGE_DATA:
            with self._lock:
                trunk_cap = self.master.trunk_bytes(poll.size)
            self.images.request_sent(t, poll.img, poll.offset, trunk_cap)
        # It reaches the ROV after its own air time and the one-way delay.
        arrival = t + 8.0 * len(frame) / self.bitrate_bps + self.delay_s
        with self._lock:
            if isinstance(order, Stop):
                self.predictor.stop_sent(arrival)
            if isinstance(order, Velocity):
                wish = wish_of(order)
                self._last_poll_velocity = (arrival, *wish)
                self.predictor.wish_sent(arrival, wish)
        if isinstance(order, Velocity):
            if order.arm:
                self.orders.request_sent("arm", t)
            if order.mode:
                self.orders.request_sent("mode", t)
        for master_id in sent.order_ids:
            self.orders.sent_by_master_id(master_id, t)

    def _resend_image_settings(self) -> None:
        """A restarted ROV has its default image settings again (§8): ours go again."""
        s = self.requested_settings
        self.set_image_settings(roi=s.roi, shift=s.shift, mono=s.mono, budget_bytes=s.budget_bytes)

    def _pose(self, event: PoseReceived, t: float) -> None:
        reply, round_trip_s = event.reply, event.round_trip_s
        report = event.report or report_from_reply(reply, arrived_at=t, frame_bytes=None, bitrate_bps=self.bitrate_bps,
                                                   delay_s=self.delay_s, round_trip_s=round_trip_s)
        pose = Pose.from_report(report)
        with self._lock:
            self._last_reply = reply
            previous = self.odometry.take(report, round_trip_s)
            self.world.depth(report.z_m)
            entered_failsafe = bool(reply.failsafe) and (previous is None or not previous.report.failsafe)
            left_failsafe = not reply.failsafe and previous is not None and bool(previous.report.failsafe)
            self.health.reply(t, round_trip_s)
            self.history.trail.append((t, pose.x_m, pose.y_m, pose.z_m))
            # A reply proves its poll arrived intact: the velocity it carried
            # is what the ROV received (Fig. 5), at send time + transmission + delay.
            if self._last_poll_velocity is not None:
                self.history.received.append(self._last_poll_velocity)
                self._last_poll_velocity = None
        self.recorder.write({"k": "pose", "t": round(t, 4), **{k: round(v, 3) for k, v in pose.as_dict().items()},
                             "armed": reply.armed, "mode": reply.mode, "failsafe": reply.failsafe,
                             "autopilot": reply.autopilot})
        if entered_failsafe and previous is None:
            self.note("ROV in FAILSAFE at link start (it had no poll yet)", "warn")
        elif entered_failsafe:
            self.note("ROV reports FAILSAFE: it had no poll for its failsafe time, braked and holds", "alert",
                      cause="failsafe")
        elif left_failsafe:
            self.clear_alerts("failsafe")
            self.note("ROV out of FAILSAFE: polls reach it again", "warn")
        self.health.watch(t)
        self._publish("pose", self.pose_state())
        fix = self.odometry.fix
        self.orders.check_requests(fix, t)
        with self._lock:
            self.goto.on_reply(fix, t)

    # ------------------------------------------------------------------
    # Commands (any thread)
    # ------------------------------------------------------------------

    def set_velocity(self, vx: float, vy: float, vz: float, vyaw: float) -> None:
        """Velocity wish, fractions -1..1 of the maximum (body frame, z down)."""
        values = (vx, vy, vz, vyaw)
        for name, v in zip(("vx", "vy", "vz", "vyaw"), values):
            if not isinstance(v, (int, float)) or not math.isfinite(v) or not -1.0 <= v <= 1.0:
                raise OrderError(f"{name} must be a number in -1..1, got {v!r}")
        ints = velocity_ints(values)
        t = self.now()
        # One wish at a time, the master's and ours alike (the link's events are not held up).
        with self._wish_lock:
            with self._machine_lock(self.master):
                self.master.set_velocity(*ints, t)
            with self._lock:
                changed = tuple(float(v) for v in values) != self._wish
                self._wish = tuple(float(v) for v in values)
                if changed:
                    self.history.commanded.append((t, *self._wish))
                    # Every change is recorded, neutral ones (STOP, a holder
                    # gone, the dead man) as much as the pilot's.
                    self.recorder.write({"k": "wish", "t": round(t, 4), "v": list(ints)})
        if changed:
            self._publish("wish", self.wish_state())

    def set_pilot_in_force(self, in_force: bool) -> None:
        """Whether the wish is a pilot's own input: someone holds control and has
        re-centred since taking it (the command layer decides).  When not, a
        neutral wish releases no HOLD on the ROV (link.master.set_pilot_in_force)."""
        with self._machine_lock(self.master):
            self.master.set_pilot_in_force(in_force)

    def set_attended(self, attended: bool) -> None:
        """Whether a pilot holds control (the command layer says): replies are
        then sized for the pilot's reaction and a fresh pose, not only for pictures."""
        with self._machine_lock(self.master):
            self.master.set_attended(attended)

    def recentred(self) -> None:
        """The holder's own input is neutral: its re-centring reaches the ROV
        (releasing a HOLD) even if the sticks move again before the next poll."""
        with self._machine_lock(self.master):
            self.master.recentred()

    def arm(self, armed: bool) -> int:
        """Request arming (or disarming); the returned order id is followed
        until the vehicle reports it armed (disarmed), however late."""
        t = self.now()
        order_id = self._request(lambda: self.master.request_arm(bool(armed), t), "arm", "ARM" if armed else "DISARM",
                                 {"armed": bool(armed)}, t)
        self.note("arm requested" if armed else "disarm requested")
        return order_id

    def set_mode(self, mode: str | int) -> int:
        """Request a mode (a name of MODE_NAMES or its number); the returned
        order id is followed until the vehicle reports the mode, however late."""
        value = mode_of(mode)
        t = self.now()
        order_id = self._request(lambda: self.master.request_mode(value, t), "mode", "MODE", {"mode": value.name}, t)
        self.note(f"mode {value.name} requested")
        return order_id

    def _request(self, call: Callable[[], None], what: str, kind: str, detail: dict, t: float) -> int:
        """An arm or mode request handed to the master, then watched (followed when the
        vehicle shows it).  A link process slow to answer has it all the same: it is
        watched, and refused only if the process says so."""
        try:
            with self._machine_lock(self.master), self._link_call(may_be_slow=True):
                call()
        except LinkProcessSlow as slow:
            order_id = self.orders.request(what, kind, detail, t)
            self.note(f"{kind} order {order_id}: {slow}", "warn")
            slow.when_answered(lambda _: None,
                               lambda text: self.orders.set_state(order_id, Fate.REFUSED, self.now(), text),
                               lambda _why: None)  # the process's end settles its requests (link_ended)
            return order_id
        return self.orders.request(what, kind, detail, t)

    def _queue(self, order, kind: str, detail: dict) -> int:
        order_id = self.orders.new(kind, Fate.QUEUED, detail, self.now())
        try:
            with self._machine_lock(self.master):
                master_id = self.master.send_order(order)
        except LinkProcessSlow as slow:
            self._answer_awaited(slow, order_id, kind)
            return order_id
        except LinkProcessDown as exc:
            if kind == "STOP":  # never refused: it goes with the next link process
                with self._lock:
                    self._stops_to_resend.append(order_id)
                self.note("STOP waits for the link process, which is being started again", "warn")
                return order_id
            self.orders.set_state(order_id, Fate.REFUSED, self.now(), str(exc))
            raise NotNow(str(exc)) from None
        self._handed(order_id, master_id)
        return order_id

    def _handed(self, order_id: int, master_id: int) -> None:
        """A one-shot order the master took under `master_id`: what it already said of it
        (a link process's events may come before its answer) applies now."""
        settings = self.orders.queued(order_id, master_id)
        if settings is not None:
            with self._lock:
                self.images.confirmed_settings = settings

    def _answer_awaited(self, slow: LinkProcessSlow, order_id: int, kind: str) -> None:
        """The link process took the order but has not answered yet (a busy machine): it
        stays queued, neither refused nor parked, and is followed when the answer comes.
        If the process ends first, a STOP goes with the next one; any other order is
        unknown (it may have gone out)."""
        self.note(f"{kind} order {order_id}: {slow}", "warn")

        def lost(why: str) -> None:
            if kind == "STOP":
                with self._lock:
                    self._stops_to_resend.append(order_id)
            else:
                self.orders.set_state(order_id, Fate.UNKNOWN, self.now(), why)

        slow.when_answered(lambda master_id: self._handed(order_id, master_id),
                           lambda text: self.orders.set_state(order_id, Fate.REFUSED, self.now(), text), lost)

    def _queue_position(self, x_m: float, y_m: float, z_m: float, yaw_deg: float, *, relative: bool, body: bool,
                        detail: dict) -> int:
        try:
            order = position_order(x_m, y_m, z_m, yaw_deg, relative=relative, body=body)
        except ProtocolError as exc:
            raise OrderError(str(exc)) from None
        return self._queue(order, "POSITION", detail)

    def stop(self) -> int:
        """STOP: neutral velocity now, cancel queued targets, hold depth."""
        self.set_velocity(0.0, 0.0, 0.0, 0.0)
        with self._lock:
            self.goto.abort("STOP", self.now())
        return self._queue(Stop(), "STOP", {})

    def set_image_settings(self, *, roi=None, shift: int | None = None, mono: bool | None = None,
                           budget_bytes: int | None = None) -> int:
        current = self.requested_settings
        try:
            settings = ImageSettings(
                roi=tuple(int(v) for v in roi) if roi is not None else None,
                shift=current.shift if shift is None else shift,
                mono=current.mono if mono is None else mono,
                budget_bytes=current.budget_bytes if budget_bytes is None else budget_bytes,
            )
        except (ProtocolError, TypeError, ValueError) as exc:
            raise OrderError(str(exc)) from None
        with self._lock:
            self.requested_settings = settings
        order_id = self._queue(settings, "IMAGE", {"roi": list(settings.roi) if settings.roi else None,
                                               "shift": settings.shift, "mono": settings.mono,
                                               "budget_bytes": settings.budget_bytes})
        self.orders.image_order(order_id, settings)
        return order_id

    def follow_roi(self, roi, *, keep: bool = True, drawn_on: int = 0, shift: int | None = None) -> int:
        """FOLLOW (docs/PROTOCOL.md §10): the ROI `roi`, drawn on the picture whose IMG is
        `drawn_on`, follows its object; the other settings stay as requested.  An IMAGE
        order (set_image_settings) ends it."""
        current = self.requested_settings
        try:
            settings = FollowSettings(
                roi=tuple(int(v) for v in roi) if roi is not None else None,
                shift=current.shift if shift is None else shift, mono=current.mono,
                budget_bytes=current.budget_bytes, keep=bool(keep), drawn_on=int(drawn_on),
            )
        except (ProtocolError, TypeError, ValueError) as exc:
            raise OrderError(str(exc)) from None
        with self._lock:
            self.requested_settings = settings
        # Kind IMAGE: its acknowledgement confirms the settings as an IMAGE order's does.
        order_id = self._queue(settings, "IMAGE", {"roi": list(settings.roi), "shift": settings.shift,
                                               "mono": settings.mono, "budget_bytes": settings.budget_bytes,
                                               "follow": True, "keep": settings.keep, "drawn_on": settings.drawn_on})
        self.orders.image_order(order_id, settings)
        return order_id

    def cancel_stop(self) -> bool:
        """Give up a STOP the ROV shows it cannot carry out (no autopilot), so that
        a DISARM or a SURFACE can go out (protocol 1.1); False if there is none."""
        with self._machine_lock(self.master), self._link_call():
            done = bool(self.master.cancel_stop())
        if done:
            self.note("STOP cancelled by the pilot")
        return done

    def stopping(self) -> bool:
        """A STOP is being sent until the ROV confirms it: no order and no wish goes out meanwhile."""
        return bool(self.master.stopping)

    def next_image(self) -> None:
        """The pilot skips the picture arriving: the ROV's next one is asked for.  What was
        skipped is said (the log, and the image state's `skipped`) when the master lets it go."""
        arriving = self.protocol_master.image_received
        with self._machine_lock(self.master), self._link_call():
            self.master.abandon_image()
        if not arriving:
            self.images.nothing_to_skip(self.now())

    # -- a replay shows what was, and sends nothing -----------------------

    def replayed(self, record: dict) -> None:
        """One record of a radio recording, fed back by the master's own rules
        (link/radio/replay.py): frames both ways, replies, wishes, orders."""
        now, kind = self.now(), record.get("k")  # the record's own time
        if self._replayer is None:
            self._replayer = ReplyReplayer(bitrate_bps=float(self.bitrate_bps), delay_s=float(self.delay_s))
        if kind == "rx":
            data = bytes.fromhex(record["hex"])
            self.bytes_received(data, now)
            # Protocol 2 sessions record what the master was given ("reply": authentic,
            # timely, tag removed); their raw frames then count only as traffic.
            if self.link_version != "2":
                self.handle_events(self._replayer.feed(data, now), now)
        elif kind == "reply":
            events = self._replayer.feed_payload(bytes.fromhex(record["hex"]), now, sync=bool(record.get("sync")))
            self.handle_events(events, now)
        elif kind == "tx":
            sent = poll_sent_from_frame(bytes.fromhex(record["hex"]), now, version=self.link_version,
                                        poll=bytes.fromhex(record["poll"]) if "poll" in record else None)
            if sent is not None:
                # The poll first, then what it did to the picture held (the master's order of things).
                self.handle_events([sent, *self._replayer.poll_sent(sent.poll, now)], now)
        elif kind == "wish":
            self.replayed_wish(wish_fractions(record["v"]))
        elif kind in ("order", "order_state"):
            self.replayed_order(record)
        elif self.world.replayed(record, now):
            pass
        elif kind == "link" and record.get("version") == 2:
            self.link_version = "2"  # written before the first frame (authenticate comes before run)

    def replayed_wish(self, values: tuple[float, ...]) -> None:
        """A recorded wish change, shown as it was."""
        with self._lock:
            self._wish = tuple(float(v) for v in values)
            self.history.commanded.append((self.now(), *self._wish))
        self._publish("wish", self.wish_state())

    # ------------------------------------------------------------------
    # State (any thread; no side effects)
    # ------------------------------------------------------------------

    @property
    def last_reply(self) -> Reply | None:
        """The radio reply itself (wire units), for link tools and tests; the
        console's surfaces read `vehicle()`."""
        return self._last_reply

    def velocity_wish(self) -> tuple[float, float, float, float]:
        return self._wish

    def wish_state(self) -> dict:
        w = self._wish
        return {"vx": w[0], "vy": w[1], "vz": w[2], "vyaw": w[3]}

    def predicted_pose(self, at: float | None = None) -> Pose | None:
        """Dead reckoning from the last odometry to `at` (session time; now by
        default): console.session.predictor."""
        with self._lock:
            return self.predictor.predict(self.odometry.fix, self.now() if at is None else at, self.rov_failsafe_s)

    def image_state(self) -> dict:
        return {**self.images.state(), "waiting": self.picture_wait()}

    _first_report = "reply"

    def _pictures_off(self) -> str | None:
        if self.requested_settings.budget_bytes == 0:
            return "pictures are off (budget 0 B): give them a budget to get some"
        return None

    def _picture_wait_on_link(self) -> str:
        if self.images.view.received_bytes:
            return ("the first picture's first bytes are in: it shows as soon as this console's picture "
                    "decoder has started (up to a minute on a first run)")
        with self._lock:
            arriving = self.protocol_master.image_received
        if arriving:
            # The ROV may have held it since before this session: its age is unknown, so it is not shown.
            return (f"the ROV is sending a picture it took before this session ({arriving} B so far): it may be "
                    f"old, so it is not shown; the first fresh picture comes right after it")
        return ("the ROV is preparing its first picture (its picture coder starts up: up to a minute on a "
                "first run); it shows here as it arrives")

    def _link_counts(self) -> dict:
        with self._lock:
            m = self.master.stats
            crc_errors = self.master.decoder.crc_errors
            ber = self.master.estimated_ber()
        return {
            "sent": m.polls_sent,
            "reports": m.replies,
            "reports_lost": m.replies_lost,
            "bad_frames": crc_errors,
            "protocol_errors": m.protocol_errors,
            "bytes_sent": m.bytes_sent,
            "bytes_received": m.bytes_received,
            "images_completed": m.images_completed,
            # Why this console's own modem port is down (None while it is up, or for a replay).
            "port_error": port_down_reason(self.endpoint),
            **self._link_process_state(self.master),
            "radio": {"last_round_trip_s": m.last_round_trip_s, "estimated_ber": ber,
                      "images_abandoned": m.images_abandoned},
        }
