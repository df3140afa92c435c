"""Objects lying on the seabed, recognised on the ROV in its camera frames, merged into one
map with stable ids, and told to the operator as §11 records (docs/PROTOCOL.md).

Goals
- Class (amphora, pipe, timber, ladder, unknown), centre north/east, length, width, heading
  of the long axis, confidence: measured on the seabed, not in the picture, so that a go-to
  can stop facing an object and the scene can draw it at its size.
- Off the reply path: detection runs in a thread of its own on the frames the camera thread
  keeps (rov/followcam.py), at DETECT_HZ; the link only reads the outbox.  A detector that
  fails is said once in the node's log and the map stops growing; the ROV node goes on.

Plan
- `SeabedDetector.detect(frame, pose, altitude_m)`: the seabed is the plane at the
  vehicle's depth plus its altitude.  Each pixel is compared with the local seabed around it
  (a wide blur of the frame): an object differs in colour (the ratio of its channels to the
  seabed's, which a shadow, being the seabed darker, does not change), or is far brighter or
  darker than a shadow can be.  The mask is closed (a ladder's rails and rungs become one
  frame), components too small or touching the picture's edge (not wholly in view) are
  dropped, and each component's outline is projected onto the seabed through the camera's
  rays: its minimum-area rectangle there gives centre, length, width and heading.
- Class from the measured shape (fill of its rectangle, length, slenderness): a frame that
  fills little of its rectangle is a ladder; long and slender, a pipe; short and stout, an
  amphora; the rest box-like timber; nothing fits: unknown.
- `ObjectMap.add(detections, now)`: a detection within reach of a mapped object's centre (half
  its length, at least 0.5 m) is a sighting of it: the map keeps a median of its last 15
  measurements.  Two objects that come within that reach of each other are one: the one seen
  more keeps its id, the other is told REMOVED.  An object becomes NEW after MIN_SIGHTINGS sightings; CHANGED when its centre
  moved 10 cm, its size 5 %, its heading 3 degrees or its class or confidence changed; a
  candidate seen once and not again within 5 s is forgotten (never told).

Rate: DETECT_HZ = 2.  A picture takes 11 to 21 s over the radio and a thumbnail a minute over
the acoustic link, and a record goes at most every fourth reply (0.48 s cycles) on the radio
and in a SCENE every few seconds on the acoustic link: two looks a second see an object lying
in a 6 m wide view at least 3 times while the vehicle passes at 1 m/s, and leave most of a
core to the encoder and the tracker (a look takes about 15 ms for 320x240).
"""

from __future__ import annotations

import logging
import math
import statistics
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from rovlink.link.scene import OP_CHANGED, OP_NEW, OP_REMOVED, ObjectRecord, SceneOutbox

log = logging.getLogger(__name__)

DETECT_HZ = 2.0
MIN_AREA_PX = 50  # an object's own pixels: fewer, a pebble, or too far to measure
MIN_LENGTH_M = 0.5
GROUP_PX = 13  # pieces this close are one object
PIPE_MIN_M = 2.8
EDGE_MARGIN_PX = 2
MAX_RANGE_M = 9.0  # beyond, a pixel covers more than ~5 cm: no measurement
MIN_SIGHTINGS = 3
FORGET_CANDIDATE_S = 5.0
CHROMA_T, BRIGHT_T, DARK_T = 0.08, 0.10, -0.15


@dataclass(frozen=True)
class Detection:
    """One object as one frame measured it, on the seabed (local NED, metres)."""

    class_name: str
    north_m: float
    east_m: float
    length_m: float
    width_m: float
    heading_deg: float  # long axis, 0..180
    confidence: float
    fill: float  # of its rectangle on the seabed: a frame fills little


