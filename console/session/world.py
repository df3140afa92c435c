"""The world as the ROV measured it (docs/PROTOCOL.md §11): the seabed's depth and the
objects recognised on it, for the scene, the page and the recording.

Goal: the pilot is shown only what the link told.  The seabed is a plane at the
depth the ROV measured, its depth plus its altitude above the bottom (a
rangefinder's); with no altitude reported there is no floor, and the state says
so.  The objects are those the ROV recognised, each with its age, until the ROV
removes one; a record out of range is counted and said once.  Nothing here knows
the simulator's seabed.

Plan: `SeenWorld` is a session part like the others (console/session/): handed the
session's lock, its recorder's `write`, `publish` and `note`.  The drivers hand it
their link's events in SI (link/scene.py's `SeenObject`, an altitude in metres) and
each report's depth; `state(t)` is what GET /api/world and the telemetry's `world`
carry; `replayed` lays a recording's records again.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

# The ROV's camera as the console knows it (rov/camera.py SimulatedCamera's defaults; a
# test checks they agree): the scene draws it, "Frame it" projects through it.
CAMERA_HFOV_DEG = 80.0
CAMERA_TILT_DEG = 35.0
CAMERA_IN_BODY_FLU = (0.2, 0.0, 0.035)  # the dome at the front of the electronics tube
FRAME_RANGE_M = 8.0       # an object further off is framed by too few pixels (the mosaic's range)
FRAME_MARGIN = 0.15       # the ROI's margin round the object's footprint, a fraction of its size each side
FRAME_MIN_PX = 4          # an ROI smaller than this frames nothing (a drag this small is a click)
FRAME_IN_VIEW = 0.5       # at least this share of the footprint in the picture: in view
SAME_POSE_M, SAME_POSE_DEG = 0.3, 5.0  # a picture taken this near the pose now was taken from here
ALTITUDE_STALE_S = 10.0   # an altitude not told again within this long is shown old
STANDOFF_M = 1.5          # a go-to to an object stops this far from its nearer end, facing it
APPROACH_ALTITUDE_M = 2.5  # ... this high above the measured seabed (the detector's own height)
OBJECTS_KEPT = 64         # the ROV's map holds fewer; a bound against a misbehaving peer


class SeenWorld:
    def __init__(self, *, lock, record: Callable[[dict], None], publish: Callable[[str, Any], None],
                 note: Callable[..., None]) -> None:
        self._lock, self._record, self._publish, self._note = lock, record, publish, note
        self.altitude_m: float | None = None
        self.altitude_t: float | None = None  # when the ROV last told it (session time)
        self.depth_m: float | None = None     # the vehicle's depth when it was told (the report's then)
        self._latest_depth_m: float | None = None
        self.objects: dict[int, dict] = {}
        self.records_ignored = 0

    # -- what the link tells -------------------------------------------------

    def altitude(self, altitude_m: float | None, t: float, depth_m: float | None) -> None:
        with self._lock:
            changed = (altitude_m is None) != (self.altitude_m is None)
            self.altitude_m = None if altitude_m is None else float(altitude_m)
            self.altitude_t = t
            depth_m = self._latest_depth_m if depth_m is None else depth_m
            self.depth_m = None if depth_m is None else float(depth_m)
        self._record({"k": "altitude", "t": round(t, 4),
                      "altitude_m": None if altitude_m is None else round(float(altitude_m), 3),
                      "depth_m": None if depth_m is None else round(float(depth_m), 3)})
        if changed:
            self._note("seabed depth unknown: the ROV reports no altitude (no rangefinder)" if altitude_m is None
                       else f"seabed measured: altitude {altitude_m:.2f} m above it")
        self._publish("world", self.state(t))

    def depth(self, depth_m: float) -> None:
        """Each report's depth: an altitude told without one is measured from here.  The
        seabed is the depth an altitude was measured at plus that altitude (the ROV tells
        it again as it changes), not today's depth plus an older altitude."""
        with self._lock:
            self._latest_depth_m = float(depth_m)

    def object_seen(self, obj, record_bytes: int, t: float) -> None:
        with self._lock:
            held = self.objects.get(obj.object_id)
            info = {"id": int(obj.object_id), "class": obj.class_name, "confidence": round(float(obj.confidence), 3),
                    "north_m": round(float(obj.north_m), 3), "east_m": round(float(obj.east_m), 3),
                    "length_m": round(float(obj.length_m), 3), "width_m": round(float(obj.width_m), 3),
                    "heading_deg": round(float(obj.heading_deg), 1), "record_bytes": int(record_bytes),
                    "first_t": held["first_t"] if held else t, "updated_t": t}
            self.objects[info["id"]] = info
            if len(self.objects) > OBJECTS_KEPT:
                oldest = min(self.objects.values(), key=lambda o: o["updated_t"])
                del self.objects[oldest["id"]]
        self._record({"k": "object", "t": round(t, 4), **{k: v for k, v in info.items()
                                                          if k not in ("first_t", "updated_t")}})
        if held is None:
            self._note(f"object #{info['id']} recognised: {info['class']} {info['length_m']:.1f} x "
                       f"{info['width_m']:.1f} m at N {info['north_m']:.1f} E {info['east_m']:.1f} m "
                       f"({info['confidence']:.0%})")
        self._publish("world", self.state(t))

    def object_removed(self, object_id: int, t: float) -> None:
        with self._lock:
            gone = self.objects.pop(int(object_id), None)
        self._record({"k": "object_removed", "t": round(t, 4), "id": int(object_id)})
        if gone is not None:
            self._note(f"object #{object_id} removed by the ROV ({gone['class']})")
        self._publish("world", self.state(t))

    def record_ignored(self, record_hex: str, t: float) -> None:
        with self._lock:
            self.records_ignored += 1
            first = self.records_ignored == 1
        if first:  # one clear line; the rest are counted
            self._note(f"an object record out of range was ignored ({record_hex}); "
                       "more are counted in the world's records_ignored", "warn")

    # -- the read side --------------------------------------------------------

    def state(self, t: float) -> dict:
        with self._lock:
            alt, depth = self.altitude_m, self.depth_m
            age = None if self.altitude_t is None else round(max(0.0, t - self.altitude_t), 1)
            objects = [dict(o, age_s=round(max(0.0, t - o["updated_t"]), 1))
                       for o in sorted(self.objects.values(), key=lambda o: o["id"])]
            ignored = self.records_ignored
        seabed = None if alt is None or depth is None else round(depth + alt, 2)
        return {"seabed_depth_m": seabed, "altitude_m": alt, "altitude_age_s": age,
                "altitude_stale": age is not None and age > ALTITUDE_STALE_S,
                "seabed_unknown_why": None if seabed is not None else (
                    "no report yet" if self.altitude_t is None else "the ROV reports no altitude (no rangefinder)"),
                "objects": objects, "records_ignored": ignored}

    def approach(self, object_id: int, x_m: float, y_m: float, z_m: float) -> dict | None:
        """Where a go-to to object `object_id` stops: STANDOFF_M short of it on the line from
        (x_m, y_m) (the vehicle), facing it, APPROACH_ALTITUDE_M above the measured seabed
        (the vehicle's depth when none is measured); None for an object not held."""
        with self._lock:
            obj = self.objects.get(int(object_id))
            alt, depth = self.altitude_m, self.depth_m
        if obj is None:
            return None
        dn, de = obj["north_m"] - x_m, obj["east_m"] - y_m
        distance = math.hypot(dn, de)
        # The object's half extent along the line of approach, then the stand-off beyond it.
        if distance < 1e-6:
            dn, de, distance = 1.0, 0.0, 1.0
        along = math.radians(obj["heading_deg"])
        cos_a = abs(math.cos(along) * dn / distance + math.sin(along) * de / distance)
        reach = 0.5 * (obj["length_m"] * cos_a + obj["width_m"] * math.sqrt(max(0.0, 1.0 - cos_a * cos_a)))
        back = reach + STANDOFF_M
        tx, ty = obj["north_m"] - dn / distance * back, obj["east_m"] - de / distance * back
        tz = z_m if alt is None or depth is None else max(0.5, depth + alt - APPROACH_ALTITUDE_M)
        return {"x_m": round(tx, 2), "y_m": round(ty, 2), "z_m": round(tz, 2),
                "yaw_deg": round(math.degrees(math.atan2(de, dn)) % 360.0, 1), "object_id": obj["id"],
                "standoff_m": STANDOFF_M}

    def frame(self, object_id: int, pose, size_px: tuple[int, int]) -> tuple[tuple[int, int, int, int] | None, str]:
        """The ROI that frames object `object_id` in a picture of `size_px` taken from `pose`
        (NED, anything with x_m..yaw_deg): its footprint on the measured seabed projected
        through the camera, a margin round it, clipped to the picture, as the pilot would
        drag it.  (None, why) when it cannot: no such object, no seabed, out of view."""
        with self._lock:
            obj = self.objects.get(int(object_id))
            alt, depth = self.altitude_m, self.depth_m
        if obj is None:
            return None, f"no object #{object_id}: the ROV does not hold it"
        if alt is None or depth is None:
            return None, (f"object #{object_id} cannot be framed: seabed depth unknown (the ROV reports no altitude), "
                          "so where it lies in the picture is not known")
        what = f"object #{object_id} ({obj['class']})"
        corners = footprint_ned(obj, depth + alt)
        col, row, ahead, range_m = project_ned(pose, corners, size_px)
        centre_range = float(np.mean(range_m))
        if not ahead.all():
            return None, f"{what} is not in view of the camera from where the ROV is: it lies behind the camera"
        if centre_range > FRAME_RANGE_M:
            return None, (f"{what} is not in view of the camera from where the ROV is: {centre_range:.1f} m off, "
                          f"beyond {FRAME_RANGE_M:g} m (Go to first)")
        w, h = size_px
        x0, y0, x1, y1 = float(col.min()), float(row.min()), float(col.max()), float(row.max())
        cx0, cy0, cx1, cy1 = max(0.0, x0), max(0.0, y0), min(float(w), x1), min(float(h), y1)
        area = max(1e-9, (x1 - x0) * (y1 - y0))
        shown = max(0.0, cx1 - cx0) * max(0.0, cy1 - cy0) / area
        if shown < FRAME_IN_VIEW:
            return None, (f"{what} is not in view of the camera from where the ROV is: {shown:.0%} of it in the "
                          f"picture (turn towards it, or Go to first)")
        mx, my = FRAME_MARGIN * (x1 - x0), FRAME_MARGIN * (y1 - y0)
        roi = (max(0, math.floor(x0 - mx)), max(0, math.floor(y0 - my)),
               min(w, math.ceil(x1 + mx)), min(h, math.ceil(y1 + my)))
        if roi[2] - roi[0] < FRAME_MIN_PX or roi[3] - roi[1] < FRAME_MIN_PX:
            return None, f"{what} is too small in the picture from where the ROV is to frame (Go to first)"
        return roi, f"{what} framed at {centre_range:.1f} m"

    # -- a replay ---------------------------------------------------------------

    def replayed(self, record: dict, t: float) -> bool:
        """A recorded altitude or object, laid again; False: not a record of the world."""
        kind = record.get("k")
        if kind == "altitude":
            self.altitude(record.get("altitude_m"), t, record.get("depth_m"))
        elif kind == "object":
            self.object_seen(_Recorded(record), int(record.get("record_bytes", 0)), t)
        elif kind == "object_removed":
            self.object_removed(int(record["id"]), t)
        else:
            return False
        return True


