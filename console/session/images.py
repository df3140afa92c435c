"""The picture being received, decoded as it refines, and the pictures before it.

Goals: the pilot sees every prefix of a DEBT stream as soon as it can be
decoded, newest first (an older prefix still waiting is skipped), without the
decode ever holding up the link; each picture says when and where the ROV
captured it; the last IMAGE_HISTORY pictures stay to look back at.

When and where was a picture captured?  Decision: the console stamps it from
the replies; the protocol carries no capture time (bytes are dear, and its
image object is fixed by docs/PROTOCOL.md §4).  The ROV (rov/node.py) captures the
next image as the last trunk of the previous one goes out, in the reply that
carries it (prefetch), or, when that capture was thrown away (settings
changed, too old, an image abandoned, the first image), when a poll asks for
the new IMG.  Either way the capture lies between the reply that ended the
previous image (or was the last before it was abandoned) and the reply that
brings the new one's first trunk.  So a picture is stamped with that interval,
"not_before" to "not_after", and with the odometry of the "not_before" reply
(the prefetch's pose: the ROV sampled both while answering that poll).  The
lower bound is the first poll that could carry the previous picture's last
trunk (OFFSET + the largest trunk its SIZE allows reaches the object's end):
a sure bound whatever is lost and sent again, and whatever the load on either
end.  Without an earlier reply to bound it ("not_before" None) it may be of
any age (§4).
"""

from __future__ import annotations

import collections
import concurrent.futures
import logging
import queue
import threading
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from rovlink import debt
from rovlink.link.pictures import PILOT_SKIPPED, ImageAbandoned, ImageComplete, ImageProgress
from rovlink.link.vocabulary import PictureRequest

from .follow import coded_settings, read_picture
from .odometry import Fix, Pose

IMAGE_HISTORY = 24        # pictures kept to look back at (320x240x3 is 230 kB each)

log = logging.getLogger("rovlink.console.images")


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
    settings: PictureRequest | None = None
    images_completed: int = 0
    serial: int = 0                   # counts images, never wraps (IMG wraps at 8)
    capture: dict | None = None       # when and where the ROV captured it (ImageReceiver._capture_stamp)
    track: dict | None = None         # a followed picture's track (session/follow.py), else None
    coded_roi: tuple | None = None    # a followed picture's ROI, from its DEBT header


def settings_dict(s: PictureRequest | None) -> dict | None:
    return None if s is None else {"roi": list(s.roi) if s.roi else None, "shift": s.shift, "mono": s.mono,
                                   "budget_bytes": s.budget_bytes}


class DaemonWorker:
    """One daemon thread running submitted calls in order (a ThreadPoolExecutor's
    submit/shutdown).  Daemon: a console that stops never waits for a decode,
    even one held up by DEBT's first (cold) compilation; a ThreadPoolExecutor's
    worker is joined at exit."""

    def __init__(self, name: str) -> None:
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

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

    def wait_idle(self, timeout: float) -> bool:
        """Wait until every call submitted so far has run (True), or `timeout`
        seconds (False).  A worker shut down is idle once its thread ended."""
        if self._closed:
            self._thread.join(timeout)
            return not self._thread.is_alive()
        try:
            self.submit(lambda: None).result(timeout)
        except concurrent.futures.TimeoutError:
            return False
        except (concurrent.futures.CancelledError, RuntimeError):  # shut down meanwhile
            self._thread.join(timeout)
            return not self._thread.is_alive()
        return True

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


