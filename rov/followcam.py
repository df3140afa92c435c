"""The camera at its own rate for FOLLOW (docs/PROTOCOL.md §10, and §9.3's THUMB over
the acoustic profile): the frames a tracker needs between the pictures the link carries.

Goals
- The ROV tracks the pilot's ROI in every camera frame, not only in the pictures
  it sends: a radio picture comes every few seconds, an acoustic thumbnail every
  minute, and a tracker fed that seldom loses anything that moves.
- A ROI drawn on a picture seconds (radio) or minutes (acoustic) old still finds its
  object: the tracker starts on the frame that picture was coded from and catches up
  through the frames kept since.
- One implementation for both profiles' nodes (rov/node.py, rov/acoustic.py).

Plan
- A daemon thread grabs a frame `camera_hz` times a second, keeps the last
  `history_s` of them (optionally shrunk first: the acoustic node keeps 320x240
  grey, so three minutes at 5 frames a second take 69 MB) and feeds each to the
  follower.
- `mark(key, at)` remembers which frame a picture was coded from (the radio's IMG,
  the acoustic THUMB's OID); `follow(...)` starts the tracker there.
- One lock over the frames and the follower: the camera thread, the encoder's
  worker and the link's loop all touch them.
"""

from __future__ import annotations

import collections
import threading
import time
from typing import Callable

import numpy as np

from .follow import Box, RoiFollower

PICTURES_MARKED = 64  # pictures whose frame time is remembered (a FOLLOW names one of the last)


class FollowCamera:
    def __init__(self, follower: RoiFollower, grab: Callable[[], np.ndarray], note: Callable[[str], None], *,
                 camera_hz: float = 10.0, history_s: float = 15.0,
                 shrink: Callable[[np.ndarray], np.ndarray] | None = None) -> None:
        self.follower = follower
        self.camera_hz = camera_hz
        self._grab = grab
        self._note = note
        self._shrink = shrink
        self._frames: collections.deque[tuple[float, np.ndarray]] = collections.deque(
            maxlen=max(int(history_s * camera_hz), 1))  # (captured at, frame), oldest first
        self._picture_at: collections.OrderedDict = collections.OrderedDict()  # picture key -> frame time
        self._origin: tuple | None = None  # (key, roi) the track in force started from
        self._lock = threading.Lock()
        self._stop = threading.Event()

    # -- the camera thread -----------------------------------------------------

    def start(self) -> None:
        threading.Thread(target=self._loop, name="follow-camera", daemon=True).start()

    def close(self) -> None:
        self._stop.set()

    def _loop(self) -> None:
        period = 1.0 / self.camera_hz
        while not self._stop.is_set():
            started = time.monotonic()
            try:
                frame = np.asarray(self._grab())
            except Exception as exc:  # a camera that fails now may deliver later: said, not fatal
                self._note(f"camera frame not captured: {exc}")
                self._stop.wait(1.0)
                continue
            self.take_frame(frame, time.monotonic())
            self._stop.wait(max(period - (time.monotonic() - started), 0.0))

    def take_frame(self, frame: np.ndarray, at: float) -> None:
        """One camera frame: kept, and followed when a FOLLOW stands."""
        if self._shrink is not None:
            frame = self._shrink(frame)
        with self._lock:
            self._frames.append((at, frame))
            self.follower.frame(frame, at)

    # -- read-outs -------------------------------------------------------------

    @property
    def last_frame_at(self) -> float | None:
        """When the newest camera frame kept was captured (monotonic), None before the first."""
        with self._lock:
            return self._frames[-1][0] if self._frames else None

    def newest(self) -> tuple[np.ndarray | None, float | None]:
        with self._lock:
            return (self._frames[-1][1], self._frames[-1][0]) if self._frames else (None, None)

    def mark(self, key, at: float) -> None:
        """The picture `key` was coded from the frame captured at `at`: a FOLLOW may start there."""
        with self._lock:
            self._picture_at[key] = at
            self._picture_at.move_to_end(key)
            while len(self._picture_at) > PICTURES_MARKED:
                self._picture_at.popitem(last=False)

    # -- following -------------------------------------------------------------

    def follow(self, roi: Box, keep: bool, drawn_on, *, resume: bool = False) -> None:
        """Start following `roi` (in the kept frames' pixels) from the frame picture
        `drawn_on` was coded from, catching up through the frames since.  With `resume`,
        the same ROI drawn on the same picture as the track in force goes on with that
        track (only KEEP changes): the acoustic operator names it again with every
        thumbnail it asks for."""
        with self._lock:
            if resume and self.follower.active and self._origin == (drawn_on, tuple(roi)):
                self.follower.keep = keep
                return
            drawn_at = self._picture_at.get(drawn_on)
            frames = list(self._frames)
            start = next((i for i, (at, _) in enumerate(frames) if at == drawn_at), None)
            if start is None:
                if not frames:
                    self._note("FOLLOW: no camera frame yet; the ROI stays where it was drawn")
                    return
                start = len(frames) - 1
                self._note(f"FOLLOW: picture {drawn_on} is no longer kept; following from the newest frame")
            at, frame = frames[start]
            height, width = frame.shape[:2]
            x0, y0 = max(0, int(roi[0])), max(0, int(roi[1]))
            x1, y1 = min(width, int(roi[2])), min(height, int(roi[3]))
            if x1 <= x0 or y1 <= y0:
                self._note("FOLLOW: the ROI lies outside the picture")
                return
            self.follower.start(frame, (x0, y0, x1, y1), keep, at)
            self._origin = (drawn_on, tuple(roi))
            for at, frame in frames[start + 1:]:  # catch up with the frames since
                self.follower.frame(frame, at)
            self._note(f"FOLLOW from picture {drawn_on}: {len(frames) - 1 - start} frames caught up")

    def stop_following(self) -> None:
        with self._lock:
            self.follower.stop()
            self._origin = None

    def followed(self) -> tuple[np.ndarray, float, Box | None, bytes] | None:
        """The newest frame, the ROI it is coded with and its TRACK record, under FOLLOW."""
        with self._lock:
            if not self._frames or not self.follower.active:
                return None
            at, frame = self._frames[-1]
            roi, record = self.follower.picture(at)
            return frame, at, roi, record.encode()
