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


class _Recorded:
    """A recorded object as the part takes one from the link."""

    def __init__(self, r: dict) -> None:
        self.object_id, self.class_name, self.confidence = int(r["id"]), str(r["class"]), float(r["confidence"])
        self.north_m, self.east_m = float(r["north_m"]), float(r["east_m"])
        self.length_m, self.width_m, self.heading_deg = float(r["length_m"]), float(r["width_m"]), float(r["heading_deg"])
