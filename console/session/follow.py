"""What a followed picture says (docs/PROTOCOL.md §10): its track and the ROI it was
coded with, for the picture's state and the pictures kept.

A picture coded under FOLLOW starts its stream with a TRACK record; the ROI it was
coded with is its DEBT header's (the ROV moved it), not the settings the console sent.
The link parts the record from the DEBT stream (link/pictures.py: the event's `track`
and `stream`); `read_picture` reads the ROI the DEBT header names; `coded_settings`
puts that ROI into the settings a picture is shown with, so whatever draws "the ROI
this picture was coded with" draws where the ROV put it.
"""

from __future__ import annotations

from rovlink import debt
from rovlink.link.vocabulary import Track


def read_picture(track: Track | None, stream: bytes) -> tuple[dict | None, tuple | None, bytes]:
    """(the track as the page shows it or None, the ROI its DEBT header names or None, the DEBT stream).
    The link parsed the TRACK record (link/pictures.py); what is left here is DEBT's header."""
    if track is None:
        return None, None, stream
    try:
        roi = debt.unpack_header(stream).roi
    except ValueError:  # the header not yet in (IncompleteStream), or damaged: said when decoded
        roi = None
    return track.as_dict(), roi, stream


def coded_settings(settings: dict | None, track: dict | None, roi: tuple | None) -> dict | None:
    """A followed picture's settings with the ROI it was coded with."""
    if settings is None or track is None:
        return settings
    return {**settings, "roi": list(roi) if roi else None}
