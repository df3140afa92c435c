"""Where each viewer looks from, and where the picture's screen stands.

Goals
- A pilot driving away must not lose the vehicle: by default every viewer's
  camera follows it (`follow`: behind and above, looking the way it heads);
  `top` looks down on it from above, north up, like a chart, so that turns do
  not spin the world; `free` leaves the orbit to the pilot.  A button centres
  any view on the vehicle.
- Cheap: a viewer's camera is set at most every `CHASE_PERIOD_S`, and only when
  the vehicle moved or turned enough to see it (`ViewerView.due`); the scene's
  20 Hz loop asks, nothing is pushed otherwise.
- The picture's screen never hides the vehicle in the views the scene chooses.
  Decision: it stays in the scene (the pilot draws the ROI on it) as a board
  carried ahead of and above the vehicle, leaning back, facing the follow
  camera: from behind it shows above the vehicle, from the top it lies ahead of
  it.  In `free` view the pilot may orbit to where it hides the vehicle: that
  view is his.  tests/console/test_scene_follow.py projects both from the
  views' cameras and checks they never overlap.

Plan: pure functions of the vehicle's world position and NED heading
(`chase_view`, `screen_pose`), and one small record per viewer (`ViewerView`).
World frame as in `console.scene.frames` (ENU, z up); cameras as viser's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from viser import transforms as tf

FOLLOW, TOP, FREE = "follow", "top", "free"
VIEWS = (FOLLOW, TOP, FREE)
VIEW_LABELS = {FOLLOW: "Follow (behind the vehicle)", TOP: "Top (north up)", FREE: "Free (orbit)"}

CHASE_PERIOD_S = 0.25         # a viewer's camera moves at most 4 times a second
CHASE_MIN_MOVE_M = 0.05       # ...and only when the vehicle moved this far
CHASE_MIN_TURN_DEG = 2.0      # ...or turned this much (follow view)
FOLLOW_DISTANCE_M = 6.0       # the follow camera's distance to the vehicle, until the pilot zooms
FOLLOW_ELEVATION_DEG = 20.0   # ...seen from this far above the horizon of...
FOLLOW_AIM_ABOVE_M = 1.0      # ...a point above the vehicle: it sits below the middle, the screen above it
TOP_HEIGHT_M = 10.0
TOP_TILT_DEG = 4.0            # a little south of the zenith: north up, and the orbit's up (+z) stays defined
DISTANCE_LIMITS_M = {FOLLOW: (4.0, 30.0), TOP: (6.0, 40.0)}  # the pilot's zoom, kept within
CENTRE_DISTANCE_LIMITS_M = (2.0, 20.0)

# The screen: SCREEN_WIDTH_M wide (the height follows the picture's aspect),
# its centre SCREEN_AHEAD_M ahead of the vehicle and SCREEN_ABOVE_M above
# it, its top leaning SCREEN_LEAN_DEG away from the follow camera so that the
# top view sees it too.
SCREEN_WIDTH_M = 4.0
SCREEN_AHEAD_M = 5.0
SCREEN_ABOVE_M = 2.2
SCREEN_LEAN_DEG = 30.0
SCREEN_MIN_MOVE_M = 0.05
SCREEN_MIN_TURN_DEG = 1.0

UP = np.array([0.0, 0.0, 1.0])


def heading_vector(yaw_deg: float) -> np.ndarray:
    """The world (ENU) horizontal unit vector of a NED heading."""
    y = math.radians(yaw_deg)
    return np.array([math.sin(y), math.cos(y), 0.0])


def chase_view(position, yaw_deg: float, mode: str,
               distance_m: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(eye, look_at, up) of a viewer's camera for the vehicle at world
    `position` heading `yaw_deg`, in `mode` (follow or top)."""
    p = np.asarray(position, float)
    if mode == FOLLOW:
        d = FOLLOW_DISTANCE_M if distance_m is None else distance_m
        e = math.radians(FOLLOW_ELEVATION_DEG)
        f = heading_vector(yaw_deg)
        look_at = p + FOLLOW_AIM_ABOVE_M * UP
        eye = look_at - d * math.cos(e) * f + d * math.sin(e) * UP
        return eye, look_at, UP.copy()
    if mode == TOP:
        h = TOP_HEIGHT_M if distance_m is None else distance_m
        t = math.radians(TOP_TILT_DEG)
        eye = p + np.array([0.0, -h * math.sin(t), h * math.cos(t)])
        return eye, p.copy(), UP.copy()
    raise ValueError(f"no chase view {mode!r}: one of {FOLLOW!r}, {TOP!r}")