class CameraGeometry:
    """The pinhole camera of rov/camera.py (horizontal field `hfov_deg`, tilted down `tilt_deg`
    from the vehicle's forward axis): each pixel's ray, to the seabed plane."""

    def __init__(self, width: int = 320, height: int = 240, hfov_deg: float = 80.0, tilt_deg: float = 35.0) -> None:
        self.width, self.height = width, height
        self.focal = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
        self.tilt = math.radians(tilt_deg)

    @classmethod
    def of(cls, camera: Any) -> "CameraGeometry":
        return cls(camera.width, camera.height, getattr(camera, "hfov_deg", 80.0), getattr(camera, "tilt_deg", 35.0))

    def to_seabed(self, cols: np.ndarray, rows: np.ndarray, pose: Any, seabed_depth_m: float):
        """(north, east, range) where pixels (fractional column, row of pixel centres) meet
        the plane z = seabed_depth_m; NaN where a ray misses it."""
        from rovlink.rov.camera import SimulatedCamera, _pose_tuple

        x, y, z, roll, pitch, yaw = _pose_tuple(pose)
        right = (np.asarray(cols, float) + 0.5 - self.width / 2) / self.focal
        down = (np.asarray(rows, float) + 0.5 - self.height / 2) / self.focal
        ct, st = math.cos(self.tilt), math.sin(self.tilt)
        body = np.stack([ct - down * st, right, st + down * ct])  # forward + right + down axes, body frame
        ned = SimulatedCamera._body_to_ned(roll, pitch, yaw).astype(float) @ body
        height = seabed_depth_m - z
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(ned[2] > 1e-3, height / ned[2], np.nan)
        if height <= 0:
            t = np.full_like(t, np.nan)
        rng = t * np.linalg.norm(ned, axis=0)
        return x + t * ned[0], y + t * ned[1], rng


def _classify(length: float, width: float, fill: float) -> tuple[str, float]:
    """Class and confidence from the shape measured on the seabed."""
    slender = length / max(width, 1e-3)
    if fill < 0.5 and width >= 0.3 and 1.2 <= length <= 3.5:
        return "ladder", min(1.0, 0.6 + (0.5 - fill))
    # Lengths part pipes from timber midway between the vocabulary's sizes (rov/seabed.py:
    # timber up to 2.6 m, pipes from 3 m).
    if length > PIPE_MIN_M and slender >= 7:
        return "pipe", min(1.0, 0.6 + (slender - 7) / 20)
    if length <= 1.15 and width <= 0.5:
        return "amphora", 0.85 if slender < 4.5 else 0.6
    if 1.15 < length <= PIPE_MIN_M and slender >= 2.5:
        return "timber", 0.75
    return "unknown", 0.4


class SeabedDetector:
    """Finds objects in one frame (see the module's plan).  Needs OpenCV (the `tracking` extra)."""

    def __init__(self, geometry: CameraGeometry | None = None) -> None:
        import cv2  # the caller says once if it is missing

        self._cv2 = cv2
        self.geometry = geometry or CameraGeometry()

    def mask(self, frame: np.ndarray) -> np.ndarray:
        cv2 = self._cv2
        img = frame.astype(np.float32) + 4.0
        # The seabed around: a wide median, which an object narrower than half of it does not pull.
        background = cv2.blur(cv2.medianBlur(frame, 31), (9, 9)).astype(np.float32) + 4.0
        ratio = np.log(img / background)
        brightness = ratio.mean(axis=2)
        chroma = np.abs(ratio - brightness[..., None]).max(axis=2)
        # Through the water's haze an object is mostly darker or brighter than the seabed around
        # it, seldom of another colour; its shadow joins it (the scene's light is not known).
        mask = (chroma > CHROMA_T) | (brightness > BRIGHT_T) | (brightness < DARK_T)
        return cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, np.ones((2, 2), np.uint8))

    def detect(self, frame: np.ndarray, pose: Any, altitude_m: float | None) -> list[Detection]:
        if altitude_m is None or frame is None or frame.ndim != 3:
            return []  # no seabed to project on: nothing measured
        cv2 = self._cv2
        from rovlink.rov.camera import _pose_tuple

        depth = _pose_tuple(pose)[2] + altitude_m
        raw = self.mask(frame)
        # Pieces a little apart are one object (a ladder's rails and rungs); it is measured on its
        # own pixels, not on the joining.
        groups = cv2.dilate(raw, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (GROUP_PX, GROUP_PX)))
        h, w = raw.shape
        count, labels, stats, _ = cv2.connectedComponentsWithStats(groups, connectivity=8)
        found = []
        for i in range(1, count):
            x0, y0, bw, bh, _ = stats[i]
            piece = ((labels[y0:y0 + bh, x0:x0 + bw] == i) & (raw[y0:y0 + bh, x0:x0 + bw] > 0)).astype(np.uint8)
            area = int(piece.sum())
            if area < MIN_AREA_PX:
                continue
            ys, xs = np.nonzero(piece)
            if (xs.min() + x0 <= EDGE_MARGIN_PX or ys.min() + y0 <= EDGE_MARGIN_PX
                    or xs.max() + x0 >= w - 1 - EDGE_MARGIN_PX or ys.max() + y0 >= h - 1 - EDGE_MARGIN_PX):
                continue  # not wholly in view: its size would be wrong
            # Every pixel of it on the seabed: its axis from their spread, its extents from their
            # percentiles along and across it (a few stray pixels of the seabed move neither).
            north, east, rng = self.geometry.to_seabed(xs + x0, ys + y0, pose, depth)
            if not (np.isfinite(north).all() and (rng < MAX_RANGE_M).all()):
                continue
            cn, ce = float(np.median(north)), float(np.median(east))
            dn, de = north - cn, east - ce
            cov = np.cov(np.stack([dn, de]))
            _, evecs = np.linalg.eigh(cov)
            axis_n, axis_e = evecs[0, 1], evecs[1, 1]  # the largest spread
            along = dn * axis_n + de * axis_e
            across = -dn * axis_e + de * axis_n
            lo, hi = np.percentile(along, [1.5, 98.5])
            wlo, whi = np.percentile(across, [4, 96])
            # Half a pixel's footprint at each end: pixel centres lie inside the object's edges.
            pixel_m = float(np.median(rng)) / self.geometry.focal
            length, width = float(hi - lo) + pixel_m, float(whi - wlo) + pixel_m
            if length < MIN_LENGTH_M:
                continue
            cn += axis_n * (lo + hi) / 2 - axis_e * (wlo + whi) / 2
            ce += axis_e * (lo + hi) / 2 + axis_n * (wlo + whi) / 2
            heading = math.degrees(math.atan2(axis_e, axis_n)) % 180.0
            height = depth - _pose_tuple(pose)[2]
            footprint = (rng / self.geometry.focal) ** 2 * rng / max(height, 0.1)  # a pixel's area on the seabed
            fill = min(1.0, float(footprint.sum()) / max(length * width, 1e-6))
            cls, conf = _classify(length, width, fill)
            found.append(Detection(cls, cn, ce, length, width, heading, conf, fill))
        return found


