"""What both profiles say of the vehicle and its pictures, in SI and in words,
once: the console's side speaks this vocabulary, and each profile translates it
to and from its own bytes (the radio: link/radio/, docs/PROTOCOL.md §1-§8 and
§10; the acoustic link: link/acoustic/, §9).

- `Mode`: a flight mode as the protocol numbers it (§2's numbers, which §9's
  ORDER and STATUS use too); `REQUESTABLE_MODES`, what a pilot may ask for.
- `PictureRequest`: what the pilot asks of the pictures to come: an ROI in
  the picture's pixels, its SHIFT, MONO, a budget in bytes; `FollowRequest`
  adds FOLLOW (§10: the ROI follows what it framed in picture `drawn_on`).  The
  radio's IMAGE and FOLLOW orders are their wire forms (ImageSettings,
  FollowSettings); the acoustic link's THUMB its own.
- `Track`: a followed picture's track (§10) in words and seconds; `TrackState`
  its numbers.
The picture events, with their TRACK record parsed, are link/pictures.py's.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import ClassVar


class Mode(enum.IntEnum):
    """Flight modes as the protocol numbers them (requested and reported).

    In a request 0 means "keep"; in a report 0 means "unknown" and 7 "other".
    """

    KEEP = 0
    MANUAL = 1
    STABILIZE = 2
    DEPTH_HOLD = 3
    POS_HOLD = 4
    GUIDED = 5
    SURFACE = 6
    OTHER = 7

    UNKNOWN = 0  # alias of KEEP, for reports


# What a pilot may ask for (KEEP is no request; OTHER only a report says).
REQUESTABLE_MODES = (Mode.MANUAL, Mode.STABILIZE, Mode.DEPTH_HOLD, Mode.POS_HOLD, Mode.GUIDED, Mode.SURFACE)


@dataclass(frozen=True)
class PictureRequest:
    """The pictures the pilot asks for: ROI (x0, y0, x1, y1) in picture pixels or
    None, SHIFT (bit planes the ROI is raised by), MONO, a budget in bytes.  Each
    profile checks it against what its wire carries."""

    roi: tuple[int, int, int, int] | None = None
    shift: int = 0
    mono: bool = False
    budget_bytes: int = 2000

    follow: ClassVar[bool] = False  # the ROI stays where it is in the picture


@dataclass(frozen=True)
class FollowRequest(PictureRequest):
    """A picture request whose ROI follows what it framed in picture `drawn_on` (its
    IMG, §10); `keep`: a lost track keeps its last ROI, else the pictures go without one
    until it holds again.  The radio's FOLLOW order (FollowSettings) and the acoustic
    link's THUMB with its FOLLOW bit are its wire forms."""

    keep: bool = True
    drawn_on: int = 0

    follow: ClassVar[bool] = True


class TrackState(enum.IntEnum):
    """STATE of a picture's TRACK record (§10)."""

    HOLDS = 0  # the ROI is where the object is in this picture
    LOST = 1  # not found in this picture; the ROV still looks for it
    DROPPED = 2  # the ROV no longer looks for it
    UNKNOWN = 3  # reserved: shown as unknown


@dataclass(frozen=True)
class Track:
    """A followed picture's track as the ROV saw it when it took the picture."""

    state: str          # "holds", "lost", "dropped" or "unknown"
    keep: bool          # a lost track keeps its last ROI
    lost_for_s: float   # how long it has been lost (0 while it holds)

    @classmethod
    def of(cls, state: int, keep: bool, lost_for_s: float) -> "Track":
        return cls(TrackState(state).name.lower(), bool(keep), float(lost_for_s))

    def as_dict(self) -> dict:
        return {"state": self.state, "keep": self.keep, "lost_for_s": self.lost_for_s}
