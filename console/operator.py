"""The operator's session: what the pilot wants in, what the ROV says out.

Goals: one place that holds the console's truth, shared by the viser scene,
the web API and the recorder: the link master and its loop, the latest
odometry and its age, the predicted pose, the image being received (decoded
prefix), link health, and bounded histories for the live plots.  Every
method may be called from any thread (viser runs callbacks in a thread
pool, FastAPI in its loop); memory stays flat however long the session.

Plan: `Operator.run()` drives the master on an Endpoint in the running event
loop, recording each frame both ways, each order and each pose to a JSON-lines
file.  Commands take a lock and talk to the master directly.  Image prefixes
are decoded in one worker thread, newest first (an older prefix still in the
queue is skipped).  Subscribers get `(topic, payload)` callbacks: "pose",
"image", "order", "link", "log"; they must be quick and must not raise.

Prediction (the ghost): the last odometry, aged by the time since it was
sampled on the ROV, flown forward with `rov.vehicle.VehicleModel` under the
velocity commanded since, in the reported mode.  The same model previews the
path of a position order before it is sent.
"""

from __future__ import annotations

import asyncio
import collections
import concurrent.futures
import json
import logging
import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from rovlink.link.aio import run_master
from rovlink.link.frame import OVERHEAD
from rovlink.link.master import (
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
from rovlink.link.messages import (
    NO_IMAGE_DATA,
    REPLY_IMAGE_HEADER,
    ImageSettings,
    Mode,
    Position,
    ProtocolError,
    Reply,
    Stop,
    Velocity,
)
from rovlink.link.secure import InauthenticFrame, LateReply, Synced
from rovlink.link.transport import Endpoint

AUTH_ALERT_COUNT, AUTH_ALERT_WINDOW_S = 3, 10.0  # more forged replies than this in the window: alert

log = logging.getLogger("rovlink.console.operator")

# The modes a pilot may request: the protocol's own list (1..6).
MODE_NAMES = {m.name: m for m in Mode if 1 <= m <= 6}
REPORTED_MODE_NAMES = {0: "UNKNOWN", **{int(m): m.name for m in MODE_NAMES.values()}, 7: "OTHER"}

# Link state from replies (docs/PROTOCOL.md §5): no reply for LOST_AFTER_S is a
# lost link; a reply lost or a CRC error within DEGRADED_WINDOW_S degrades it.
LOST_AFTER_S = 3.0
DEGRADED_WINDOW_S = 5.0
VELOCITY_LAPSE_S = 1.5    # a VELOCITY lapses on the ROV after this long without another (docs/PROTOCOL.md §5)
NEUTRAL_WISH = (0.0, 0.0, 0.0, 0.0)
STOP_WISH = ("STOP",)     # a STOP poll in the timeline of wishes sent: brake and HOLD
ROV_FAILSAFE_S = 3.0      # the ROV's failsafe time: with no poll that long it stops (docs/PROTOCOL.md §3)
REQUEST_FOLLOW_S = 3.0    # an arm/disarm/mode the vehicle does not follow in this time is refused
MAX_SPEED_MPS = 1.0       # how fast the prediction's uncertainty grows when nothing is heard
IMAGE_HISTORY = 24        # pictures kept to look back at (320x240x3 is 230 kB each)
LOG_KEPT = 500            # log lines kept (the page filters them)


class OrderError(ValueError):
    """An order the operator cannot send as given; the message says why."""


@dataclass(frozen=True)
class Pose:
    x_m: float
    y_m: float
    z_m: float
    roll_deg: float
    pitch_deg: float
    yaw_deg: float

    @classmethod
    def from_reply(cls, r: Reply) -> "Pose":
        return cls(r.x_cm / 100, r.y_cm / 100, r.z_cm / 100, r.roll_cdeg / 100, r.pitch_cdeg / 100,
                   r.yaw_cdeg / 100)

    def as_dict(self) -> dict:
        return {"x_m": self.x_m, "y_m": self.y_m, "z_m": self.z_m, "roll_deg": self.roll_deg,
                "pitch_deg": self.pitch_deg, "yaw_deg": self.yaw_deg}


@dataclass
class ImageView:
    img: int | None = None
    received_bytes: int = 0
    total_bytes: int | None = None
    complete: bool = False
    stream: bytes = b""  # the DEBT stream prefix held
    picture: np.ndarray | None = None  # decoded from `decoded_bytes` of it
    decoded_bytes: int = 0
    decoded_at: float | None = None
    started_at: float | None = None
    settings: ImageSettings | None = None
    images_completed: int = 0
    serial: int = 0                   # counts images, never wraps (IMG wraps at 8)
    capture: dict | None = None       # when and where the ROV captured it (Operator._capture_stamp)


@dataclass
class History:
    """Bounded series for the live plots and the session summary."""

    trail: collections.deque = field(default_factory=lambda: collections.deque(maxlen=1000))  # (t, x, y, z)
    commanded: collections.deque = field(default_factory=lambda: collections.deque(maxlen=1000))  # (t, vx..vyaw)
    received: collections.deque = field(default_factory=lambda: collections.deque(maxlen=1000))  # (t, vx..vyaw)
    link_events: collections.deque = field(default_factory=lambda: collections.deque(maxlen=1000))  # (t, kind, n)
    log: collections.deque = field(default_factory=lambda: collections.deque(maxlen=LOG_KEPT))  # (t, text, level)
    round_trips: collections.deque = field(default_factory=lambda: collections.deque(maxlen=50))


class Recorder:
    """JSON lines: one record per frame (hex), order, wish and pose, with its time."""

    def __init__(self, path: str | Path | None, meta: dict) -> None:
        self.path = Path(path) if path else None
        self._file = None
        self._lock = threading.Lock()
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(self.path, "w", buffering=1, encoding="utf-8")
            self.write({"k": "meta", "t": 0.0, **meta})

    def write(self, record: dict) -> None:
        if self._file is None:
            return
        line = json.dumps(record, separators=(",", ":"))
        with self._lock:
            if self._file is not None:
                self._file.write(line + "\n")

    def close(self) -> None:
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None


class DaemonWorker:
    """One daemon thread running submitted calls in order (a ThreadPoolExecutor's
    submit/shutdown).  Daemon: a console that stops never waits for a decode,
    even one held up by DEBT's first (cold) compilation; a ThreadPoolExecutor's
    worker is joined at exit."""

    def __init__(self, name: str) -> None:
        import queue

        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._closed = False
        threading.Thread(target=self._run, name=name, daemon=True).start()

    def submit(self, fn: Callable[[], Any]) -> concurrent.futures.Future:
        if self._closed:
            raise RuntimeError("worker shut down")
        future: concurrent.futures.Future = concurrent.futures.Future()
        self._queue.put((fn, future))
        return future

    def shutdown(self) -> None:
        """Stop after the job in hand; queued jobs are dropped (a daemon thread: nobody waits)."""
        self._closed = True
        self._queue.put(None)

    def _run(self) -> None:
        while (item := self._queue.get()) is not None:
            fn, future = item
            if self._closed:
                future.cancel()
                continue
            if not future.set_running_or_notify_cancel():
                continue
            try:
                future.set_result(fn())
            except BaseException as exc:  # noqa: BLE001 -- handed to whoever waits on the future
                future.set_exception(exc)


def _protocol_to_sub_mode(mode: int):
    from rovlink.rov.autopilot import PROTOCOL_TO_SUB
    from rovlink.rov.vehicle import SubMode

    return PROTOCOL_TO_SUB.get(mode, SubMode.MANUAL)


class Operator:
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
        self.endpoint = endpoint
        self._clock = clock or time.monotonic
        max_frame = (endpoint.max_frame if endpoint is not None else None) or 259
        self.master = master or Master(bitrate_bps=bitrate_bps, delay_s=delay_s, max_frame=max_frame)
        # Nobody's input is in force until the command layer says a pilot's is: a
        # console that starts releases no HOLD (docs/PROTOCOL.md §5, decided).
        self.master.set_pilot_in_force(False)
        self.bitrate_bps = bitrate_bps
        self.delay_s = delay_s
        self.history = History()
        # What the ROV is known to use: given by a caller that knows (the demo
        # starts the ROV itself), else unknown until an IMAGE order we sent is
        # acknowledged.  `requested_settings` is the base for the pilot's edits.
        self._confirmed_settings = image_settings
        self._image_orders: dict[int, ImageSettings] = {}
        self.image = ImageView(settings=image_settings)
        self.requested_settings = image_settings or ImageSettings(mono=True, budget_bytes=2000)
        self._lock = threading.RLock()
        self._subscribers: list[Callable[[str, Any], None]] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._t0 = self._clock()
        # Clock time of session time 0, for the pilot's clock times (a replay sets the recording's).
        self.wall0 = time.time()
        self._reply: Reply | None = None
        self._reply_at: float | None = None  # monotonic time the reply arrived
        self._odometry_at: float | None = None  # estimated time it was sampled on the ROV
        self._reply_poll_sent_at: float | None = None  # when the poll the last reply answers was sent
        self._velocity_est = (0.0, 0.0, 0.0, 0.0)  # NED m/s and yaw deg/s, from successive poses
        self._wish = (0.0, 0.0, 0.0, 0.0)  # fractions -1..1
        self._orders: dict[int, dict] = {}  # console order id -> its info (kind, state, times, details)
        self._next_order_id = 1
        self._by_master_id: dict[int, int] = {}  # the master's one-shot order ids -> ours
        self._requests: dict[str, int] = {}  # "arm"/"mode" -> our id of the request awaiting its effect
        self._crc_seen = 0
        self.inauthentic_frames = 0
        self.late_replies = 0
        self._auth_alerted_at: float | None = None
        self.lost_after_s = LOST_AFTER_S
        self.rov_failsafe_s = ROV_FAILSAFE_S
        self._pending_decode: tuple[int, bytes] | None = None
        self._decoder = DaemonWorker("debt-decode")
        self._decode_busy = False
        self._undecodable_serial: int | None = None   # the picture last said undecodable
        # DEBT compiles on first use: ahead, in a daemon thread (never holding the exit).
        from rovlink import debt

        debt.warm_up_in_background("debt-warm-up (console)")
        self.recorder = Recorder(record, {"bitrate_bps": bitrate_bps, "delay_s": delay_s,
                                          "started": time.strftime("%Y-%m-%dT%H:%M:%S"),
                                          "wall0": round(self.wall0, 3)})
        self._last_poll_at: float | None = None
        self._last_poll_velocity: tuple | None = None
        # The wishes as they went out, each with when it reaches the ROV (send time,
        # its air time and the one-way delay): (arrival, (vx, vy, vz, vyaw) | STOP).
        self._sent_wishes: collections.deque = collections.deque(maxlen=256)
        # The image requests as they went out: (sent at, IMG, OFFSET, largest trunk its SIZE allows).
        self._image_requests: collections.deque = collections.deque(maxlen=256)
        self.replaying = False
        self._shown_link_state: str | None = None
        self._image_history: collections.deque = collections.deque(maxlen=IMAGE_HISTORY)
        self._next_capture: tuple[float, Pose | None, str] | None = None  # see _capture_stamp
        # "1.1" until `authenticate` puts version 2 around the master.
        self.link_version = "1.1"

    # ------------------------------------------------------------------
    # Time and subscribers
    # ------------------------------------------------------------------

    def now(self) -> float:
        """Session time in seconds (monotonic, 0 at start; simulated in benchmarks)."""
        return self._clock() - self._t0

    def subscribe(self, callback: Callable[[str, Any], None]) -> Callable[[], None]:
        with self._lock:
            self._subscribers.append(callback)

        def unsubscribe() -> None:
            with self._lock:
                if callback in self._subscribers:
                    self._subscribers.remove(callback)

        return unsubscribe

    def publish(self, topic: str, payload: Any) -> None:
        """Tell every subscriber (the command layer publishes its own events here too)."""
        self._publish(topic, payload)

    def _publish(self, topic: str, payload: Any) -> None:
        for callback in list(self._subscribers):
            try:
                callback(topic, payload)
            except Exception:
                log.exception("subscriber failed on %s", topic)

    def wall(self, t: float) -> float:
        """Clock time (Unix seconds) of session time `t`."""
        return self.wall0 + t

    def note(self, text: str, level: str = "info") -> None:
        """A log line. `level`: "alert" (the pilot must see it: link lost, failsafe,
        forged frames, an order refused), "warn", or "info" (routine: an image complete)."""
        t = self.now()
        self.history.log.append((t, text, level))
        self._publish("log", self._log_entry(t, text, level))

    def _log_entry(self, t: float, text: str, level: str) -> dict:
        return {"t": t, "wall": round(self.wall(t), 3), "text": text, "level": level}

    def log_entries(self, last: int = LOG_KEPT) -> list[dict]:
        return [self._log_entry(*e) for e in list(self.history.log)[-last:]]

    # ------------------------------------------------------------------
    # The link loop
    # ------------------------------------------------------------------

    async def run(self) -> None:
        """Drive the link until cancelled."""
        if self.endpoint is None:
            raise RuntimeError("no link endpoint: this operator only replays")
        self._loop = asyncio.get_running_loop()
        try:
            await run_master(self.master, self.endpoint, self._on_link_events, clock=self.now, lock=self._lock,
                             on_bytes=self._bytes_received, on_turn=self._check_requests)
        finally:
            self._decoder.shutdown()

    def _bytes_received(self, data: bytes, t: float) -> None:
        self.recorder.write({"k": "rx", "t": round(t, 4), "hex": data.hex()})
        self.history.link_events.append((t, "rx", len(data)))

    def _on_link_events(self, events: list, t: float) -> None:
        with self._lock:
            crc = self.master.decoder.crc_errors
        if crc != self._crc_seen:
            self.history.link_events.append((t, "crc", crc - self._crc_seen))
            self._crc_seen = crc
        self._on_events(events, t)

    def authenticate(self, key: bytes) -> None:
        """Protocol version 2 (docs/PROTOCOL.md §8): every frame authenticated with
        `key`.  Call before `run`.  The recording then also keeps the reply
        payloads the master was given ("reply": authentic, timely, tag
        removed), which is what a replay may show."""
        from rovlink.link.secure import SecureMaster

        def record_reply(payload: bytes, sync: bool, now: float) -> None:
            self.recorder.write({"k": "reply", "t": round(now, 4), "hex": payload.hex(), "sync": sync})

        with self._lock:
            self.master = SecureMaster(self.master, key)
            self.master.on_reply = record_reply
            self.link_version = "2"
        self.recorder.write({"k": "link", "t": round(self.now(), 4), "version": 2})

    def _poll_sent(self, sent: PollSent, t: float) -> None:
        """What the master said it sent: recorded, and the orders it carried marked sent."""
        frame = sent.frame
        self.recorder.write({"k": "tx", "t": round(t, 4), "hex": frame.hex()})
        self.history.link_events.append((t, "tx", len(frame)))
        self._last_poll_at = t
        self._last_poll_velocity = None
        poll = sent.poll
        if poll is None:  # a HELLO: no order in it
            return
        order = poll.order
        if poll.offset != NO_IMAGE_DATA:
            with self._lock:
                trunk_cap = self.master.reply_frame_bytes(poll.size) - OVERHEAD - REPLY_IMAGE_HEADER
            self._image_requests.append((t, poll.img, poll.offset, trunk_cap))
        arrival = t + 8.0 * len(frame) / self.bitrate_bps + self.delay_s
        if isinstance(order, Stop):
            self._sent_wishes.append((arrival, STOP_WISH))
        if isinstance(order, Velocity):
            self._last_poll_velocity = (arrival, order.vx / 127, order.vy / 127, order.vz / 127, order.vyaw / 127)
            self._sent_wishes.append((arrival, self._last_poll_velocity[1:]))
            for what, field_ in (("arm", "arm"), ("mode", "mode")):
                if getattr(order, field_, 0):
                    self._mark_sent(self._requests.get(what), t)
        for master_id in sent.order_ids:
            with self._lock:
                mine = self._by_master_id.get(master_id)
            self._mark_sent(mine, t)

    def _mark_sent(self, order_id: int | None, t: float) -> None:
        with self._lock:
            info = self._orders.get(order_id) if order_id is not None else None
            if info is None or info["state"] not in ("queued", "requested"):
                return
        self._set_order_state(order_id, "sent", t)

    def close(self) -> None:
        self.recorder.close()
        self._decoder.shutdown()

    # ------------------------------------------------------------------
    # Events from the master (or a replay)
    # ------------------------------------------------------------------

    def _on_events(self, events: list, t: float) -> None:
        for event in events:
            if isinstance(event, PoseReceived):
                self._pose(event.reply, t, event.round_trip_s)
            elif isinstance(event, PollSent):
                self._poll_sent(event, t)
            elif isinstance(event, ImageProgress):
                self._image_progress(event, t)
            elif isinstance(event, ImageComplete):
                self._image_complete(event, t)
            elif isinstance(event, ImageAbandoned):
                self._image_abandoned(event, t)
            elif isinstance(event, OrderAcknowledged):
                self._order_state(event.order_id, "acknowledged", t)
            elif isinstance(event, OrderCancelled):
                self._order_state(event.order_id, f"cancelled: {event.reason}", t)
            elif isinstance(event, OrderRejected):
                reason = getattr(event, "reason_text", None) or str(getattr(event, "reason", "no reason given"))
                self._order_state(event.order_id, f"rejected: {reason}", t)
            elif isinstance(event, OrderNotSent):
                self._order_state(event.order_id, f"cancelled: {event.reason} (never sent)", t)
            elif isinstance(event, StopConfirmed):
                mode = REPORTED_MODE_NAMES.get(int(event.mode), str(event.mode))
                self._order_state(event.order_id, f"acknowledged: holding in {mode}", t)
            elif isinstance(event, StopNotCarriedOut):
                self._order_state(event.order_id, "not carried out: no autopilot holds the vehicle", t)
            elif isinstance(event, ReplyLost):
                self.history.link_events.append((t, "lost", 0))
                self._publish("link", {"t": t, "lost": True})
            elif isinstance(event, InauthenticFrame):
                self._inauthentic(t)
            elif isinstance(event, LateReply):
                self.late_replies += 1
            elif isinstance(event, OrderFateUnknown):
                self._order_state(event.order_id, "unknown: the ROV restarted before its answer came (not resent)", t)
            elif isinstance(event, Synced):
                restarted = event.restarted and not event.first
                self.note("ROV restarted (new BOOT): link synchronised again" if restarted else "link synchronised",
                          "alert" if restarted else "info")
                if event.restarted and not event.first:
                    self._resend_image_settings()
            elif isinstance(event, RequestExpired):
                self._refuse_request(event.what, t, "not confirmed by the ROV within its time")

    def _resend_image_settings(self) -> None:
        """A restarted ROV has its default image settings again (§8): ours go again."""
        s = self.requested_settings
        self.set_image_settings(roi=s.roi, shift=s.shift, mono=s.mono, budget_bytes=s.budget_bytes)

    def _inauthentic(self, t: float) -> None:
        """A forged or replayed frame: counted; more than a few in a while is an alert."""
        self.inauthentic_frames += 1
        self.history.link_events.append((t, "forged", 0))
        if self._auth_recent(t) > AUTH_ALERT_COUNT and (
                self._auth_alerted_at is None or t - self._auth_alerted_at > AUTH_ALERT_WINDOW_S):
            self._auth_alerted_at = t
            self.note(f"ALERT: {self._auth_recent(t)} inauthentic frames in {AUTH_ALERT_WINDOW_S:g} s "
                      f"(forged or replayed replies on the link)", "alert")

    def _auth_recent(self, t: float) -> int:
        return sum(1 for e in list(self.history.link_events)[-300:]
                   if e[1] == "forged" and t - e[0] <= AUTH_ALERT_WINDOW_S)

    def _pose(self, reply: Reply, t: float, round_trip_s: float | None) -> None:
        # The ROV sampled its odometry when the poll arrived: the reply's own
        # transmission and the intrinsic delay ago.
        sampled = t - (8.0 * (len(reply.encode()) + OVERHEAD) / self.bitrate_bps) - self.delay_s
        pose = Pose.from_reply(reply)
        with self._lock:
            previous, previous_at = self._reply, self._odometry_at
            entered_failsafe = bool(reply.failsafe) and (previous is None or not previous.failsafe)
            self._reply, self._reply_at, self._odometry_at = reply, t, sampled
            # The poll this reply answers left then: the ROV cannot have acted on it earlier.
            self._reply_poll_sent_at = t - round_trip_s if round_trip_s is not None else None
            if previous is not None and previous_at is not None and sampled - previous_at > 0.05:
                dt = sampled - previous_at
                old = Pose.from_reply(previous)
                dyaw = (pose.yaw_deg - old.yaw_deg + 180) % 360 - 180
                new = ((pose.x_m - old.x_m) / dt, (pose.y_m - old.y_m) / dt, (pose.z_m - old.z_m) / dt, dyaw / dt)
                a = 0.5  # smooth the finite difference of quantised odometry
                self._velocity_est = tuple(a * n + (1 - a) * o for n, o in zip(new, self._velocity_est))
            if round_trip_s is not None:
                self.history.round_trips.append(round_trip_s)
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
            self.note("ROV reports FAILSAFE: it had no poll for its failsafe time, braked and holds", "alert")
        self._publish("pose", self.pose_state())
        self._check_requests(t)

    # When and where was an image captured?  Decision: the console stamps it from
    # the replies; the protocol carries no capture time (bytes are dear, and its
    # image object is fixed by docs/PROTOCOL.md §4).  The ROV (rov/node.py) captures the
    # next image as the last trunk of the previous one goes out, in the reply that
    # carries it (prefetch), or, when that capture was thrown away (settings
    # changed, too old, an image abandoned, the first image), when a poll asks for
    # the new IMG.  Either way the capture lies between the reply that ended the
    # previous image (or was the last before it was abandoned) and the reply that
    # brings the new one's first trunk (from when the poll that reply answers was
    # sent: the ROV took it later).  So an image is stamped with that interval,
    # "not_before" to "not_after", and with the odometry of the "not_before" reply
    # (the prefetch's pose: the ROV sampled both while answering that poll).  If
    # the reply that ended the previous image was lost and sent again, the capture
    # is earlier than "not_before" by the retries (one poll cycle each).  Without an
    # earlier reply to bound it ("not_before" None) it may be of any age (§4).
    def _mark_capture_window(self, t: float, why: str, *, img: int | None = None, total: int | None = None,
                             since: float | None = None) -> None:
        # The ROV may have captured from the moment it took the first poll whose
        # answer could carry the previous image's last trunk (OFFSET + the largest
        # trunk its SIZE allows reaches the object's end): not before that poll left
        # here.  A sure bound whatever is lost and sent again, and whatever the load
        # on either end (the poll this reply answers may be a resend, later than the
        # capture); without the image's end, the poll this reply answers.
        reply = self._reply
        pose = Pose.from_reply(reply) if reply is not None and reply.position_valid is not False else None
        sent = self._reply_poll_sent_at
        if img is not None and total is not None:
            # This image's polls only (IMG wraps at 8): those sent since its first request.
            ends = [at for at, i, offset, cap in list(self._image_requests)
                    if i == img and offset + cap >= total and (since is None or at >= since) and at <= t]
            if ends:
                sent = min(ends) if sent is None else min(min(ends), sent)
        self._next_capture = (sent if sent is not None and sent <= t else t, pose, why)

    def _capture_stamp(self, t_first: float) -> dict:
        mark = self._next_capture
        self._next_capture = None
        reply = self._reply
        if mark is None:
            pose = None
            not_before = None
            why = "unknown"
        else:
            not_before, pose, why = mark
        # Without a bound below, the first trunk's reply is all there is.
        if pose is None and reply is not None and mark is None:
            pose = Pose.from_reply(reply)
        t_est = not_before if not_before is not None else t_first
        return {"t": round(t_est, 3), "wall": round(self.wall(t_est), 3),
                "not_before_wall": None if not_before is None else round(self.wall(not_before), 3),
                "not_after_wall": round(self.wall(t_first), 3), "how": why,
                "pose": None if pose is None else {k: round(v, 3) for k, v in pose.as_dict().items()}}

    def _image_progress(self, event: ImageProgress, t: float) -> None:
        with self._lock:
            view = self.image
            if view.img != event.img or event.received_bytes < view.received_bytes:
                view.img = event.img
                view.started_at = t
                view.picture = None
                view.decoded_bytes = 0
                view.complete = False
                view.settings = self._confirmed_settings
                view.serial += 1
                view.capture = self._capture_stamp(t)
            view.received_bytes = event.received_bytes
            view.total_bytes = event.total_bytes
            view.stream = event.prefix
        self._publish("image_progress", self.image_state())
        self._decode_later(event.img, event.prefix)

    def _image_complete(self, event: ImageComplete, t: float) -> None:
        with self._lock:
            self.image.complete = True
            self.image.images_completed += 1
            self.image.stream = event.data
            self._keep_image(t, partial=False)
            self._mark_capture_window(t, "prefetch", img=event.img, total=2 + len(event.data),
                                      since=event.started_at)
        self.recorder.write({"k": "image", "t": round(t, 4), "img": event.img, "bytes": len(event.data),
                             "seconds": round(event.at - event.started_at, 3)})
        self.note(f"image {event.img} complete: {len(event.data)} bytes in {event.at - event.started_at:.1f} s")

    def _image_abandoned(self, event, t: float) -> None:
        with self._lock:
            if self.image.img == event.img and not self.image.complete and self.image.stream:
                self._keep_image(t, partial=True)
            self._mark_capture_window(t, "request")
        self.note(f"image {event.img} abandoned after {event.received_bytes} bytes: {event.reason}")

    def _keep_image(self, t: float, *, partial: bool) -> None:
        """Into the pictures to look back at (caller holds the lock)."""
        v = self.image
        s = v.settings
        self._image_history.append({
            "n": v.serial, "img": v.img, "capture": v.capture, "bytes": len(v.stream),
            "total_bytes": v.total_bytes, "partial": partial,
            "received_wall": round(self.wall(t), 3),
            "seconds": None if v.started_at is None else round(t - v.started_at, 2),
            "settings": None if s is None else {"roi": list(s.roi) if s.roi else None, "shift": s.shift,
                                                 "mono": s.mono, "budget_bytes": s.budget_bytes},
            "stream": bytes(v.stream),
        })

    def image_history(self) -> list[dict]:
        """Completed (and abandoned, `partial`) images, oldest first, with their
        metadata and DEBT stream ("stream": decode it for the picture)."""
        with self._lock:
            return [dict(e) for e in self._image_history]

    def _decode_later(self, img: int, prefix: bytes) -> None:
        with self._lock:
            self._pending_decode = (img, prefix)
            if self._decode_busy:
                return
            self._decode_busy = True
        try:
            self._decoder.submit(self._decode_loop)
        except RuntimeError:  # shut down
            self._decode_busy = False

    def _decode_loop(self) -> None:
        from rovlink import debt

        while True:
            with self._lock:
                job, self._pending_decode = self._pending_decode, None
                if job is None:
                    self._decode_busy = False
                    return
            img, prefix = job
            try:
                picture = debt.decode(prefix)
            except debt.IncompleteStream:
                continue  # not even the header yet
            except ValueError as exc:
                # A damaged stream, or one of another DEBT format (an ROV of
                # another rovlink version, an old recording): said once per
                # picture, loud, since the pilot sees no picture.
                with self._lock:
                    serial = self.image.serial if self.image.img == img else None
                    first = serial is not None and serial != self._undecodable_serial
                    if first:
                        self._undecodable_serial = serial
                if first:
                    self.note(f"picture {serial} cannot be decoded: {exc}", "alert")
                continue
            with self._lock:
                if self.image.img != img or len(prefix) < self.image.decoded_bytes:
                    continue
                self.image.picture = picture
                self.image.decoded_bytes = len(prefix)
                self.image.decoded_at = self.now()
            self._publish("image", self.image_state())

    def _order_state(self, master_id: int, state: str, t: float) -> None:
        """A one-shot order's fate, from the master (its ids)."""
        with self._lock:
            order_id = self._by_master_id.get(master_id)
        if order_id is None:
            return
        info = self._set_order_state(order_id, state, t)
        if info is not None and info["kind"] == "IMAGE":
            with self._lock:
                settings = self._image_orders.pop(order_id, None)
                if state == "acknowledged" and settings is not None:
                    self._confirmed_settings = settings  # applies from the next image on

    def _set_order_state(self, order_id: int, state: str, t: float) -> dict | None:
        with self._lock:
            info = self._orders.get(order_id)
            if info is None:
                return None
            info["state"] = state
            info["t_" + state.split(":")[0]] = t
            info = dict(info)
        self.recorder.write({"k": "order_state", "t": round(t, 4), "id": order_id, "kind": info["kind"],
                             "state": state})
        self._publish("order", info)
        if state.startswith(("rejected", "refused", "not carried out", "unknown")):
            self.note(f"{info['kind']} order {order_id} {state}", "alert")
        return info

    def _new_order(self, kind: str, state: str, detail: dict, t: float) -> int:
        """A console order id and its record (caller holds no lock)."""
        with self._lock:
            order_id = self._next_order_id
            self._next_order_id += 1
            info = {"id": order_id, "kind": kind, "state": state, "t_queued": t, **detail}
            self._orders[order_id] = info
            if len(self._orders) > 200:
                for old in sorted(self._orders)[:-200]:
                    del self._orders[old]
            if len(self._by_master_id) > 400:
                for old in sorted(self._by_master_id)[:-200]:
                    del self._by_master_id[old]
            info = dict(info)
        self.recorder.write({"k": "order", "t": round(t, 4), "id": order_id, "kind": kind, **detail})
        self._publish("order", info)
        return order_id

    # arm/disarm and mode are requests the link repeats; the vehicle's
    # reported state says whether it followed.
    def _check_requests(self, t: float) -> None:
        if not self._requests:
            return
        reply = self._reply
        for what, order_id in list(self._requests.items()):
            with self._lock:
                info = self._orders.get(order_id)
            if info is None:
                self._requests.pop(what, None)
                continue
            followed = reply is not None and self._reply_at is not None and self._reply_at >= info["t_queued"] and (
                reply.armed == info["armed"] if what == "arm" else int(reply.mode) == int(MODE_NAMES[info["mode"]]))
            if followed:
                self._requests.pop(what, None)
                self._set_order_state(order_id, "followed", t)
            elif t - info["t_queued"] > REQUEST_FOLLOW_S:
                self._refuse_request(what, t, f"the vehicle did not follow within {REQUEST_FOLLOW_S:g} s")

    def _refuse_request(self, what: str, t: float, why: str) -> None:
        order_id = self._requests.pop(what, None)
        if order_id is None:
            self.note(f"{what} request {why}", "alert")
            return
        self._set_order_state(order_id, f"refused: {why}", t)

    # ------------------------------------------------------------------
    # Commands (any thread)
    # ------------------------------------------------------------------

    def set_velocity(self, vx: float, vy: float, vz: float, vyaw: float) -> None:
        """Velocity wish, fractions -1..1 of the maximum (body frame, z down)."""
        values = (vx, vy, vz, vyaw)
        for name, v in zip(("vx", "vy", "vz", "vyaw"), values):
            if not isinstance(v, (int, float)) or not math.isfinite(v) or not -1.0 <= v <= 1.0:
                raise OrderError(f"{name} must be a number in -1..1, got {v!r}")
        ints = tuple(int(round(v * 127)) for v in values)
        t = self.now()
        with self._lock:
            self.master.set_velocity(*ints, t)
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
        with self._lock:
            self.master.set_pilot_in_force(in_force)

    def set_attended(self, attended: bool) -> None:
        """Whether a pilot holds control (the command layer says): replies are
        then sized for the pilot's reaction and a fresh pose, not only for pictures."""
        with self._lock:
            self.master.set_attended(attended)

    def recentred(self) -> None:
        """The holder's own input is neutral: its re-centring reaches the ROV
        (releasing a HOLD) even if the sticks move again before the next poll."""
        with self._lock:
            self.master.recentred()

    def replayed_wish(self, values: tuple[float, ...]) -> None:
        """A recorded wish change, shown as it was (a replay sends nothing)."""
        with self._lock:
            self._wish = tuple(float(v) for v in values)
            self.history.commanded.append((self.now(), *self._wish))
        self._publish("wish", self.wish_state())

    def replayed_order(self, record: dict) -> None:
        """A recorded order or change of its state, listed as it was."""
        order_id = record.get("id")
        if order_id is None:  # recordings older than order ids
            self.note("(replay) " + ", ".join(f"{k}={v}" for k, v in record.items() if k not in ("k", "t")))
            return
        t = self.now()
        with self._lock:
            if record["k"] == "order":
                detail = {k: v for k, v in record.items() if k not in ("k", "t", "id", "kind")}
                self._orders[order_id] = {"id": order_id, "kind": record.get("kind", "?"), "state": "queued",
                                          "t_queued": t, **detail}
            elif order_id in self._orders:
                self._orders[order_id]["state"] = record.get("state", "?")
            info = dict(self._orders[order_id]) if order_id in self._orders else None
        if info is not None:
            self._publish("order", info)

    def velocity_wish(self) -> tuple[float, float, float, float]:
        return self._wish

    def wish_state(self) -> dict:
        w = self._wish
        return {"vx": w[0], "vy": w[1], "vz": w[2], "vyaw": w[3]}

    def arm(self, armed: bool) -> int:
        """Request arming (or disarming); the returned order id is followed
        until the vehicle reports it armed (disarmed), or refused."""
        t = self.now()
        with self._lock:
            self.master.request_arm(bool(armed), t)
        self._supersede("arm", t)
        order_id = self._new_order("ARM" if armed else "DISARM", "requested", {"armed": bool(armed)}, t)
        self._requests["arm"] = order_id
        self.note("arm requested" if armed else "disarm requested")
        return order_id

    def _supersede(self, what: str, t: float) -> None:
        old = self._requests.pop(what, None)
        if old is not None:
            self._set_order_state(old, "cancelled: superseded by a newer request", t)

    def set_mode(self, mode: str | int) -> None:
        if isinstance(mode, str):
            if mode.upper() not in MODE_NAMES:
                raise OrderError(f"unknown mode {mode!r}; one of {', '.join(MODE_NAMES)}")
            value = MODE_NAMES[mode.upper()]
        else:
            if mode not in MODE_NAMES.values():
                raise OrderError(f"mode must be 1..6, got {mode!r}")
            value = Mode(mode)
        t = self.now()
        with self._lock:
            self.master.request_mode(value, t)
        self._supersede("mode", t)
        order_id = self._new_order("MODE", "requested", {"mode": value.name}, t)
        self._requests["mode"] = order_id
        self.note(f"mode {value.name} requested")
        return order_id

    def _queue(self, order, kind: str, detail: dict) -> int:
        t = self.now()
        order_id = self._new_order(kind, "queued", detail, t)
        with self._lock:
            master_id = self.master.send_order(order)
            self._by_master_id[master_id] = order_id
        return order_id

    def send_position(self, x_m: float, y_m: float, z_m: float, yaw_deg: float = 0.0, *, relative: bool = False,
                      body: bool = False) -> int:
        for name, v in (("x_m", x_m), ("y_m", y_m), ("z_m", z_m), ("yaw_deg", yaw_deg)):
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise OrderError(f"{name} must be a finite number, got {v!r}")
        yaw = (yaw_deg + 180.0) % 360.0 - 180.0
        try:
            order = Position(int(round(x_m * 100)), int(round(y_m * 100)), int(round(z_m * 100)),
                             int(round(yaw * 100)), bool(relative), bool(body))
        except ProtocolError as exc:
            raise OrderError(str(exc)) from None
        # The ROV flies a position order in GUIDED: the pilot is told before it goes.
        return self._queue(order, "POSITION", {"x_m": x_m, "y_m": y_m, "z_m": z_m, "yaw_deg": yaw,
                                               "relative": relative, "body": body, "mode": "GUIDED"})

    def stop(self) -> int:
        """STOP: neutral velocity now, cancel queued targets, hold depth."""
        self.set_velocity(0.0, 0.0, 0.0, 0.0)
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
        with self._lock:
            self._image_orders[order_id] = settings
        return order_id

    def cancel_stop(self) -> bool:
        """Give up a STOP the ROV shows it cannot carry out (no autopilot), so that
        a DISARM or a SURFACE can go out (protocol 1.1); False if there is none."""
        cancel = getattr(self.master, "cancel_stop", None)
        with self._lock:
            done = bool(cancel()) if cancel is not None else False
        if done:
            self.note("STOP cancelled by the pilot")
        return done

    def stopping(self) -> bool:
        """A STOP is being sent until the ROV confirms it: no order and no wish goes out meanwhile."""
        return bool(getattr(self.master, "stopping", False))

    def next_image(self) -> None:
        with self._lock:
            self.master.abandon_image()

    # ------------------------------------------------------------------
    # State (any thread)
    # ------------------------------------------------------------------

    @property
    def last_reply(self) -> Reply | None:
        return self._reply

    def odometry_age_s(self) -> float | None:
        return None if self._odometry_at is None else self.now() - self._odometry_at

    def predicted_pose(self, at: float | None = None) -> Pose | None:
        """Dead reckoning from the last odometry to `at` (session time; now by
        default): the vehicle model run from the pose's sample time under the
        wishes as they were sent, each from when it reached the ROV (never
        today's wish over yesterday's pose), as the ROV applies them: a STOP
        brakes, HOLD ignores non-zero wishes until a neutral one arrives, a
        wish lapses after VELOCITY_LAPSE_S without another."""
        with self._lock:
            reply, sampled, vel = self._reply, self._odometry_at, self._velocity_est
            timeline = list(self._sent_wishes)
        if reply is None or sampled is None:
            return None
        # No further than the ROV's failsafe time: by then, with no poll
        # heard, it has stopped; beyond it the uncertainty grows instead.
        end = sampled + max(0.0, min((self.now() if at is None else at) - sampled, self.rov_failsafe_s))
        pose = Pose.from_reply(reply)
        if end <= sampled:
            return pose
        from rovlink.rov.vehicle import VehicleModel, VehicleState

        state = VehicleState(x_m=pose.x_m, y_m=pose.y_m, z_m=pose.z_m, yaw_rad=math.radians(pose.yaw_deg),
                             vn_mps=vel[0], ve_mps=vel[1], vd_mps=vel[2], yaw_rate_radps=math.radians(vel[3]))
        model = VehicleModel(state=state)
        mode = _protocol_to_sub_mode(reply.mode)
        hold = bool(reply.hold or reply.failsafe)
        wish, wish_at = NEUTRAL_WISH, -math.inf
        t = sampled
        for arrival, sent in timeline:
            if arrival > t:
                t = self._predict_until(model, t, min(arrival, end), wish, wish_at, hold, mode, reply.armed)
                if t >= end:
                    break
            if sent is STOP_WISH:
                wish, hold = NEUTRAL_WISH, True
            else:
                wish, wish_at = sent, arrival
                if hold and not any(sent):
                    hold = False  # the re-centring reached the ROV
        if t < end:
            self._predict_until(model, t, end, wish, wish_at, hold, mode, reply.armed)
        s = model.state
        return Pose(s.x_m, s.y_m, s.z_m, pose.roll_deg, pose.pitch_deg, math.degrees(s.yaw_rad))

    @staticmethod
    def _predict_until(model, t: float, until: float, wish: tuple, wish_at: float, hold: bool, mode,
                       armed: bool) -> float:
        """Step the model from t to `until` under `wish` as the ROV applies it."""
        from rovlink.rov.vehicle import Controls, PilotInput

        lapse_at = wish_at + VELOCITY_LAPSE_S
        for t0, t1, applied in ((t, min(until, lapse_at), wish), (max(t, lapse_at), until, NEUTRAL_WISH)):
            if t1 > t0:
                if hold:
                    applied = NEUTRAL_WISH
                model.step(t1 - t0, Controls(pilot=PilotInput.from_velocity(*applied), mode=mode, armed=armed,
                                             target=None))
        return until

    def preview_path(self, x_m: float, y_m: float, z_m: float, yaw_deg: float = 0.0, *, seconds: float = 30.0,
                     step_s: float = 0.5) -> list[tuple[float, float, float]]:
        """Where a POSITION order would take the vehicle (GUIDED, from the predicted pose)."""
        from rovlink.rov.vehicle import (
            Controls,
            PilotInput,
            PositionTarget,
            SubMode,
            VehicleModel,
            VehicleState,
        )

        start = self.predicted_pose() or Pose(0, 0, 0, 0, 0, 0)
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

    def pose_state(self) -> dict:
        reply = self._reply
        out: dict[str, Any] = {"t": self.now(), "received": None, "predicted": None}
        if reply is not None:
            out["received"] = Pose.from_reply(reply).as_dict()
            age = self.odometry_age_s()
            out.update(armed=reply.armed, mode=REPORTED_MODE_NAMES.get(reply.mode, "OTHER"), failsafe=reply.failsafe,
                       autopilot=reply.autopilot, position_valid=reply.position_valid,
                       hold=getattr(reply, "hold", None), attitude_valid=getattr(reply, "attitude_valid", None),
                       stopping=self.stopping(),
                       odometry_age_s=age, stale=self.link_condition()[0] == "lost",
                       uncertainty_m=None if age is None else round(MAX_SPEED_MPS * max(0.0, age), 3))
            predicted = self.predicted_pose()
            out["predicted"] = predicted.as_dict() if predicted else None
            out["velocity"] = self.measured_velocity()
        return out

    def measured_velocity(self) -> dict | None:
        """Speeds from successive received poses (finite differences, smoothed): body
        forward and right, down, and yaw rate; None before two replies."""
        with self._lock:
            reply, (vn, ve, vd, vyaw) = self._reply, self._velocity_est
            known = self._odometry_at is not None and len(self.history.trail) >= 2
        if reply is None or not known:
            return None
        yaw = math.radians(reply.yaw_cdeg / 100)
        return {"forward_mps": round(vn * math.cos(yaw) + ve * math.sin(yaw), 3),
                "right_mps": round(-vn * math.sin(yaw) + ve * math.cos(yaw), 3),
                "down_mps": round(vd, 3), "yaw_dps": round(vyaw, 2)}

    def link_condition(self, t: float | None = None) -> tuple[str, float | None]:
        """("up" | "degraded" | "lost" | "replay" | "starting", seconds since the last reply)."""
        t = self.now() if t is None else t
        since = None if self._reply_at is None else max(0.0, t - self._reply_at)
        if self.replaying:
            return "replay", since
        if since is None:
            return ("lost" if t > self.lost_after_s else "starting"), since
        if since >= self.lost_after_s:
            return "lost", since
        recent = [e for e in list(self.history.link_events)[-200:]
                  if e[1] in ("lost", "crc") and t - e[0] <= DEGRADED_WINDOW_S]
        return ("degraded" if recent else "up"), since

    def image_state(self) -> dict:
        v = self.image
        s = v.settings
        return {
            "img": v.img, "received_bytes": v.received_bytes, "total_bytes": v.total_bytes, "complete": v.complete,
            "decoded_bytes": v.decoded_bytes, "started_at": v.started_at, "decoded_at": v.decoded_at,
            "images_completed": v.images_completed, "serial": v.serial, "capture": v.capture,
            "settings": None if s is None else {"roi": list(s.roi) if s.roi else None, "shift": s.shift,
                                                 "mono": s.mono, "budget_bytes": s.budget_bytes},
        }

    def _watch_link(self, state: str, silent_s: float | None) -> None:
        """Link lost and back into the log, once per change."""
        with self._lock:
            was, self._shown_link_state = self._shown_link_state, state
        if was == state or state in ("starting", "replay"):
            return
        if state == "lost":
            self.note("LINK LOST: no reply from the ROV" + (f" for {silent_s:.0f} s" if silent_s else ""), "alert")
        elif was == "lost":
            self.note("link back: replies arrive again", "warn")

    def link_state(self) -> dict:
        t = self.now()
        m = self.master.stats
        recent = [e for e in list(self.history.link_events) if t - e[0] <= 10.0]
        polls = sum(1 for e in recent if e[1] == "tx")
        span = min(10.0, max(t, 1e-6))
        rtts = sorted(self.history.round_trips)
        state, since = self.link_condition(t)
        silent_s = since if since is not None else (t if state == "lost" else None)
        self._watch_link(state, silent_s)
        inferred = state == "lost" and silent_s is not None and silent_s >= self.rov_failsafe_s
        failsafe_at = time.time() - silent_s + self.rov_failsafe_s if inferred else None
        return {
            "state": state,
            "since_reply_s": silent_s,
            "lost_after_s": self.lost_after_s,
            "rov_failsafe_s": self.rov_failsafe_s,
            # No poll has reached the ROV for its failsafe time: it has
            # stopped and holds depth (docs/PROTOCOL.md §3), though it cannot say so.
            "failsafe_inferred": inferred,
            "failsafe_inferred_at": failsafe_at,
            "failsafe_inferred_since": time.strftime("%H:%M:%S", time.localtime(failsafe_at)) if inferred else None,
            "t": t,
            "poll_rate_hz": polls / span,
            "reply_rate_hz": sum(1 for e in recent if e[1] == "rx") / span,
            "round_trip_s": rtts[len(rtts) // 2] if rtts else None,
            "last_round_trip_s": m.last_round_trip_s,
            "polls_sent": m.polls_sent,
            "replies": m.replies,
            "replies_lost": m.replies_lost,
            "crc_errors": self.master.decoder.crc_errors,
            "protocol_errors": m.protocol_errors,
            "bytes_per_s": sum(e[2] for e in recent) / span,
            "bytes_sent": m.bytes_sent,
            "bytes_received": m.bytes_received,
            "odometry_age_s": self.odometry_age_s(),
            "failsafe": bool(self._reply and self._reply.failsafe),
            "autopilot": bool(self._reply and self._reply.autopilot),
            "estimated_ber": self.master.estimated_ber(),
            "images_completed": m.images_completed,
            "images_abandoned": m.images_abandoned,
            "version": self.link_version,  # "2": every frame authenticated; "1.1": INSECURE
            "inauthentic_frames": self.inauthentic_frames,
            "late_replies": self.late_replies,
            "auth_alert": self._auth_recent(t) > AUTH_ALERT_COUNT,
            # Up means replies arrive, not that polls leave (a dead channel still takes polls).
            "link_up": state in ("up", "degraded"),
            "transport_up": self.endpoint.is_up if self.endpoint is not None else False,
        }

    def orders_state(self) -> list[dict]:
        with self._lock:
            return [dict(v) for _, v in sorted(self._orders.items())][-50:]

    def state(self) -> dict:
        wish = self._wish
        return {
            "pose": self.pose_state(),
            "image": self.image_state(),
            "link": self.link_state(),
            "velocity_wish": {"vx": wish[0], "vy": wish[1], "vz": wish[2], "vyaw": wish[3]},
            "orders": self.orders_state(),
            "log": self.log_entries(20),
            "replaying": self.replaying,
            # The session's clock time now: a replay's own (it stands still while paused).
            "wall": round(self.wall(self.now()), 3),
        }

    def picture(self) -> np.ndarray | None:
        return self.image.picture