# -- the map ----------------------------------------------------------------------


def _axis_diff(a: float, b: float) -> float:
    d = abs(a - b) % 180.0
    return min(d, 180.0 - d)


def _axis_median(values: list[float]) -> float:
    """The median of axes (0..180, 180 = 0): about the first one's side."""
    ref = values[0]
    unwrapped = [ref + ((v - ref + 90.0) % 180.0 - 90.0) for v in values]
    return statistics.median(unwrapped) % 180.0


@dataclass
class MappedObject:
    object_id: int
    sightings: list[Detection] = field(default_factory=list)
    last_s: float = 0.0
    told: Detection | None = None  # what the operator was last told (None: not yet)

    def estimate(self) -> Detection:
        recent = self.sightings[-15:]
        classes = [d.class_name for d in recent]
        cls = max(set(classes), key=classes.count)
        agree = classes.count(cls) / len(classes)
        conf = statistics.median(d.confidence for d in recent) * agree * min(1.0, 0.6 + 0.1 * len(self.sightings))
        return Detection(cls, statistics.median(d.north_m for d in recent), statistics.median(d.east_m for d in recent),
                         statistics.median(d.length_m for d in recent), statistics.median(d.width_m for d in recent),
                         _axis_median([d.heading_deg for d in recent]), conf,
                         statistics.median(d.fill for d in recent))