class ImageReceiver:
    """Image events in, pictures out ("image_progress" and "image" published).

    `lock`: the session's (re-entrant) lock, held around every change;
    `now`/`wall`: session time and its clock time; `fix`: the last reply's fix;
    `record`, `publish`, `note`: the session's recorder, subscribers and log.
    The decode thread is handed in, so that a replay's new receiver keeps it."""

    def __init__(self, *, lock, now: Callable[[], float], wall: Callable[[float], float],
                 fix: Callable[[], Fix | None], record: Callable[[dict], None],
                 publish: Callable[[str, Any], None], note: Callable[..., None], decoder: DaemonWorker,
                 settings: PictureRequest | None) -> None:
        self._lock, self._now, self._wall, self._fix = lock, now, wall, fix
        self._record, self._publish, self._note = record, publish, note
        self._decoder = decoder
        self.view = ImageView(settings=settings)
        # What the ROV is known to use (applies from the next picture on).
        self.confirmed_settings = settings
        self._history: collections.deque = collections.deque(maxlen=IMAGE_HISTORY)
        self._kept = 0  # pictures ever kept (the page refetches its strip when it moves)
        # The image requests as they went out: (sent at, IMG, OFFSET, largest trunk its SIZE allows).
        self._requests: collections.deque = collections.deque(maxlen=256)
        self._next_capture: tuple[float, Pose | None, str] | None = None
        self._pending: tuple[int, bytes] | None = None
        self._busy = False
        self._undecodable_serial: int | None = None   # the picture last said undecodable
        self.skipped: dict | None = None   # the pilot's last Next image: what it skipped (the page's fate)

    # -- what went out and came in ----------------------------------------

    def request_sent(self, t: float, img: int, offset: int, trunk_cap: int) -> None:
        self._requests.append((t, img, offset, trunk_cap))

    def on_event(self, event, t: float) -> None:
        if isinstance(event, ImageProgress):
            self._progress(event, t)
        elif isinstance(event, ImageComplete):
            self._complete(event, t)
        elif isinstance(event, ImageAbandoned):
            self._abandoned(event, t)

    def _progress(self, event: ImageProgress, t: float) -> None:
        with self._lock:
            view = self.view
            if view.img != event.img or event.received_bytes < view.received_bytes:
                view.img = event.img
                view.started_at = t
                view.picture = None
                view.decoded_bytes = 0
                view.complete = False
                view.settings = self.confirmed_settings
                view.serial += 1
                view.capture = self._capture_stamp(t)
            view.received_bytes = event.received_bytes
            view.total_bytes = event.total_bytes
            view.track, view.coded_roi, view.stream = read_picture(event.track, event.stream)
            stream = view.stream
        self._publish("image_progress", self.state())
        self._decode_later(event.img, stream)

    def _complete(self, event: ImageComplete, t: float) -> None:
        with self._lock:
            self.view.complete = True
            self.view.images_completed += 1
            self.view.track, self.view.coded_roi, self.view.stream = read_picture(event.track, event.stream)
            self._keep(t, partial=False)
            self._mark_capture_window(t, "prefetch", img=event.img, total=2 + len(event.data),
                                      since=event.started_at)
            serial = self.view.serial
        self._record({"k": "image", "t": round(t, 4), "img": event.img, "n": serial, "bytes": len(event.data),
                      "seconds": round(event.at - event.started_at, 3)})
        # The picture's own number (the page's card, strip and saved file say it too); IMG wraps at 8.
        self._note(f"picture #{serial} complete: {len(event.data)} bytes in {event.at - event.started_at:.1f} s "
                   f"(IMG {event.img})")

    def _abandoned(self, event: ImageAbandoned, t: float) -> None:
        with self._lock:
            shown = self.view.img == event.img and not self.view.complete and self.view.stream
            if shown:
                self._keep(t, partial=True, skipped=event.reason == PILOT_SKIPPED)
            self._mark_capture_window(t, "request")
            what = f"picture #{self.view.serial}" if shown else f"a picture not yet shown (IMG {event.img})"
            if event.reason == PILOT_SKIPPED:
                self._skipped(t, self.view.serial if shown else None, event.received_bytes,
                              self.view.total_bytes if shown else None)
        if event.reason != PILOT_SKIPPED:
            self._note(f"{what} abandoned after {event.received_bytes} bytes: {event.reason}")
        elif event.received_bytes:
            of = f" of {self.view.total_bytes - 2}" if shown and self.view.total_bytes else ""
            self._note(f"{what} skipped by the pilot at {event.received_bytes}{of} B: the next one is coming")
        else:
            self._note("the pilot skipped a picture before its first bytes came: the next one is coming")

    def _skipped(self, t: float, serial: int | None, received_bytes: int, total_bytes: int | None) -> None:
        self.skipped = {"n": serial, "received_bytes": received_bytes, "total_bytes": total_bytes,
                        "wall": round(self._wall(t), 3)}

    def nothing_to_skip(self, t: float) -> None:
        """Next image with no byte of a picture in yet: the next one is asked for all the same."""
        with self._lock:
            self._skipped(t, None, 0, None)
        self._publish("image_progress", self.state())

    # -- the capture window (see the module's docstring) ------------------

    def captured_after(self, t: float, pose: Pose | None) -> None:
        """The next picture was captured at `t` or later, where `pose` was (a
        thumbnail the ROV takes when it takes the request: the acoustic profile)."""
        with self._lock:
            self._next_capture = (t, pose, "request")

    def _mark_capture_window(self, t: float, why: str, *, img: int | None = None, total: int | None = None,
                             since: float | None = None) -> None:
        fix = self._fix()
        report = None if fix is None else fix.report
        pose = Pose.from_report(report) if report is not None and report.position_valid else None
        sent = None if fix is None else fix.poll_sent_at
        if img is not None and total is not None:
            # This image's polls only (IMG wraps at 8): those sent since its first request.
            ends = [at for at, i, offset, cap in list(self._requests)
                    if i == img and offset + cap >= total and (since is None or at >= since) and at <= t]
            if ends:
                sent = min(ends) if sent is None else min(min(ends), sent)
        self._next_capture = (sent if sent is not None and sent <= t else t, pose, why)

    def _capture_stamp(self, t_first: float) -> dict:
        mark, self._next_capture = self._next_capture, None
        if mark is None:
            # Without a bound below, the first trunk's reply is all there is.
            fix = self._fix()
            pose, not_before, why = (None if fix is None else fix.pose), None, "unknown"
        else:
            not_before, pose, why = mark
        t_est = not_before if not_before is not None else t_first
        return {"t": round(t_est, 3), "wall": round(self._wall(t_est), 3),
                "not_before_wall": None if not_before is None else round(self._wall(not_before), 3),
                "not_after_wall": round(self._wall(t_first), 3), "how": why,
                "pose": None if pose is None else {k: round(v, 3) for k, v in pose.as_dict().items()}}

    # -- pictures to look back at -----------------------------------------

    def _keep(self, t: float, *, partial: bool, skipped: bool = False) -> None:
        v = self.view
        self._kept += 1
        self._history.append({
            "n": v.serial, "img": v.img, "capture": v.capture, "bytes": len(v.stream),
            "total_bytes": v.total_bytes, "partial": partial, "skipped": skipped,
            "received_wall": round(self._wall(t), 3),
            "seconds": None if v.started_at is None else round(t - v.started_at, 2),
            "settings": coded_settings(settings_dict(v.settings), v.track, v.coded_roi),
            "track": v.track,
            "stream": bytes(v.stream),
        })

    def history(self) -> list[dict]:
        """Completed (and abandoned, `partial`) pictures, oldest first, with their
        metadata and DEBT stream ("stream": decode it for the picture)."""
        with self._lock:
            return [dict(e) for e in self._history]

    # -- decoding ---------------------------------------------------------

    def _decode_later(self, img: int, prefix: bytes) -> None:
        with self._lock:
            self._pending = (img, prefix)
            if self._busy:
                return
            self._busy = True
        try:
            self._decoder.submit(self._decode_loop)
        except RuntimeError:  # shut down
            with self._lock:
                self._busy = False

    def _decode_loop(self) -> None:
        while True:
            with self._lock:
                job, self._pending = self._pending, None
                if job is None:
                    self._busy = False
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
                    serial = self.view.serial if self.view.img == img else None
                    first = serial is not None and serial != self._undecodable_serial
                    if first:
                        self._undecodable_serial = serial
                if first:
                    self._note(f"picture {serial} cannot be decoded: {exc}", "alert")
                continue
            with self._lock:
                if self.view.img != img or len(prefix) < self.view.decoded_bytes:
                    continue
                self.view.picture = picture
                self.view.decoded_bytes = len(prefix)
                self.view.decoded_at = self._now()
            self._publish("image", self.state())

    # -- state ------------------------------------------------------------

    def state(self) -> dict:
        with self._lock:
            v = self.view
            return {
                "img": v.img, "received_bytes": v.received_bytes, "total_bytes": v.total_bytes,
                "complete": v.complete, "decoded_bytes": v.decoded_bytes, "started_at": v.started_at,
                "decoded_at": v.decoded_at, "images_completed": v.images_completed, "serial": v.serial,
                "kept": self._kept,
                "capture": v.capture, "settings": coded_settings(settings_dict(v.settings), v.track, v.coded_roi),
                "track": v.track, "skipped": self.skipped,
            }
