"""link/vocabulary.py: what both profiles say of the pictures, once. A follow request
is a picture request that follows; the radio's FOLLOW order is its wire form, and the
session's requested settings after a follow say so in the vocabulary's own terms."""

from __future__ import annotations

import dataclasses

import pytest

from rovlink.link.radio.messages import FollowSettings, ImageSettings, ProtocolError
from rovlink.link.vocabulary import FollowRequest, PictureRequest


def test_a_follow_request_is_a_picture_request_that_follows_and_follow_is_its_radio_form():
    request = FollowRequest(roi=(1, 2, 30, 40), shift=4, mono=True, budget_bytes=900, keep=False, drawn_on=5)
    assert isinstance(request, PictureRequest) and request.follow and not PictureRequest().follow
    assert [f.name for f in dataclasses.fields(FollowRequest)] == ["roi", "shift", "mono", "budget_bytes", "keep",
                                                                  "drawn_on"]
    wire = FollowSettings(roi=(1, 2, 30, 40), shift=4, mono=True, budget_bytes=900, keep=False, drawn_on=5)
    assert isinstance(wire, FollowRequest) and isinstance(wire, ImageSettings) and wire.follow
    assert dataclasses.astuple(wire) == dataclasses.astuple(request)
    assert FollowSettings.decode_body(wire.encode_body()) == wire
    assert not ImageSettings(roi=(1, 2, 30, 40)).follow
    with pytest.raises(ProtocolError):
        FollowSettings(roi=None)


def test_the_radio_sessions_requested_settings_after_a_follow_are_a_follow_request():
    from rovlink.console.session.radio import Operator

    op = Operator(None)
    try:
        op.set_image_settings(roi=(0, 0, 64, 48), shift=3, budget_bytes=1500)
        assert not op.requested_settings.follow
        op.follow_roi((10, 10, 40, 30), keep=True, drawn_on=2)
        s = op.requested_settings
        assert isinstance(s, FollowRequest) and s.follow and (s.keep, s.drawn_on, s.budget_bytes) == (True, 2, 1500)
    finally:
        op.close()
