"""The ROV program on the acoustic link (docs/PROTOCOL.md §9): supervisory orders,
status and thumbnails over a Water Linked Modem-M64.

Goals: every order the operator gives runs once and its fate goes back; the
modem always has the next thing worth sending and never more than one packet
queued, so a STOP or a status is never stuck behind a queue; the vehicle holds
position (or surfaces, if so configured) when the operator falls silent for
the failsafe time (60 s by default: a packet a second, seconds of latency).

Plan: one asyncio loop.  Packets from the modem go to the sans-I/O
`AcousticRov`; its events become bridge calls (the same `AutopilotBridge` the
radio node uses: brake, modes, arming, go-to tickets); a 10 Hz task copies the
bridge's snapshot into the machine's status, reports go-to tickets (accepted,
arrived, failed) and, whenever the modem's transmit queue is empty, hands it
the machine's next packet.  Thumbnails are captured, shrunk to 80x60 grey and
DEBT-encoded in a worker thread.

Decisions:
- "Queue empty" is the modem's own count when the endpoint can say it
  (`queue_length()`, the real modem and the emulator on a pty); any other
  endpoint gets at most one packet a second (the modem's rate).
- HOLD asks POS_HOLD with a position estimate, else DEPTH_HOLD; the failsafe's
  hold does the same; its "surface" asks SURFACE.
- HOLD and MODE are done when the autopilot takes the mode (nothing of them runs
  after); SURFACE runs while the vehicle rises and is done at the surface, so that
  a STOP or the failsafe on the way shows it aborted (§9.4).
- FOLLOW (a THUMB with its FOLLOW bit, §9.3 and §10) with a `follower`: the camera
  runs at `camera_hz` (rov/followcam.py, as on the radio node), its frames kept at
  320x240 grey (four times the thumbnail: at 160x120 the tracker held the bench's
  ladder in a quarter of the frames, at 320x240 in 99 %) for `history_s` (three
  minutes: a thumbnail takes about one, and the pilot draws on it after; 69 MB at the
  acoustic ROV's 5 frames a second), the tracker fed every frame.  The thumbnail asked for is
  the newest frame, coded with the ROI where the object is now, led by the TRACK
  record.  A THUMB naming the same ROI on the same thumbnail goes on with the track
  in force; one without FOLLOW ends it.  Without a follower the machine answers
  FOLLOW "impossible now".
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import math
import time

import numpy as np

from rovlink.link import acoustic as ac
from rovlink.link.acoustic.pump import AcousticPump
from rovlink.link.radio.messages import Mode
from rovlink.link.transports.transport import Endpoint

from .followcam import FollowCamera

log = logging.getLogger("rovlink.rov.acoustic")

THUMB_SIZE = (80, 60)  # width, height
FOLLOW_SIZE = (320, 240)  # the camera frames a FOLLOW tracks in: grey, four times the thumbnail
FOLLOW_HISTORY_S = 180.0  # a ROI drawn on a thumbnail this old still finds its object
CAMERA_HZ = 5.0  # frames a second the tracker follows (the radio ROV's 10: half the memory, as well held)
SURFACE_DONE_M = 0.3  # §9.4: a SURFACE order is done when the vehicle is this shallow


def thumbnail(image: np.ndarray, size: tuple[int, int] = THUMB_SIZE) -> np.ndarray:
    """A grey thumbnail of `size` (w, h): the mean of each block of the picture."""
    image = np.asarray(image)
    grey = image.astype(np.float32).mean(axis=2) if image.ndim == 3 else image.astype(np.float32)
    w, h = size
    rows = np.linspace(0, grey.shape[0], h + 1).astype(int)
    cols = np.linspace(0, grey.shape[1], w + 1).astype(int)
    out = np.add.reduceat(np.add.reduceat(grey, rows[:-1], axis=0), cols[:-1], axis=1)
    out /= np.outer(np.diff(rows), np.diff(cols))
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def follow_frame(frame: np.ndarray) -> np.ndarray:
    """A camera frame as the acoustic ROV keeps it for FOLLOW: grey, FOLLOW_SIZE."""
    frame = np.asarray(frame)
    if frame.shape[1::-1] == FOLLOW_SIZE:
        return frame if frame.ndim == 2 else frame.mean(axis=2).astype(np.uint8)
    return thumbnail(frame, FOLLOW_SIZE)


def _scaled(roi, factor: float) -> tuple[int, int, int, int] | None:
    """An ROI in another size of the same picture, rounded outwards (so it still covers what it framed)."""
    if roi is None:
        return None
    x0, y0, x1, y1 = roi
    return (int(math.floor(x0 * factor)), int(math.floor(y0 * factor)),
            int(math.ceil(x1 * factor)), int(math.ceil(y1 * factor)))


class AcousticNode:
    def __init__(self, endpoint: Endpoint, bridge, grab, key: bytes, *, failsafe_s: float = 60.0,
                 failsafe_action: str = "hold", encode=None, pace_s: float = 1.0, follower=None,
                 camera_hz: float = CAMERA_HZ, history_s: float = FOLLOW_HISTORY_S, objects=None) -> None:
        self.endpoint = endpoint
        # rov/objects.py's geometry: objects recognised in a thread of their own, told in SCENE frames.
        self._objects_geometry = objects
        self.objects = None
        self.bridge = bridge
        self.grab = grab
        self.pace_s = pace_s
        if encode is None:
            from rovlink import debt

            encode = debt.encode
        self._encode = encode
        if failsafe_action not in ("hold", "surface"):
            raise ValueError("the failsafe action is hold or surface")
        self.machine = ac.AcousticRov(key, failsafe_s=int(round(failsafe_s)),
                                      failsafe_action=ac.FAILSAFE_SURFACE if failsafe_action == "surface"
                                      else ac.FAILSAFE_HOLD)
        self._worker = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="thumbnail")
        # FOLLOW (§9.3's THUMB, §10): the camera at its own rate, the tracker in every frame.
        self.machine.follows = follower is not None
        self.camera = None if follower is None else FollowCamera(
            follower, lambda: self.grab(self.bridge.snapshot()), self._note, camera_hz=camera_hz,
            history_s=history_s, shrink=follow_frame)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._goto: tuple[int, object] | None = None  # (oid, ticket) being flown
        self._tickets: dict[int, object] = {}  # oid -> ticket of an arm/mode/hold/surface request
        self._surfacing: int | None = None  # a SURFACE order the autopilot took, the vehicle still rising
        self._surface_orders: set[int] = set()  # SURFACE orders whose mode change is awaited
        self.log: list[str] = []

    async def run(self) -> None:
        self._loop = asyncio.get_running_loop()
        # The one pump every acoustic end runs (link/acoustic/pump.py): packets split and
        # handed to the machine, a packet whenever the modem's queue is empty, flushed first
        # for a SYNC.  All on this loop's thread: the machine needs no lock of its own.
        pump = AcousticPump(self.machine, self.endpoint, clock=time.monotonic, pace_s=self.pace_s,
                            on_received=lambda packet, events, now: self._on_events(events, now),
                            on_events=self._on_events, before_tick=lambda now: self._before_tick())
        if self.camera is not None:
            self.camera.start()
        self._start_objects(self.machine.scene)
        try:
            await pump.run()
        finally:
            if self.camera is not None:
                self.camera.close()
            if self.objects is not None:
                self.objects.stop()
            self._worker.shutdown(wait=False, cancel_futures=True)

    def _before_tick(self) -> None:
        self._refresh_status()
        self._check_tickets()

    # -- the vehicle -----------------------------------------------------------

    def _refresh_status(self) -> None:
        s = self.bridge.snapshot()
        self.machine.update_status(ac.VehicleState(
            x_m=s.x_m, y_m=s.y_m, z_m=s.z_m, heading_deg=math.degrees(s.yaw_rad) % 360.0,
            armed=s.armed, mode=s.mode, autopilot=s.autopilot_alive, position_valid=s.position_valid,
            attitude_valid=s.attitude_valid, battery_v=s.battery_v or 0.0,
            going=self._goto is not None))
        self.machine.scene.altitude_m = s.altitude_m  # told in SCENE frames (docs/PROTOCOL.md §11.2)

    def _check_tickets(self) -> None:
        if self._goto is not None:
            oid, ticket = self._goto
            if ticket.status == "failed":
                self._goto = None
                self.machine.order_outcome(oid, ac.R_REFUSED if ticket.reject_reason == 2 else ac.R_IMPOSSIBLE)
                self._note(f"go-to {oid} failed: {ticket.reason}")
            elif ticket.status == "cancelled":
                self._goto = None
                self.machine.order_outcome(oid, ac.R_ABORTED)
                self._note(f"go-to {oid} cancelled: {ticket.reason}")
            elif getattr(ticket, "reached", False):
                self._goto = None
                self.machine.order_outcome(oid, ac.R_DONE)
                self._note(f"go-to {oid} arrived")
        if self._surfacing is not None and self.bridge.snapshot().z_m <= SURFACE_DONE_M:
            self.machine.order_outcome(self._surfacing, ac.R_DONE)
            self._note(f"order {self._surfacing}: at the surface")
            self._surfacing = None
        for oid, ticket in list(self._tickets.items()):
            if ticket.done:
                del self._tickets[oid]
                if ticket.status == "accepted" and oid in self._surface_orders:
                    self._surface_orders.discard(oid)
                    self._surfacing = oid  # taken: running until the vehicle is at the surface
                elif ticket.status == "accepted":
                    self.machine.order_outcome(oid, ac.R_DONE)
                else:
                    self.machine.order_outcome(oid, ac.R_REFUSED)
                    self._note(f"order {oid} refused: {ticket.reason}")

    def _hold_mode(self) -> int:
        return int(Mode.POS_HOLD if self.bridge.snapshot().position_valid else Mode.DEPTH_HOLD)

    def _on_events(self, events: list, now: float) -> None:
        for event in events:
            if isinstance(event, (ac.StopWanted, ac.HoldWanted, ac.SurfaceWanted, ac.ModeWanted, ac.GoToWanted, ac.FailsafeStarted)):
                self._surfacing = None  # the vehicle does something else now: a SURFACE under way ends
                self._surface_orders.clear()
            if isinstance(event, ac.StopWanted):
                self._goto = None
                self.bridge.brake()
                if event.new:
                    self._note("STOP: brake" if event.stop_no is not None else "brake at start")
            elif isinstance(event, ac.HoldWanted):
                self._goto = None
                self._tickets[event.oid] = self.bridge.request_mode(self._hold_mode())
                self._note(f"order {event.oid}: hold")
            elif isinstance(event, ac.SurfaceWanted):
                self._goto = None
                self._tickets[event.oid] = self.bridge.request_mode(int(Mode.SURFACE))
                self._surface_orders.add(event.oid)
                self._note(f"order {event.oid}: surface")
            elif isinstance(event, (ac.ArmWanted, ac.DisarmWanted)):
                self._tickets[event.oid] = self.bridge.request_arm(isinstance(event, ac.ArmWanted))
                self._note(f"order {event.oid}: {'arm' if isinstance(event, ac.ArmWanted) else 'disarm'}")
            elif isinstance(event, ac.ModeWanted):
                self._goto = None
                self._tickets[event.oid] = self.bridge.request_mode(int(event.mode))
                self._note(f"order {event.oid}: mode {event.mode}")
            elif isinstance(event, ac.GoToWanted):
                t = event.target
                self._goto = (event.oid, self.bridge.goto(
                    t.x_dm / 10.0, t.y_dm / 10.0, t.z_dm / 10.0,
                    math.radians(t.yaw_cdeg / 100.0) if t.yaw_set else None,
                    relative=t.relative, body=t.body_frame))
                self._note(f"go-to {event.oid}: ({t.x_dm / 10:.1f}, {t.y_dm / 10:.1f}, {t.z_dm / 10:.1f}) m"
                           f"{' relative' if t.relative else ''}")
                self._check_tickets()  # refused at once (impossible now): say so in the next status
            elif isinstance(event, ac.ThumbnailWanted):
                self._thumbnail(event.oid, event.settings)
            elif isinstance(event, ac.FailsafeStarted):
                self._goto = None
                surface = event.action == ac.FAILSAFE_SURFACE
                self._note(f"FAILSAFE: nothing from the operator for {self.machine.failsafe_s} s: "
                           f"{'surface' if surface else 'hold position'}")
                self.bridge.failsafe(True)
                if surface:
                    self.bridge.request_mode(int(Mode.SURFACE))
            elif isinstance(event, ac.FailsafeEnded):
                self._note("failsafe cleared: the operator is heard again")
                self.bridge.failsafe(False)

    # -- thumbnails ------------------------------------------------------------

    def _thumbnail(self, oid: int, order) -> None:
        snap = self.bridge.snapshot()
        loop = self._loop

        def work() -> bytes:
            return self.thumbnail_object(oid, order, snap)

        def done(f: concurrent.futures.Future) -> None:
            if f.cancelled() or loop is None or loop.is_closed():
                return
            if f.exception() is not None:
                self._note(f"thumbnail {oid} not encoded: {f.exception()}")
                return
            try:
                loop.call_soon_threadsafe(self.machine.thumbnail_ready, oid, f.result())
            except RuntimeError:
                pass

        self._worker.submit(work).add_done_callback(done)

    def thumbnail_object(self, oid: int, order, snap) -> bytes:
        """The thumbnail object THUMB `oid` asks for, `[N:2]` and its stream (led by the
        TRACK record under FOLLOW), from the newest camera frame (or one grabbed now)."""
        record, budget, roi = b"", order.budget, order.clipped_roi()  # BUDGET: bytes of DEBT stream
        frame, at = self.camera.newest() if self.camera is not None else (None, None)
        if self.camera is not None:
            if order.follow:  # started (or gone on with) before the picture is taken
                self.camera.follow(_scaled(roi, FOLLOW_SIZE[0] / THUMB_SIZE[0]), order.keep, order.drawn_on,
                                   resume=True)
            else:
                self.camera.stop_following()
            followed = self.camera.followed() if order.follow else None
            if followed is not None:
                frame, at, tracked, record = followed
                roi = _scaled(tracked, THUMB_SIZE[0] / FOLLOW_SIZE[0]) if tracked else None
                budget = max(budget - len(record), 1)  # BUDGET counts the TRACK record (§10)
        if frame is None:
            frame, at = self.grab(snap), time.monotonic()
        if self.camera is not None:
            self.camera.mark(oid, at)  # a FOLLOW drawn on this thumbnail starts on its frame
        small = thumbnail(frame)
        try:
            stream = self._encode(small, budget, roi=roi, shift=order.shift if roi else 0, mono=True)
        except ValueError:
            stream = self._encode(small, budget, mono=True)
        stream = (record + bytes(stream))[:ac.MAX_OBJECT - 2]
        return len(stream).to_bytes(2, "big") + stream

    def _note(self, text: str) -> None:
        log.info("%s", text)
        self.log.append(text)
        del self.log[:-200]

    def _start_objects(self, outbox) -> None:
        from rovlink.rov.objects import watch_node_camera

        self.objects = watch_node_camera(self.bridge, self.grab, outbox, self._objects_geometry)
