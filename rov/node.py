"""The ROV program: link slave + autopilot bridge + camera + DEBT encoder + failsafe.

Goals: answer every poll at once with fresh odometry; turn the operator's
orders into autopilot requests exactly once; keep images flowing without
ever delaying a reply for the encoder; stop the vehicle when the operator
falls silent; survive the modem and the autopilot going away.

Plan: one asyncio loop runs `link.aio.run_slave` on the modem's Endpoint and
a 10 Hz task that copies the bridge's snapshot into the slave's status.  The
slave's events are turned into bridge calls here.  Images are captured and
encoded in one worker thread; the result is handed to the slave from the
loop, and until then the slave answers without image data (PROTOCOL.md §4).

Decisions:
- ARM and MODE ride in the operator's soft state until the reply shows them,
  so the same request arrives many times: a request is passed to the bridge
  only when it differs from what the autopilot reports and no identical
  request is still pending.
- When the last trunk of an image goes out, the next image is captured and
  encoded at once, with the current settings, so it is ready when asked for
  (saving one empty reply per image).  Settings changed since, or an image
  older than `prefetch_max_age_s`, and it is thrown away.
- An ROI reaching outside the image is clipped to it; one left empty is
  dropped.  A setting DEBT refuses is logged and the image is sent without
  its ROI rather than not at all.
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
from rovlink.link.messages import Arm, ImageSettings, Mode, Position, Stop
from rovlink.link.slave import (
    FailsafeCleared,
    FailsafeEntered,
    ImageDelivered,
    ImageWanted,
    OrderExecuted,
    OrderRejected,
    Slave,
    VelocityCommanded,
    status_from_pose,
)
from rovlink.link.transport import Endpoint

log = logging.getLogger("rovlink.rov.node")

Grab = Callable[[object], np.ndarray]  # snapshot -> HxW or HxWx3 uint8


@dataclass
class NodeStats:
    images_encoded: int = 0
    images_prefetched_used: int = 0
    encode_failures: int = 0
    orders_rejected: int = 0
    goto_failed: int = 0
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
        failsafe_s: float = 3.0,
        default_settings: ImageSettings | None = None,
        prefetch: bool = True,
        prefetch_max_age_s: float = 5.0,
        encode: Callable[..., bytes] | None = None,
    ) -> None:
        self.endpoint = endpoint
        self.bridge = bridge
        self.grab = grab
        self.prefetch = prefetch
        self.prefetch_max_age_s = prefetch_max_age_s
        self.stats = NodeStats()
        if encode is None:
            from rovlink import debt

            encode = debt.encode
        self._encode = encode
        max_frame = endpoint.max_frame or 259
        self.slave = Slave(
            image_source=self._prefetched,
            failsafe_s=failsafe_s,
            max_frame=max_frame,
            default_settings=default_settings,
            now=time.monotonic(),
        )
        self._worker = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="debt-encoder")
        # DEBT's coder compiles on first use (tens of seconds when its cache
        # is cold): do it now, while the link comes up, not at the first image.
        self._worker.submit(_warm_up, self._encode)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._prefetched_image: tuple[int, ImageSettings, float, bytes] | None = None
        self._arm_ticket = None
        self._arm_wanted: bool | None = None
        self._mode_ticket = None
        self._mode_wanted: int | None = None
        self._lock = threading.Lock()

    # ------------------------------------------------------------------

    async def run(self) -> None:
        """Serve the link until cancelled."""
        self._loop = asyncio.get_running_loop()
        status_task = asyncio.create_task(self._status_loop())
        try:
            await run_slave(self.slave, self.endpoint, self._on_events)
        finally:
            status_task.cancel()
            self._worker.shutdown(wait=False, cancel_futures=True)

    async def _status_loop(self) -> None:
        while True:
            self._refresh_status()
            await asyncio.sleep(0.1)

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
            )
        )

    # ------------------------------------------------------------------
    # Slave events -> bridge
    # ------------------------------------------------------------------

    def _on_events(self, events: list, now: float) -> None:
        for event in events:
            if isinstance(event, VelocityCommanded):
                self._velocity(event.velocity)
            elif isinstance(event, OrderExecuted):
                self._order(event.order)
            elif isinstance(event, ImageWanted):
                self._start_encode(event.img, event.settings, deliver=True)
            elif isinstance(event, ImageDelivered):
                if self.prefetch:
                    self._start_encode((event.img + 1) % 8, self.slave.settings, deliver=False)
            elif isinstance(event, FailsafeEntered):
                self.stats.failsafes += 1
                self._note(f"FAILSAFE: no valid poll for {event.silent_s:.1f} s: neutral, depth hold")
                self.bridge.failsafe(True)
            elif isinstance(event, FailsafeCleared):
                self._note("failsafe cleared: polls are back")
                self.bridge.failsafe(False)
            elif isinstance(event, OrderRejected):
                self.stats.orders_rejected += 1
                self._note(f"order rejected (answered, ignored): {event.reason}")

    def _velocity(self, v) -> None:
        self.bridge.set_velocity(v.vx / 127.0, v.vy / 127.0, v.vz / 127.0, v.vyaw / 127.0)
        snap = self.bridge.snapshot()
        if v.arm != Arm.NONE:
            want = v.arm == Arm.ARM
            if snap.armed != want and not self._in_progress(self._arm_ticket, self._arm_wanted == want):
                self._arm_wanted = want
                self._arm_ticket = (self.bridge.request_arm(want), time.monotonic())
                self._note(f"{'arm' if want else 'disarm'} requested")
        if v.mode != Mode.KEEP:
            if snap.mode != v.mode and not self._in_progress(self._mode_ticket, self._mode_wanted == v.mode):
                self._mode_wanted = int(v.mode)
                self._mode_ticket = (self.bridge.request_mode(int(v.mode)), time.monotonic())
                self._note(f"mode {Mode(v.mode).name} requested")

    @staticmethod
    def _in_progress(issued, same_wish: bool, settle_s: float = 2.0) -> bool:
        """An identical request is pending, or was accepted so recently that the
        autopilot's HEARTBEAT may not show it yet."""
        if issued is None or not same_wish:
            return False
        ticket, at = issued
        if not ticket.done:
            return True
        return ticket.status == "accepted" and time.monotonic() - at < settle_s

    def _order(self, order) -> None:
        if isinstance(order, Stop):
            self._note("STOP: neutral, target cancelled, depth hold")
            self.bridge.stop_motion()
        elif isinstance(order, Position):
            yaw = math.radians(order.yaw_cdeg / 100.0)
            ticket = self.bridge.goto(
                order.x_cm / 100.0, order.y_cm / 100.0, order.z_cm / 100.0, yaw,
                relative=order.relative, body=order.body,
            )
            self._note(
                f"POSITION {'relative ' if order.relative else ''}{'body ' if order.body else ''}"
                f"({order.x_cm / 100:.2f}, {order.y_cm / 100:.2f}, {order.z_cm / 100:.2f}) m"
            )
            self._watch_goto(ticket)
        elif isinstance(order, ImageSettings):
            self._prefetched_image = None  # encoded with the old settings
            self._note(f"IMAGE settings: {order}")

    def _watch_goto(self, ticket) -> None:
        def watch() -> None:
            ticket.wait(30.0)
            if ticket.status == "failed":
                self.stats.goto_failed += 1
                self._note(f"POSITION order failed: {ticket.reason}")

        threading.Thread(target=watch, daemon=True, name="goto-watch").start()

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
        future = self._worker.submit(self._capture_and_encode, snap, settings)
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

    def _capture_and_encode(self, snap, settings: ImageSettings) -> bytes:
        t0 = time.perf_counter()
        image = np.asarray(self.grab(snap))
        height, width = image.shape[:2]
        roi = clip_roi(settings.roi, width, height)
        shift = settings.shift if roi is not None else 0
        mono = True if image.ndim == 2 else settings.mono
        try:
            stream = self._encode(image, settings.budget_bytes, roi=roi, shift=shift, mono=mono)
        except ValueError as exc:
            self._note(f"DEBT refused {settings}: {exc}; sending without ROI")
            stream = self._encode(image, settings.budget_bytes, mono=mono)
        elapsed = time.perf_counter() - t0
        self.stats.images_encoded += 1
        self.stats.last_encode_s = elapsed
        self.stats.worst_encode_s = max(self.stats.worst_encode_s, elapsed)
        return stream
