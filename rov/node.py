"""The ROV program: link slave + autopilot bridge + camera + DEBT encoder + failsafe.

Goals: answer every poll at once with fresh odometry; turn the operator's
orders into autopilot requests exactly once; keep images flowing without
ever delaying a reply for the encoder; stop the vehicle when the operator
falls silent; survive the modem and the autopilot going away.

Plan: one asyncio loop runs `link.aio.run_slave` on the modem's Endpoint and
a 10 Hz task that copies the bridge's snapshot into the slave's status.  The
slave's events are turned into bridge calls here.  Images are captured and
encoded in one worker thread; the result is handed to the slave from the
loop, and until then the slave answers without image data (docs/PROTOCOL.md §4).

The slave decides what the protocol means (docs/PROTOCOL.md 1.1: ARM/MODE acted
on when they change, HOLD, the velocity lapse, the failsafe); the node turns
its events into bridge calls and reports the autopilot's answers back:
`OrderStarted` -> `bridge.goto(...)`, whose ticket is watched (10 Hz) and
reported with `slave.order_outcome(token, accepted, reason)`, also after the
slave abandoned the order (a late accept then brakes).

Decisions:
- A POSITION ticket "cancelled" by the bridge (another mode was requested,
  a brake, the bridge stopping) is reported as not accepted, REASON 1
  (impossible now); "failed" carries the bridge's own REASON (1 or 2).
- STOP acts on every poll that carries it (§2): a brake is asked of the bridge
  unless one is still pending.  A disarm acts whenever it arrives: one is
  asked unless one is pending or the vehicle already shows disarmed.
- A wish that replaces a standing POSITION target while the autopilot is in
  GUIDED asks for the hold mode (POS_HOLD with a position estimate, else
  DEPTH_HOLD), in which the sticks drive; a brake already is such a mode.
- When the last trunk of an image goes out, the next image is captured and
  encoded at once, with the current settings, so it is ready when asked for
  (saving one empty reply per image).  Settings changed since, or an image
  older than `prefetch_max_age_s`, and it is thrown away.
- An ROI reaching outside the image is clipped to it; one left empty is
  dropped.  A setting DEBT refuses is logged and the image is sent without
  its ROI rather than not at all.
- FOLLOW (docs/PROTOCOL.md §10) with a `follower` (rov/follow.py): its camera
  (rov/followcam.py, shared with the acoustic node) grabs frames at `camera_hz` and keeps the last `history_s` of them;
  the tracker starts on the frame of the picture the ROI was drawn on (or the
  newest, when that one is no longer kept), catches up through the frames
  since, then follows every new one.  Pictures under FOLLOW are the newest
  frame, coded with the follower's ROI, their stream led by the TRACK record
  (which BUDGET counts).  Without a follower the slave refuses FOLLOW.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from rovlink.link.aio import run_slave
from rovlink.link.radio.frame import MAX_FRAME
from rovlink.link.radio.messages import FAILSAFE_S, VELOCITY_FULL, ImageSettings, Mode, Position, Reason, next_img
from rovlink.link.radio.secure import SecureSlave
from rovlink.link.radio.slave import (
    ArmRequested,
    BrakeRequested,
    FailsafeCleared,
    FailsafeEntered,
    ImageDelivered,
    ImageWanted,
    ModeRequested,
    OrderAbandoned,
    OrderDeclined,
    OrderExecuted,
    OrderStarted,
    Slave,
    VelocityCommanded,
    WishInvalid,
    status_from_pose,
)
from rovlink.link.transports.transport import Endpoint

from .followcam import FollowCamera

log = logging.getLogger("rovlink.rov.node")

Grab = Callable[[object], np.ndarray]  # snapshot -> HxW or HxWx3 uint8


@dataclass
class NodeStats:
    images_encoded: int = 0
    images_prefetched_used: int = 0
    encode_failures: int = 0
    orders_rejected: int = 0
    goto_failed: int = 0
    brakes: int = 0
    failsafes: int = 0
    last_encode_s: float | None = None
    worst_encode_s: float = 0.0
    log: list[str] = field(default_factory=list)


def clip_roi(roi, width: int, height: int):
    """Clip (x0, y0, x1, y1) to the image; None if nothing is left."""
    if roi is None:
        return None
    x0, y0, x1, y1 = roi
    x0, x1 = max(0, min(x0, width)), max(0, min(x1, width))
    y0, y1 = max(0, min(y0, height)), max(0, min(y1, height))
    if x1 <= x0 or y1 <= y0:
        return None
    return (x0, y0, x1, y1)


def _warm_up(encode) -> None:
    try:
        for image in (np.zeros((16, 16), np.uint8), np.zeros((16, 16, 3), np.uint8)):
            encode(image, 200, roi=(0, 0, 8, 8), shift=4, mono=image.ndim == 2)
    except Exception:  # a warm-up only; the real encode reports real errors
        log.debug("codec warm-up failed", exc_info=True)


class RovNode:
    def __init__(
        self,
        endpoint: Endpoint,
        bridge,
        grab: Grab,
        *,
        failsafe_s: float = FAILSAFE_S,
        default_settings: ImageSettings | None = None,
        prefetch: bool = True,
        prefetch_max_age_s: float = 5.0,
        encode: Callable[..., bytes] | None = None,
        key: bytes | None = None,
        follower=None,
        camera_hz: float = 10.0,
        history_s: float = 15.0,
        objects=None,
    ) -> None:
        self.endpoint = endpoint
        self.bridge = bridge
        self.grab = grab
        # rov/objects.py's geometry (a CameraGeometry): objects recognised in a thread of their own
        # and told in the replies' annex (§11.1); None: none (nor on version 1.1).
        self._objects_geometry = objects
        self.objects = None
        self.prefetch = prefetch
        self.prefetch_max_age_s = prefetch_max_age_s
        self.stats = NodeStats()
        warm_debt = encode is None
        if encode is None:
            from rovlink import debt

            encode = debt.encode
        self._encode = encode
        max_frame = endpoint.max_frame or MAX_FRAME
        self.slave = Slave(
            image_source=self._prefetched,
            failsafe_s=failsafe_s,
            max_frame=max_frame,
            default_settings=default_settings,
            now=time.monotonic(),
        )
        # What the link drives: the slave itself (version 1.1), or, with a key,
        # version 2 in front of it (docs/PROTOCOL.md §8).
        self.link_end = self.slave if key is None else SecureSlave(self.slave, key)
        # What the ROV tells of its scene (docs/PROTOCOL.md §11): the altitude, and the objects
        # its detector puts; None on version 1.1, whose replies have no annex.
        self.scene = None if key is None else self.link_end.scene
        self._worker = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="debt-encoder")
        # DEBT's coder compiles on first use (tens of seconds when its cache
        # is cold): do it now, while the link comes up, not at the first image,
        # in a daemon thread: a stopped node exits at once, never waiting for
        # the compiler (the encoder's executor thread is joined at exit).
        if warm_debt:
            from rovlink import debt

            debt.warm_up_in_background("debt-warm-up (rov)")
        else:
            self._worker.submit(_warm_up, self._encode)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._prefetched_image: tuple[int, ImageSettings, float, bytes] | None = None
        self._arm_ticket = None  # (ticket, wanted)
        self._brake_ticket = None
        self._brake_stands = False  # no goto, mode request or moving wish since the last brake
        self._order_tickets: dict[int, tuple[object, float]] = {}  # slave token -> (goto ticket, since)
        self._lock = threading.Lock()
        self.follower = follower
        self.slave.follows = follower is not None
        self.camera = None if follower is None else FollowCamera(
            follower, lambda: self.grab(self.bridge.snapshot()), self._note, camera_hz=camera_hz, history_s=history_s)

    # ------------------------------------------------------------------

    async def run(self) -> None:
        """Serve the link until cancelled."""
        self._loop = asyncio.get_running_loop()
        status_task = asyncio.create_task(self._status_loop())
        if self.camera is not None:
            self.camera.start()
        self._start_objects(self.scene)
        try:
            await run_slave(self.link_end, self.endpoint, self._on_events)
        finally:
            status_task.cancel()
            if self.camera is not None:
                self.camera.close()
            if self.objects is not None:
                self.objects.stop()
            self._worker.shutdown(wait=False, cancel_futures=True)

    async def _status_loop(self) -> None:
        while True:
            self._refresh_status()
            self._check_order_tickets(time.monotonic())
            await asyncio.sleep(0.1)

    def _check_order_tickets(self, now: float) -> None:
        """Report the autopilot's answers to POSITION orders back to the slave."""
        for token, (ticket, since) in list(self._order_tickets.items()):
            if not ticket.done:
                if now - since > 30.0:  # a ticket that never resolves: stop watching it
                    del self._order_tickets[token]
                continue
            del self._order_tickets[token]
            accepted = ticket.status == "accepted"
            reason = None
            if ticket.status == "failed":
                self.stats.goto_failed += 1
                reason = ticket.reject_reason
                self._note(f"POSITION order failed: {ticket.reason}")
            elif ticket.status == "cancelled":
                reason = Reason.IMPOSSIBLE
                self._note(f"POSITION order cancelled: {ticket.reason}")
            self._on_events(self.slave.order_outcome(token, accepted, reason, now), now)

    def _refresh_status(self) -> None:
        snap = self.bridge.snapshot()
        self.slave.update_status(
            status_from_pose(
                x_m=snap.x_m,
                y_m=snap.y_m,
                z_m=snap.z_m,
                roll_deg=math.degrees(snap.roll_rad),
                pitch_deg=math.degrees(snap.pitch_rad),
                yaw_deg=math.degrees(snap.yaw_rad),
                armed=snap.armed,
                mode=snap.mode,
                autopilot=snap.autopilot_alive,
                position_valid=snap.position_valid,
                attitude_valid=snap.attitude_valid,
            )
        )
        if self.scene is not None:  # §11.1: told in the replies' annex (version 2 only)
            self.scene.altitude_m = snap.altitude_m

    # ------------------------------------------------------------------
    # Slave events -> bridge
    # ------------------------------------------------------------------

    def _on_events(self, events: list, now: float) -> None:
        for event in events:
            if isinstance(event, VelocityCommanded):
                self._velocity(event)
            elif isinstance(event, ArmRequested):
                self._arm(event.arm)
            elif isinstance(event, ModeRequested):
                self._brake_stands = False
                self.bridge.request_mode(int(event.mode))
                self._note(f"mode {Mode(event.mode).name} requested")
            elif isinstance(event, OrderStarted):
                self._goto(event.token, event.order)
            elif isinstance(event, OrderExecuted):
                self._order(event.order)
            elif isinstance(event, BrakeRequested):
                self._brake(event)
            elif isinstance(event, ImageWanted):
                self._start_encode(event.img, event.settings, deliver=True)
            elif isinstance(event, ImageDelivered):
                if self.prefetch:
                    self._start_encode(next_img(event.img), self.slave.settings, deliver=False)
            elif isinstance(event, FailsafeEntered):
                self._brake_stands = False  # the bridge brakes on its own: a STOP after brakes again
                self.stats.failsafes += 1
                self._note(f"FAILSAFE: no valid poll for {event.silent_s:.1f} s: neutral, brake")
                self.bridge.failsafe(True)
            elif isinstance(event, FailsafeCleared):
                self._note("failsafe cleared: polls are back (HOLD until the sticks are re-centred)")
                self.bridge.failsafe(False)
            elif isinstance(event, OrderDeclined):
                self.stats.orders_rejected += 1
                self._note(f"order rejected (REASON {event.reason}): {event.why}")
            elif isinstance(event, OrderAbandoned):
                self._note(f"order abandoned: {event.why}")
            elif isinstance(event, WishInvalid):
                self._note(f"invalid wish applied as neutral: {event.why}")

    def _velocity(self, event: VelocityCommanded) -> None:
        v = event.velocity
        self.bridge.set_velocity(*(axis / VELOCITY_FULL for axis in (v.vx, v.vy, v.vz, v.vyaw)))
        if not v.is_neutral:
            self._brake_stands = False
        if event.replaces_target:
            snap = self.bridge.snapshot()
            if snap.mode == Mode.GUIDED:
                hold = Mode.POS_HOLD if snap.position_valid else Mode.DEPTH_HOLD
                self.bridge.request_mode(int(hold))
                self._note(f"the wish replaces the position target: {hold.name}")

    def _arm(self, arm: bool) -> None:
        pending = self._arm_ticket
        if pending is not None and not pending[0].done and pending[1] == arm:
            return  # the same request is on its way
        if not arm and not self.bridge.snapshot().armed and (pending is None or pending[1] is False):
            return  # a disarm acts whenever it arrives, but a disarmed vehicle needs none
        self._arm_ticket = (self.bridge.request_arm(arm), arm)
        self._note(f"{'arm' if arm else 'disarm'} requested")

    def _brake(self, event: BrakeRequested) -> None:
        pending = self._brake_ticket
        if pending is not None and not pending.done:
            return  # a STOP repeated until confirmed: one brake at a time
        if pending is not None and pending.status == "accepted" and self._brake_stands:
            if self.bridge.snapshot().mode in (Mode.POS_HOLD, Mode.DEPTH_HOLD):
                return  # still braked since: nothing new to do for a repeated STOP
        self._brake_ticket = self.bridge.brake()
        self._brake_stands = True
        self.stats.brakes += 1
        self._note(f"brake ({event.why}): neutral, target cancelled, POS_HOLD or DEPTH_HOLD")

    def _goto(self, token: int, order: Position) -> None:
        self._brake_stands = False
        yaw = math.radians(order.yaw_cdeg / 100.0)
        ticket = self.bridge.goto(
            order.x_cm / 100.0, order.y_cm / 100.0, order.z_cm / 100.0, yaw,
            relative=order.relative, body=order.body,
        )
        self._note(
            f"POSITION {'relative ' if order.relative else ''}{'body ' if order.body else ''}"
            f"({order.x_cm / 100:.2f}, {order.y_cm / 100:.2f}, {order.z_cm / 100:.2f}) m"
        )
        self._order_tickets[token] = (ticket, time.monotonic())
        if ticket.done:  # refused at once (impossible now): the reply to this poll says so
            self._check_order_tickets(time.monotonic())

    def _order(self, order) -> None:
        if isinstance(order, ImageSettings):
            self._prefetched_image = None  # encoded with the old settings
            self._note(f"IMAGE settings: {order}")
            if self.follower is not None:
                # Off the loop (catching up may take a few hundred ms), and before the next
                # picture's encode, which queues behind it on the same worker.
                self._worker.submit(self._follow, order)

    # ------------------------------------------------------------------
    # FOLLOW (§10)
    # ------------------------------------------------------------------

    @property
    def last_frame_at(self) -> float | None:
        """When the newest camera frame kept was captured (monotonic), None before the first."""
        return self.camera.last_frame_at if self.camera is not None else None

    def _follow(self, settings: ImageSettings) -> None:
        if settings.follow:
            self.camera.follow(settings.roi, settings.keep, settings.drawn_on)
        else:
            self.camera.stop_following()

    def _note(self, text: str) -> None:
        log.info("%s", text)
        with self._lock:
            self.stats.log.append(text)
            del self.stats.log[:-200]

    # ------------------------------------------------------------------
    # Images
    # ------------------------------------------------------------------

    def _prefetched(self, img: int, settings: ImageSettings) -> bytes | None:
        """Slave's image source: an image encoded ahead of the request, if it fits."""
        ready = self._prefetched_image
        if ready is None:
            return None
        p_img, p_settings, made_at, stream = ready
        if p_img == img and p_settings == settings and time.monotonic() - made_at <= self.prefetch_max_age_s:
            self._prefetched_image = None
            self.stats.images_prefetched_used += 1
            return stream
        return None

    def _start_encode(self, img: int, settings: ImageSettings, *, deliver: bool) -> None:
        snap = self.bridge.snapshot()
        future = self._worker.submit(self._capture_and_encode, snap, settings, img)
        loop = self._loop

        def done(f: concurrent.futures.Future) -> None:
            if f.cancelled():
                return
            exc = f.exception()
            if exc is not None:
                self.stats.encode_failures += 1
                self._note(f"image {img} not encoded: {exc}")
                return
            stream = f.result()
            if loop is None or loop.is_closed():
                return  # the node is shutting down
            try:
                loop.call_soon_threadsafe(self._encoded, img, settings, stream, deliver)
            except RuntimeError:
                pass  # the loop closed between the check and the call

        future.add_done_callback(done)

    def _encoded(self, img: int, settings: ImageSettings, stream: bytes, deliver: bool) -> None:
        if deliver:
            if not self.slave.image_ready(img, stream):
                log.debug("image %d no longer wanted", img)
        elif self.slave.settings == settings:
            self._prefetched_image = (img, settings, time.monotonic(), stream)

    def _capture_and_encode(self, snap, settings: ImageSettings, img: int | None = None) -> bytes:
        t0 = time.perf_counter()
        followed = self.camera.followed() if settings.follow and self.camera is not None else None
        record, budget = b"", settings.budget_bytes
        if followed is not None:
            image, at, roi, record = followed
            budget = max(budget - len(record), 1)  # BUDGET counts the TRACK record (§10)
        else:
            image, at = self.camera.newest() if self.camera is not None else (None, None)
            if image is None:
                image, at = np.asarray(self.grab(snap)), (time.monotonic() if self.camera is not None else None)
            roi = settings.roi
        if img is not None and at is not None:
            self.camera.mark(img, at)  # FOLLOW may start on this picture's frame
        image = np.asarray(image)
        height, width = image.shape[:2]
        roi = clip_roi(roi, width, height)
        shift = settings.shift if roi is not None else 0
        mono = True if image.ndim == 2 else settings.mono
        try:
            stream = self._encode(image, budget, roi=roi, shift=shift, mono=mono)
        except ValueError as exc:
            self._note(f"DEBT refused {settings}: {exc}; sending without ROI")
            stream = self._encode(image, budget, mono=mono)
        stream = record + stream
        elapsed = time.perf_counter() - t0
        self.stats.images_encoded += 1
        self.stats.last_encode_s = elapsed
        self.stats.worst_encode_s = max(self.stats.worst_encode_s, elapsed)
        return stream

    def _start_objects(self, outbox) -> None:
        from rovlink.rov.objects import watch_node_camera

        self.objects = watch_node_camera(self.bridge, self.grab, outbox, self._objects_geometry)
