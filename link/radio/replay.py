"""A recorded session's replies turned back into the master's events, with no
master on a link: the frames parsed by the link's own decoder and `Reply`, the
image trunks taken by the master's own rules (`Master.take_trunk`: the IMG its
polls asked for, a FIRST over a partial picture starting it anew, the first
picture after start not shown, §4), so that a replay shows what the live
session showed.  The console's replay (console/replaycontrol.py) feeds it the
recording's records in order: the polls as they were sent, the replies as
they came.
"""

from __future__ import annotations

from ..report import report_from_reply
from .frame import FrameDecoder
from .master import Master, PoseReceived
from .messages import Poll, ProtocolError, Reply


class ReplyReplayer:
    """Recorded polls and replies in, the master's events out."""

    def __init__(self, *, skip_first_image: bool = True, bitrate_bps: float = 1900.0, delay_s: float = 0.085) -> None:
        self.decoder = FrameDecoder()
        # Its trunk rules only: it never sends, and its IMG follows the recorded polls.
        self._master = Master(skip_first_image=skip_first_image, first_img=0, bitrate_bps=bitrate_bps,
                              delay_s=delay_s)
        self.bitrate_bps, self.delay_s = bitrate_bps, delay_s
        self._polls = 0

    def poll_sent(self, poll: Poll | None, t: float) -> list:
        """A recorded poll (None: a HELLO, or bytes that were no poll)."""
        if poll is None:
            return []
        self._polls += 1
        return self._master.follow_request(poll, t)

    def feed(self, data: bytes, t: float) -> list:
        """Received bytes as recorded (protocol 1.1: the link's own frames)."""
        events: list = []
        for payload in self.decoder.feed(data):
            events.extend(self.feed_payload(payload, t))
        return events

    def feed_payload(self, payload: bytes, t: float, *, sync: bool = False) -> list:
        """One reply payload the master was given (protocol 2 records these:
        authentic, timely, tag removed; a SYNC's reply part with `sync`)."""
        try:
            reply = Reply.decode(payload, allow_sync=sync)
        except ProtocolError:
            return []
        report = report_from_reply(reply, arrived_at=t, frame_bytes=None, bitrate_bps=self.bitrate_bps,
                                   delay_s=self.delay_s)
        events: list = [PoseReceived(reply, t, None, report)]
        if not self._polls and reply.has_trunk and reply.offset == 0:
            # A recording without its polls (older ones): an image's first trunk says its IMG.
            events += self._master.follow_request(Poll(img=reply.img, offset=0), t)
        return events + self._master.take_trunk(reply, t)
