"""The region of interest that follows its object (docs/PROTOCOL.md §10, issue 34).

Goals
- After a FOLLOW order the ROV tracks what the pilot's ROI framed, in its own camera
  frames at the camera's rate, and codes each picture with the ROI where the object
  is now; every such picture says whether the track holds, was lost (and for how
  long) or was dropped.
- Cheap enough for a Raspberry Pi 4 class companion computer beside the encoder:
  `rovlink bench roi` measures the cost per frame.
- OpenCV (`cv2`) is an optional extra (`rovlink[tracking]`): without it the ROV
  refuses FOLLOW with its reason and `rovlink rov` says which extra is missing.

Plan
- `FeatureTracker` (the default, "klt"): corners inside the ROI followed by
  optical flow, one affine motion of the seabed's plane fitted to them, the ROI's
  corners moved with it (see the class).  `rovlink bench roi` measures it against
  the others: it holds the box best, at the lowest cost.
- `CorrelationTracker` ("ncc"): the object's template matched by
  normalised cross-correlation (cv2.matchTemplate) in a window around where its
  motion so far puts it, over a few scales and in-picture rotations (the vehicle
  comes closer, goes round it): each candidate warps the window into the
  template's own frame (cv2.warpAffine), so the template is never resampled.  The
  best peak is the track's confidence; below `LOST_SCORE`, or with less than half
  of the box left in the picture, the track is lost.  While lost it keeps looking
  around the last place, and takes the object back only on a clearly better peak.
  Its box is the bounds of the rotated rectangle.
- `OpenCVTracker`: OpenCV's own CSRT or KCF behind the same two calls, for the
  bench's comparison (they give no confidence, and CSRT costs 4-5 times the budget).
- `RoiFollower`: the one object the ROV node and the bench drive: `start` on the
  frame the ROI was drawn on, `frame` at the camera's rate, `picture` when a
  picture is coded: its ROI and its `TrackRecord`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from rovlink.link.radio.messages import TRACK_LOST_FOR_MAX_DS, TrackRecord, TrackState

TRACKING_EXTRA = "tracking"
TRACKERS = ("klt", "ncc", "csrt", "kcf")
DEFAULT_TRACKER = "klt"
DROP_AFTER_S = 20.0  # lost this long: the ROV stops looking (DROPPED)

Box = tuple[int, int, int, int]  # x0, y0, x1, y1 in pixels, x1 and y1 exclusive


class TrackerMissing(RuntimeError):
    """No tracker on this ROV: OpenCV is not installed."""


def load_cv2():
    try:
        import cv2
    except ImportError as exc:
        raise TrackerMissing(
            f"FOLLOW needs OpenCV's trackers: install rovlink with the '{TRACKING_EXTRA}' extra "
            f"(opencv-contrib-python-headless)"
        ) from exc
    return cv2


def make_tracker(name: str = DEFAULT_TRACKER):
    cv2 = load_cv2()
    if name == "ncc":
        return CorrelationTracker(cv2)
    if name == "klt":
        return FeatureTracker(cv2)
    if name in ("csrt", "kcf"):
        return OpenCVTracker(cv2, name)
    raise ValueError(f"unknown tracker {name!r}: one of {', '.join(TRACKERS)}")


def _grey(cv2, frame: np.ndarray) -> np.ndarray:
    if frame.ndim == 2:
        return frame.astype(np.float32)
    return cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2GRAY).astype(np.float32)


def visible_fraction(box, width: int, height: int) -> float:
    x0, y0, x1, y1 = box
    area = max(x1 - x0, 0) * max(y1 - y0, 0)
    if area <= 0:
        return 0.0
    inside = max(min(x1, width) - max(x0, 0), 0) * max(min(y1, height) - max(y0, 0), 0)
    return inside / area


class CorrelationTracker:
    """Template matching over scale and rotation, with its confidence (see the module's plan)."""

    LOST_SCORE = 0.45  # best normalised correlation below this: not found
    REGAIN_SCORE = 0.7  # while lost, a peak this good takes the object back
    LEARN_SCORE = 0.75  # the template learns only from confident matches
    LEARN_RATE = 0.08
    TEMPLATE_SIDE = 40  # the template's longer side, pixels of its own frame
    SEARCH_MARGIN = 20  # how far (template pixels) around the predicted centre it looks
    SCALES = (1 / 1.05, 1.0, 1.05)
    TURNS_RAD = (-0.06, 0.0, 0.06)

    def __init__(self, cv2) -> None:
        self.cv2 = cv2
        self.lost = False
        self.matched = 0.0

    def init(self, frame: np.ndarray, box: Box) -> None:
        x0, y0, x1, y1 = (float(v) for v in box)
        self.cx, self.cy = (x0 + x1) / 2, (y0 + y1) / 2
        self.w, self.h = max(x1 - x0, 4.0), max(y1 - y0, 4.0)
        # Template pixels per picture pixel at scale 1: small objects are matched as they are.
        self.k = min(1.0, self.TEMPLATE_SIDE / max(self.w, self.h))
        self.tw, self.th = max(int(round(self.w * self.k)), 4), max(int(round(self.h * self.k)), 4)
        self.scale, self.angle = 1.0, 0.0
        self.vx = self.vy = self.vs = self.va = 0.0
        grey = _grey(self.cv2, frame)
        self._fill = float(grey.mean())
        self.template = self._window(grey, self.cx, self.cy, self.scale, self.angle, 0)
        self.lost = False

    def _window(self, grey: np.ndarray, cx: float, cy: float, scale: float, angle: float, margin: int) -> np.ndarray:
        """The picture around (cx, cy) warped into the template's frame, `margin` template pixels wider each side."""
        w, h = self.tw + 2 * margin, self.th + 2 * margin
        step = 1.0 / (self.k / scale)  # picture pixels per template pixel
        c, s = math.cos(angle) * step, math.sin(angle) * step
        # Template (u, v) -> picture: centre + R(angle) * step * ((u, v) - half size).
        half_u, half_v = (w - 1) / 2, (h - 1) / 2
        affine = np.array([[c, -s, cx - c * half_u + s * half_v], [s, c, cy - s * half_u - c * half_v]], np.float32)
        return self.cv2.warpAffine(grey, affine, (w, h), flags=self.cv2.INTER_LINEAR | self.cv2.WARP_INVERSE_MAP,
                                   borderMode=self.cv2.BORDER_CONSTANT, borderValue=float(self._fill))

    def update(self, frame: np.ndarray) -> Box | None:
        """The object's box in this frame, or None when the track is lost."""
        grey = _grey(self.cv2, frame)
        self._fill = float(grey.mean())  # beyond the picture: flat, so it matches nothing
        px, py = self.cx + self.vx, self.cy + self.vy
        ps, pa = self.scale * (1 + self.vs), self.angle + self.va
        margin = self.SEARCH_MARGIN * (2 if self.lost else 1)
        best = (-2.0, 0.0, 0.0, ps, pa)
        for ds in self.SCALES:
            for da in self.TURNS_RAD:
                scale, angle = ps * ds, pa + da
                window = self._window(grey, px, py, scale, angle, margin)
                result = self.cv2.matchTemplate(window, self.template, self.cv2.TM_CCOEFF_NORMED)
                _, peak, _, (u, v) = self.cv2.minMaxLoc(result)
                # A hair in favour of the motion so far, so flat sand does not jitter the scale and angle.
                peak -= 0.01 * ((ds != 1.0) + (da != 0.0))
                if peak > best[0]:
                    best = (peak, u - margin, v - margin, scale, angle)
        peak, du, dv, scale, angle = best
        step = scale / self.k
        c, s = math.cos(angle), math.sin(angle)
        nx, ny = px + step * (c * du - s * dv), py + step * (s * du + c * dv)
        box = self._box(nx, ny, scale, angle)
        width, height = grey.shape[1], grey.shape[0]
        found = peak >= (self.REGAIN_SCORE if self.lost else self.LOST_SCORE)
        if not found or visible_fraction(box, width, height) < 0.5:
            self.lost = True
            self.vx = self.vy = self.vs = self.va = 0.0  # look where it was last seen
            return None
        self.vx, self.vy = 0.6 * (nx - self.cx), 0.6 * (ny - self.cy)
        self.vs, self.va = 0.5 * (scale / self.scale - 1), 0.5 * (angle - self.angle)
        self.cx, self.cy, self.scale, self.angle = nx, ny, scale, angle
        self.lost = False
        if peak >= self.LEARN_SCORE:
            fresh = self._window(grey, nx, ny, scale, angle, 0)
            self.template = (1 - self.LEARN_RATE) * self.template + self.LEARN_RATE * fresh
        return box

    def _box(self, cx: float, cy: float, scale: float, angle: float) -> Box:
        hw, hh = self.w * scale / 2, self.h * scale / 2
        c, s = abs(math.cos(angle)), abs(math.sin(angle))
        ex, ey = hw * c + hh * s, hw * s + hh * c
        return (int(round(cx - ex)), int(round(cy - ey)), int(round(cx + ex)), int(round(cy + ey)))


class FeatureTracker:
    """Corners inside the ROI followed by pyramidal Lucas-Kanade flow, one affine
    motion fitted to them (RANSAC) from the frame they were found in: the seabed is
    locally a plane, so the ROI's four corners move with it, and its box is their
    bounds.  Where too few corners agree (bare, hazy sand far off), the ROI's own
    patch is looked for around it instead (normalised correlation).  Lost when neither
    finds it, or less than half of the box is in the picture; while lost, the patch is
    looked for in a wider window, and a clear match takes the object back."""

    MIN_POINTS = 8
    MAX_POINTS = 60
    MATCH_SCORE = 0.8  # the patch's best correlation: found (also to take a lost object back)
    RETAKE_SCORE = 0.9  # a patch that matched less well than this is taken again where it was found
    UNIQUE_MARGIN = 0.1  # ... and that far above the best correlation half a patch away or more

    def __init__(self, cv2) -> None:
        self.cv2 = cv2
        self.lost = False
        self.matched = 0.0

    def init(self, frame: np.ndarray, box: Box) -> None:
        grey = self._grey8(frame)
        x0, y0, x1, y1 = (float(v) for v in box)
        self.corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], np.float32)
        self.template = None
        self.velocity = np.zeros(2, np.float32)  # the box's last move, pixels a frame: where to look first
        self._anchor(grey)
        self.lost = False

    def _anchor(self, grey: np.ndarray, template: bool = True) -> None:
        """New corners to follow, each motion measured from here: one fit from the anchor
        rather than one per frame, so small errors do not pile up frame after frame.  The
        patch is taken again only with `template`: a patch matched frame after frame and
        taken again each time loses every motion under half a pixel a frame (an object
        far off, moving slowly), so it is kept while it still matches well."""
        self.prev = grey
        self.anchor_corners = self.corners.copy()
        self.anchor_points = self._features(grey)
        self.points = self.anchor_points.copy()
        x0, y0, x1, y1 = self._box()
        if not template and self.template is not None:
            return
        if x0 >= 0 and y0 >= 0 and x1 <= grey.shape[1] and y1 <= grey.shape[0] and x1 - x0 >= 4 and y1 - y0 >= 4:
            self.template = grey[y0:y1, x0:x1].copy()  # a patch wholly in the picture, else the last one

    def _grey8(self, frame: np.ndarray) -> np.ndarray:
        if frame.ndim == 2:
            return np.ascontiguousarray(frame)
        return self.cv2.cvtColor(np.ascontiguousarray(frame), self.cv2.COLOR_RGB2GRAY)

    def _features(self, grey: np.ndarray):
        x0, y0, x1, y1 = self._box()
        mask = np.zeros(grey.shape, np.uint8)
        mask[max(y0, 0):max(y1, 0), max(x0, 0):max(x1, 0)] = 255
        points = self.cv2.goodFeaturesToTrack(grey, self.MAX_POINTS, 0.01, 3, mask=mask, blockSize=5)
        return points if points is not None else np.zeros((0, 1, 2), np.float32)

    def _box(self) -> Box:
        c = self.corners
        return (int(round(float(c[:, 0].min()))), int(round(float(c[:, 1].min()))),
                int(round(float(c[:, 0].max()))), int(round(float(c[:, 1].max()))))

    def _flow(self, grey: np.ndarray):
        """The affine motion from the anchor to this frame, or None when too few corners agree."""
        cv2 = self.cv2
        if len(self.points) < self.MIN_POINTS:
            return None
        guess = (self.points + self.velocity).astype(np.float32)
        after, status, _ = cv2.calcOpticalFlowPyrLK(self.prev, grey, self.points, guess, winSize=(15, 15), maxLevel=3,
                                                    flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        ok = status.ravel() == 1
        self.anchor_points, self.points = self.anchor_points[ok], after[ok]
        if ok.sum() < self.MIN_POINTS:
            return None
        affine, inliers = cv2.estimateAffine2D(self.anchor_points, self.points, method=cv2.RANSAC,
                                               ransacReprojThreshold=1.5)
        if affine is None or inliers.sum() < self.MIN_POINTS:
            return None
        keep = inliers.ravel() == 1  # a corner that went its own way is not followed further
        self.anchor_points, self.points = self.anchor_points[keep], self.points[keep]
        return affine

    def _match(self, grey: np.ndarray, reach: float) -> tuple[float, float] | None:
        """Where the ROI's patch moved (dx, dy), looked for `reach` patch sizes around it; None if not clearly found.
        `self.matched` is its correlation."""
        if self.template is None:
            return None
        th, tw = self.template.shape
        x0, y0, x1, y1 = self._box()
        cx, cy = (x0 + x1) / 2 + float(self.velocity[0]), (y0 + y1) / 2 + float(self.velocity[1])
        sx0, sy0 = int(max(cx - (0.5 + reach) * tw, 0)), int(max(cy - (0.5 + reach) * th, 0))
        sx1, sy1 = int(min(cx + (0.5 + reach) * tw, grey.shape[1])), int(min(cy + (0.5 + reach) * th, grey.shape[0]))
        if sx1 - sx0 <= tw or sy1 - sy0 <= th:
            return None
        result = self.cv2.matchTemplate(grey[sy0:sy1, sx0:sx1], self.template, self.cv2.TM_CCOEFF_NORMED)
        _, peak, _, (u, v) = self.cv2.minMaxLoc(result)
        if peak < self.MATCH_SCORE or not self._unique(result, peak, u, v, tw, th):
            return None
        self.matched = peak
        return sx0 + u + tw / 2 - (x0 + x1) / 2, sy0 + v + th / 2 - (y0 + y1) / 2

    def _unique(self, result: np.ndarray, peak: float, u: int, v: int, tw: int, th: int) -> bool:
        """The peak stands out: nothing at least half a patch away matches nearly as well.
        Bare sand matches itself everywhere, and a patch taken for the object there would
        "hold" a track whose object left the picture long ago."""
        others = result.copy()
        others[max(v - th // 2, 0):v + th // 2 + 1, max(u - tw // 2, 0):u + tw // 2 + 1] = -1.0
        return not others.size or float(others.max()) < peak - self.UNIQUE_MARGIN

    def update(self, frame: np.ndarray) -> Box | None:
        before = self.corners.mean(axis=0)
        box = self._update(frame)
        if box is not None:
            self.velocity = (self.corners.mean(axis=0) - before).astype(np.float32)
        else:
            self.velocity = np.zeros(2, np.float32)
        return box

    def _update(self, frame: np.ndarray) -> Box | None:
        grey = self._grey8(frame)
        height, width = grey.shape
        if self.lost:
            shift = self._match(grey, reach=1.5)
            self.prev = grey
            if shift is None:
                return None
            self.corners = self.corners + np.float32(shift)
            self._anchor(grey, template=self.matched < self.RETAKE_SCORE)
            self.lost = False
            self.velocity = np.zeros(2, np.float32)
            return self._box()
        moved = self._flow(grey)
        if moved is not None:
            self.corners = (self.anchor_corners @ moved[:, :2].T + moved[:, 2]).astype(np.float32)
            self.prev = grey
            if len(self.points) < self.MAX_POINTS // 2:
                self._anchor(grey)
        else:
            shift = self._match(grey, reach=1.0)
            if shift is not None:
                self.corners = self.corners + np.float32(shift)
                self._anchor(grey, template=self.matched < self.RETAKE_SCORE)
            else:
                self.prev = grey
        box = self._box()
        if (moved is None and shift is None) or visible_fraction(box, width, height) < 0.5:
            self.lost = True
            return None
        return box


class OpenCVTracker:
    """OpenCV's CSRT or KCF: lost when it says so, or when less than half its box is in the picture."""

    def __init__(self, cv2, name: str) -> None:
        self.cv2 = cv2
        self.name = name
        make = {"csrt": "TrackerCSRT_create", "kcf": "TrackerKCF_create"}[name]
        factory = getattr(cv2, make, None) or getattr(getattr(cv2, "legacy", None), make, None)
        if factory is None:
            raise TrackerMissing(f"this OpenCV has no {name.upper()} tracker: install the '{TRACKING_EXTRA}' extra "
                                 f"(opencv-contrib-python-headless)")
        self._factory = factory
        self.lost = False

    def init(self, frame: np.ndarray, box: Box) -> None:
        self._tracker = self._factory()
        x0, y0, x1, y1 = box
        self._tracker.init(self._bgr(frame), (int(x0), int(y0), int(x1 - x0), int(y1 - y0)))
        self.lost = False

    def _bgr(self, frame: np.ndarray) -> np.ndarray:
        return frame if frame.ndim == 2 else np.ascontiguousarray(frame[..., ::-1])

    def update(self, frame: np.ndarray) -> Box | None:
        ok, (x, y, w, h) = self._tracker.update(self._bgr(frame))
        box = (int(x), int(y), int(x + w), int(y + h))
        if not ok or w <= 0 or h <= 0 or visible_fraction(box, frame.shape[1], frame.shape[0]) < 0.5:
            self.lost = True
            return None
        self.lost = False
        return box


@dataclass
class FollowStats:
    frames: int = 0
    seconds: float = 0.0
    worst_s: float = 0.0

    @property
    def mean_ms(self) -> float:
        return 1000.0 * self.seconds / self.frames if self.frames else 0.0


class RoiFollower:
    """One followed ROI: started on a frame, fed every camera frame, asked at each picture."""

    def __init__(self, tracker: str = DEFAULT_TRACKER, *, drop_after_s: float = DROP_AFTER_S) -> None:
        self.tracker_name = tracker
        self._tracker = make_tracker(tracker)  # TrackerMissing now, not at the pilot's first FOLLOW
        self.drop_after_s = drop_after_s
        self.stats = FollowStats()
        self.active = False
        self.keep = True
        self.state = TrackState.DROPPED
        self.roi: Box | None = None  # where the object is (or was last seen, while lost)
        self.lost_since: float | None = None
        self.size = (0, 0)

    def start(self, frame: np.ndarray, roi: Box, keep: bool, now: float) -> None:
        self._tracker = make_tracker(self.tracker_name)
        self._tracker.init(frame, roi)
        self.size = frame.shape[1], frame.shape[0]
        self.active, self.keep = True, keep
        self.state, self.roi, self.lost_since = TrackState.HOLDS, tuple(int(v) for v in roi), None

    def stop(self) -> None:
        self.active = False

    def frame(self, frame: np.ndarray, now: float) -> None:
        """One camera frame: the tracker moves the ROI (or loses it, or gives up)."""
        if not self.active or self.state == TrackState.DROPPED:
            return
        t0 = time.perf_counter()
        box = self._tracker.update(frame)
        elapsed = time.perf_counter() - t0
        self.stats.frames += 1
        self.stats.seconds += elapsed
        self.stats.worst_s = max(self.stats.worst_s, elapsed)
        if box is not None:
            self.state, self.roi, self.lost_since = TrackState.HOLDS, box, None
            return
        if self.lost_since is None:
            self.lost_since = now
        self.state = TrackState.LOST
        if now - self.lost_since >= self.drop_after_s:
            self.state = TrackState.DROPPED

    def picture(self, now: float) -> tuple[Box | None, TrackRecord]:
        """The ROI a picture captured now is coded with, and its TRACK record."""
        lost_for = 0 if self.lost_since is None else now - self.lost_since
        record = TrackRecord(self.state, self.keep, min(int(lost_for * 10), TRACK_LOST_FOR_MAX_DS))
        if self.state == TrackState.HOLDS or self.keep:
            return self._clipped(self.roi), record
        return None, record

    def _clipped(self, roi: Box | None) -> Box | None:
        if roi is None:
            return None
        width, height = self.size
        x0, y0 = max(0, roi[0]), max(0, roi[1])
        x1, y1 = min(width, roi[2]), min(height, roi[3])
        return (x0, y0, x1, y1) if x1 > x0 and y1 > y0 else None
