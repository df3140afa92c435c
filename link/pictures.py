"""The picture events the console takes from either link, in one vocabulary
(link/vocabulary.py): a picture coming in, complete, or given up.

A followed picture's stream starts with §10's TRACK record; the event parses it
here, in link/, so that its taker gets the DEBT stream (`stream`) and the track
in words (`track`) and never reads the record's bytes.  `prefix` and `data`
stay the object's stream as it came (its byte counts are the link's)."""

from __future__ import annotations

from dataclasses import dataclass, field

from .radio.messages import split_track
from .vocabulary import Track

PILOT_SKIPPED = "skipped by the pilot"  # ImageAbandoned's reason for Next image (`Master.abandon_image`)


class PictureEvent:
    """Base of the picture events both profiles hand the console."""


def _parsed(obj_stream: bytes) -> tuple[Track | None, bytes]:
    record, stream = split_track(obj_stream)
    track = None if record is None else Track.of(record.state, record.keep, record.lost_for_s)
    return track, stream


@dataclass(frozen=True)
class ImageProgress(PictureEvent):
    img: int
    received_bytes: int  # contiguous bytes of the object held
    total_bytes: int | None  # object size, once its first two bytes are in
    prefix: bytes  # the object's stream held (without its length), TRACK record first under FOLLOW
    track: Track | None = field(init=False, compare=False)
    stream: bytes = field(init=False, compare=False, repr=False)  # the DEBT stream prefix

    def __post_init__(self) -> None:
        track, stream = _parsed(self.prefix)
        object.__setattr__(self, "track", track)
        object.__setattr__(self, "stream", stream)


@dataclass(frozen=True)
class ImageComplete(PictureEvent):
    img: int
    data: bytes  # the whole object stream (without its length), TRACK record first under FOLLOW
    started_at: float
    at: float
    track: Track | None = field(init=False, compare=False)
    stream: bytes = field(init=False, compare=False, repr=False)  # the whole DEBT stream

    def __post_init__(self) -> None:
        track, stream = _parsed(self.data)
        object.__setattr__(self, "track", track)
        object.__setattr__(self, "stream", stream)


@dataclass(frozen=True)
class ImageAbandoned(PictureEvent):
    img: int
    received_bytes: int
    reason: str