def clamp_distance(mode: str, distance_m: float | None) -> float | None:
    if distance_m is None or not math.isfinite(distance_m):
        return None
    lo, hi = DISTANCE_LIMITS_M[mode]
    return min(max(distance_m, lo), hi)


def centred_view(eye, look_at, position) -> tuple[np.ndarray, np.ndarray]:
    """(eye, look_at) moved so that the view looks at `position` from the same
    direction, at a distance kept within CENTRE_DISTANCE_LIMITS_M."""
    offset = np.asarray(eye, float) - np.asarray(look_at, float)
    d = float(np.linalg.norm(offset))
    if d < 1e-6:
        offset, d = np.array([0.0, -1.0, 1.0]), math.sqrt(2.0)
    lo, hi = CENTRE_DISTANCE_LIMITS_M
    offset = offset / d * min(max(d, lo), hi)
    p = np.asarray(position, float)
    return p + offset, p.copy()


def screen_pose(position, yaw_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """(centre, wxyz) of the screen's image node for the vehicle at world
    `position` heading `yaw_deg`.  The node shows its picture on its -z side
    (frames' convention): towards the follow camera, rows running down the
    board, columns to that camera's right."""
    f = heading_vector(yaw_deg)
    lean = math.radians(SCREEN_LEAN_DEG)
    down = -math.cos(lean) * UP - math.sin(lean) * f   # image rows: down the board, towards the camera
    away = math.cos(lean) * f - math.sin(lean) * UP    # the side the picture does not face
    centre = np.asarray(position, float) + SCREEN_AHEAD_M * f + SCREEN_ABOVE_M * UP
    wxyz = tf.SO3.from_matrix(np.column_stack([np.cross(down, away), down, away])).wxyz
    return centre, wxyz


def pose_key(position, yaw_deg: float) -> tuple[np.ndarray, float]:
    return np.asarray(position, float).copy(), float(yaw_deg)


def moved(last: tuple[np.ndarray, float] | None, position, yaw_deg: float, min_move_m: float,
          min_turn_deg: float | None) -> bool:
    """Has the vehicle moved (or, with `min_turn_deg`, turned) enough since `last`?"""
    if last is None:
        return True
    p0, y0 = last
    if float(np.linalg.norm(np.asarray(position, float) - p0)) >= min_move_m:
        return True
    return min_turn_deg is not None and abs((yaw_deg - y0 + 180.0) % 360.0 - 180.0) >= min_turn_deg


@dataclass
class ViewerView:
    """One viewer's choice of view and when its camera was last set."""

    mode: str = FOLLOW
    last: tuple[np.ndarray, float] | None = None  # the vehicle's (position, yaw) the camera was set for
    next_at: float = 0.0                          # not before this (monotonic s)
    updates: int = 0                              # cameras set; the tests watch it
    centre: bool = False                          # a centre request waiting for the next update
    look_at: np.ndarray | None = None             # where the camera was last pointed, and...
    distance_m: float | None = None               # ...from how far

    def zoom(self, camera_look_at, camera_distance_m: float) -> float | None:
        """The distance to keep in this view: the camera's, if it still looks
        where we pointed it (the pilot's wheel moves the camera along that line;
        a report from before our last move does not look there); else ours."""
        if self.last is None or self.look_at is None:
            return None  # a new view: its own distance
        if float(np.linalg.norm(np.asarray(camera_look_at, float) - self.look_at)) < 0.05:
            return clamp_distance(self.mode, camera_distance_m)
        return self.distance_m

    def set_mode(self, mode: str) -> None:
        if mode not in VIEWS:
            raise ValueError(f"no view {mode!r}: one of {', '.join(VIEWS)}")
        self.mode = mode
        self.last = None       # at once, whatever moved
        self.next_at = 0.0

    def due(self, now: float, position, yaw_deg: float) -> bool:
        """Should this viewer's camera be set now for the vehicle there?"""
        if self.centre:
            return True
        if self.mode == FREE or now < self.next_at:
            return False
        turn = CHASE_MIN_TURN_DEG if self.mode == FOLLOW else None
        return moved(self.last, position, yaw_deg, CHASE_MIN_MOVE_M, turn)

    def done(self, now: float, position, yaw_deg: float, eye=None, look_at=None) -> None:
        if look_at is not None:
            self.look_at = np.asarray(look_at, float).copy()
            self.distance_m = float(np.linalg.norm(np.asarray(eye, float) - self.look_at))
        self.last = pose_key(position, yaw_deg)
        self.next_at = now + CHASE_PERIOD_S
        self.centre = False
        self.updates += 1
