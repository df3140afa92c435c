"""What a followed picture says (docs/PROTOCOL.md §10): its TRACK record and the ROI it
was coded with, for the picture's state and the pictures kept.

A picture coded under FOLLOW starts its stream with a TRACK record; the ROI it was
coded with is its DEBT header's (the ROV moved it), not the settings the console sent.
`read_picture` parts the record from the DEBT stream (which is what is decoded and
kept); `coded_settings` puts the header's ROI into the settings a picture is shown with,
so whatever draws "the ROI this picture was coded with" draws where the ROV put it.
"""

from __future__ import annotations

from rovlink import debt
from rovlink.link.radio.messages import TrackState, split_track

TRACK_STATES = {TrackState.HOLDS: "holds", TrackState.LOST: "lost", TrackState.DROPPED: "dropped",
                TrackState.UNKNOWN: "unknown"}


def read_picture(prefix: bytes) -> tuple[dict | None, tuple | None, bytes]:
    """(the track as the page shows it or None, the ROI its DEBT header names or None, the DEBT stream)."""
    record, stream = split_track(prefix)
    if record is None:
        return None, None, stream
    try:
        roi = debt.unpack_header(stream).roi
    except ValueError:  # the header not yet in (IncompleteStream), or damaged: said when decoded
        roi = None
    track = {"state": TRACK_STATES[TrackState(record.state)], "keep": record.keep, "lost_for_s": record.lost_for_s}
    return track, roi, stream


def coded_settings(settings: dict | None, track: dict | None, roi: tuple | None) -> dict | None:
    """A followed picture's settings with the ROI it was coded with."""
    if settings is None or track is None:
        return settings
    return {**settings, "roi": list(roi) if roi else None}
