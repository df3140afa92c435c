"""The capture window shown with a picture holds its real grab time, also when the
reply that ended the previous picture was lost and asked for again (issue 17 of the
console's house: under load a window was shown that held none of the ROV's grabs).
The ROV grabs the next picture when it first sends the last trunk of the one before
(rov/node.py's prefetch): the window starts no later than the first poll whose
answer could carry that trunk.  A fake clock; the operator fed as its link loop does."""

from __future__ import annotations

from rovlink.console.session.radio import Operator
from rovlink.link.radio.frame import encode_frame
from rovlink.link.radio.master import ImageComplete, ImageProgress, PollSent, PoseReceived
from rovlink.link.radio.messages import Mode, Poll, Reply, Velocity

from ..helpers import FakeClock


def test_a_lost_last_trunk_widens_the_window_back_to_the_first_poll_that_could_end_the_picture():
    clock = FakeClock()
    op = Operator(None, clock=clock)
    stream = bytes(298)  # an object of 300 bytes: SIZE 3's trunk (239) from OFFSET 100 ends it

    def poll(t, img, offset, size=3):
        clock.t = t
        sent = Poll(seq=0, size=size, order=Velocity(), img=img, offset=offset)
        op.handle_events([PollSent(t, encode_frame(sent.encode()), sent)], t)

    poll(5.0, 2, 0)
    poll(8.0, 2, 100, size=0)  # 100 + 24 does not reach the end: not a possible last trunk
    poll(10.0, 2, 100)  # could carry the last trunk: the ROV answers, grabs the next picture; the reply is lost
    poll(11.5, 2, 100)  # asked again
    clock.t = 12.7
    reply = Reply(mode=Mode.MANUAL, autopilot=True, position_valid=True, attitude_valid=True)
    op.handle_events([PoseReceived(reply, 12.7, 1.2),
                   ImageComplete(2, stream, 5.0, 12.7)], 12.7)
    poll(12.7, 3, 0)
    clock.t = 14.0
    op.handle_events([PoseReceived(reply, 14.0, 1.3), ImageProgress(3, 200, 300, bytes(198))], 14.0)
    capture = op.image.capture
    assert capture["not_before_wall"] <= op.wall(10.0) + 1e-3  # the grab (~10.1) is inside
    assert capture["not_before_wall"] >= op.wall(8.0)  # and no wider than it must be
    assert capture["not_after_wall"] == round(op.wall(14.0), 3)