def footprint_ned(obj: dict, floor_depth_m: float) -> np.ndarray:
    """The four corners (4, 3) of an object's footprint on the seabed, NED."""
    c, s = math.cos(math.radians(obj["heading_deg"])), math.sin(math.radians(obj["heading_deg"]))
    along = np.array([1, 1, -1, -1]) * obj["length_m"] / 2
    across = np.array([1, -1, -1, 1]) * obj["width_m"] / 2
    return np.column_stack([obj["north_m"] + along * c - across * s, obj["east_m"] + along * s + across * c,
                            np.full(4, float(floor_depth_m))])


def _rotation_ned_frd(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    r, p, y = (math.radians(v) for v in (roll_deg, pitch_deg, yaw_deg))
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def project_ned(pose, points_ned, size_px: tuple[int, int], *, hfov_deg: float = CAMERA_HFOV_DEG,
                tilt_deg: float = CAMERA_TILT_DEG, camera_in_body_flu=CAMERA_IN_BODY_FLU):
    """Where NED points fall in a picture of `size_px` taken from `pose`: (column, row) in
    pixel edges (0..W), whether each lies ahead of the camera, and its range (m)."""
    w, h = size_px
    rot = _rotation_ned_frd(pose.roll_deg, pose.pitch_deg, pose.yaw_deg)
    fx, fy, fz = camera_in_body_flu
    camera = np.array([pose.x_m, pose.y_m, pose.z_m]) + rot @ np.array([fx, -fy, -fz])  # FLU -> FRD
    body = (np.asarray(points_ned, float) - camera) @ rot  # rows: body FRD
    t = math.radians(tilt_deg)
    forward = math.cos(t) * body[:, 0] + math.sin(t) * body[:, 2]
    down = -math.sin(t) * body[:, 0] + math.cos(t) * body[:, 2]
    ahead = forward > 1e-6
    focal = (w / 2) / math.tan(math.radians(hfov_deg) / 2)
    safe = np.where(ahead, forward, 1.0)
    return (focal * body[:, 1] / safe + w / 2, focal * down / safe + h / 2, ahead,
            np.linalg.norm(np.asarray(points_ned, float) - camera, axis=1))


class _Recorded:
    """A recorded object as the part takes one from the link."""

    def __init__(self, r: dict) -> None:
        self.object_id, self.class_name, self.confidence = int(r["id"]), str(r["class"]), float(r["confidence"])
        self.north_m, self.east_m = float(r["north_m"]), float(r["east_m"])
        self.length_m, self.width_m, self.heading_deg = float(r["length_m"]), float(r["width_m"]), float(r["heading_deg"])