class ObjectMap:
    """Sightings across frames merged into objects with stable ids (see the module's plan);
    what changed goes to `outbox` as §11 records."""

    def __init__(self, outbox: SceneOutbox | None = None) -> None:
        self.outbox = outbox
        self.objects: dict[int, MappedObject] = {}
        self._next_id = 0

    def _match(self, d: Detection) -> MappedObject | None:
        best, best_score = None, math.inf
        for obj in self.objects.values():
            e = obj.estimate()
            dist = math.hypot(d.north_m - e.north_m, d.east_m - e.east_m)
            reach = max(0.5, 0.5 * max(e.length_m, d.length_m))
            if dist < reach and dist < best_score:
                best, best_score = obj, dist
        return best

    def add(self, detections: list[Detection], now: float) -> None:
        for d in detections:
            obj = self._match(d)
            if obj is None:
                obj = MappedObject(self._take_id())
                self.objects[obj.object_id] = obj
            obj.sightings.append(d)
            obj.last_s = now
        self._forget_candidates(now)
        self._merge()
        self._tell()

    def _take_id(self) -> int:
        for _ in range(256):
            oid, self._next_id = self._next_id, (self._next_id + 1) % 256
            if oid not in self.objects:
                return oid
        raise RuntimeError("256 objects mapped: no id left")

    def _forget_candidates(self, now: float) -> None:
        for oid in [o.object_id for o in self.objects.values()
                    if o.told is None and len(o.sightings) < MIN_SIGHTINGS and now - o.last_s > FORGET_CANDIDATE_S]:
            del self.objects[oid]
        if len(self.objects) > 200:  # the oldest told ones go, and the operator is told
            for obj in sorted(self.objects.values(), key=lambda o: o.last_s)[:len(self.objects) - 200]:
                del self.objects[obj.object_id]
                if obj.told is not None and self.outbox is not None:
                    self.outbox.put(ObjectRecord(OP_REMOVED, obj.object_id))

    def _merge(self) -> None:
        """Two mapped objects that turned out to be one (a long one first seen in parts, far
        away): the one with more sightings keeps its id, the other is removed (told REMOVED)."""
        objs = sorted(self.objects.values(), key=lambda o: -len(o.sightings))
        for i, keep in enumerate(objs):
            if keep.object_id not in self.objects:
                continue
            k = keep.estimate()
            for other in objs[i + 1:]:
                if other.object_id not in self.objects:
                    continue
                o = other.estimate()
                reach = max(0.5, 0.5 * max(k.length_m, o.length_m))
                if math.hypot(k.north_m - o.north_m, k.east_m - o.east_m) < reach:
                    keep.sightings.extend(other.sightings)
                    keep.last_s = max(keep.last_s, other.last_s)
                    del self.objects[other.object_id]
                    if other.told is not None and self.outbox is not None:
                        self.outbox.put(ObjectRecord(OP_REMOVED, other.object_id))

    def _tell(self) -> None:
        for obj in self.objects.values():
            if len(obj.sightings) < MIN_SIGHTINGS:
                continue
            e = obj.estimate()
            t = obj.told
            if t is not None and not (
                    math.hypot(e.north_m - t.north_m, e.east_m - t.east_m) > 0.1
                    or abs(e.length_m - t.length_m) > 0.05 * t.length_m or abs(e.width_m - t.width_m) > 0.05 * t.width_m
                    or _axis_diff(e.heading_deg, t.heading_deg) > 3.0 or e.class_name != t.class_name
                    or abs(e.confidence - t.confidence) > 0.125):
                continue
            op = OP_NEW if t is None else OP_CHANGED
            obj.told = e
            if self.outbox is not None:
                self.outbox.put(ObjectRecord.from_si(op, obj.object_id, e.class_name, e.confidence, e.north_m,
                                                     e.east_m, e.length_m, e.width_m, e.heading_deg))

    def told(self) -> list[tuple[int, Detection]]:
        return [(o.object_id, o.told) for o in self.objects.values() if o.told is not None]


class ObjectWatcher:
    """Detection in a thread of its own, DETECT_HZ times a second, on what `grab()` returns:
    (frame, pose, altitude_m) or None.  A detector that fails (OpenCV missing, an error in a
    frame) is said once through `note` and stops; the ROV node goes on without objects."""

    def __init__(self, grab: Callable[[], Any], outbox: SceneOutbox, note: Callable[[str], None] = log.warning, *,
                 geometry: CameraGeometry | None = None, hz: float = DETECT_HZ,
                 detector_factory: Callable[[], SeabedDetector] | None = None) -> None:
        self.grab = grab
        self.map = ObjectMap(outbox)
        self.note = note
        self.period_s = 1.0 / hz
        self._factory = detector_factory or (lambda: SeabedDetector(geometry))
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.failed: str | None = None

    def start(self) -> "ObjectWatcher":
        self._thread = threading.Thread(target=self._run, name="rov-objects", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)

    def _run(self) -> None:
        try:
            detector = self._factory()
            while not self._stop.wait(self.period_s):
                self.look_once(detector, time.monotonic())
        except Exception as exc:  # noqa: BLE001 - any failure of the detector: said once, the node goes on
            self.failed = f"{type(exc).__name__}: {exc}"
            self.note(f"object detector stopped: {self.failed}; the ROV goes on without objects")

    def look_once(self, detector: SeabedDetector, now: float) -> None:
        got = self.grab()
        if got is None:
            return
        frame, pose, altitude = got
        self.map.add(detector.detect(frame, pose, altitude), now)


def watch_node_camera(bridge, grab, outbox, geometry: CameraGeometry | None) -> ObjectWatcher | None:
    """A node's object watcher (either profile's): its camera's frames with the bridge's
    pose and altitude at the grab, told into `outbox`; None when it recognises nothing."""
    if geometry is None or outbox is None:
        return None

    def frame():
        snap = bridge.snapshot()
        return grab(snap), snap, snap.altitude_m

    return ObjectWatcher(frame, outbox, geometry=geometry).start()  # a failure: one warning
