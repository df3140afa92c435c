"""A recording's replies are taken by the master's own trunk rules (issue 32: the
replay had a second copy of the reassembly, without the rule that a FIRST trunk
over a partial picture starts it anew, so a replay could differ from the live
session).  The same polls and replies go to a live Master and to a
ReplyReplayer: the same pictures come out, abandoned and completed alike."""

from __future__ import annotations

from rovlink.link.radio.master import ImageAbandoned, ImageComplete, ImageProgress, Master
from rovlink.link.radio.messages import Poll, Reply
from rovlink.link.radio.replay import ReplyReplayer


def obj(stream: bytes) -> bytes:
    return len(stream).to_bytes(2, "big") + stream


def images(events) -> list:
    return [(type(e).__name__, e.img, getattr(e, "received_bytes", None)) for e in events
            if isinstance(e, (ImageProgress, ImageComplete, ImageAbandoned))]


def test_a_replay_takes_trunks_as_the_live_master_did_a_first_over_a_partial_picture_included():
    one, two, three = obj(b"A" * 40), obj(b"B" * 30), obj(b"C" * 20)
    # (poll's IMG and OFFSET, the reply's trunk): the first picture is not shown (§4), the
    # second is cut short by the ROV sending it anew (FIRST), the third completes.
    script = [
        (0, 0, Reply(img=0, offset=0, trunk=one[:24])), (0, 24, Reply(img=0, offset=24, trunk=one[24:], last=True)),
        (1, 0, Reply(img=1, offset=0, trunk=two[:24])),
        (1, 24, Reply(img=1, offset=0, trunk=three[:22], last=True)),  # FIRST again: another picture
        (2, 0, Reply(img=2, offset=0, trunk=three[:22], last=True)),
    ]
    live = Master(first_img=0)
    replayer = ReplyReplayer()
    live_events, replay_events = [], []
    for t, (img, offset, reply) in enumerate(script):
        poll = Poll(img=img, offset=offset)
        replay_events += replayer.poll_sent(poll, float(t))
        live_events += live.follow_request(poll, float(t))  # the live master asks for that IMG itself
        live_events += live.receive(reply.encode(), float(t) + 0.5)
        replay_events += replayer.feed_payload(reply.encode(), float(t) + 0.5)
    shown = images(replay_events)
    assert shown == images(live_events)
    assert ("ImageAbandoned", 1, 24) in shown  # the partial picture is given up, not glued to the new one
    assert ("ImageComplete", 2, None) in shown and not any(e[1] == 0 for e in shown)  # the first: not shown


def test_a_recording_without_its_polls_still_shows_its_pictures():
    two = obj(b"B" * 30)
    replayer = ReplyReplayer()
    events = []
    for t, reply in enumerate([Reply(img=3, offset=0, trunk=obj(b"A" * 10), last=True),
                               Reply(img=4, offset=0, trunk=two, last=True)]):
        events += replayer.feed_payload(reply.encode(), float(t))
    assert ("ImageComplete", 4, None) in images(events)
