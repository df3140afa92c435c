"""What both profiles' link processes share (link/process.py `LinkProcess` and the
child's command thread), on its own: the console's calls over a real pipe to a
real machine served by the child's command thread, here in a thread of the test
(the whole processes: tests/console/test_link_process.py and
tests/console/test_acoustic_link_process.py)."""

from __future__ import annotations

import multiprocessing
import threading

import pytest

from rovlink.link.acoustic.bodies import ThumbRequest
from rovlink.link.acoustic.operator import AcousticOperator
from rovlink.link.acoustic.process import CALLS as ACOUSTIC_CALLS
from rovlink.link.acoustic.process import AcousticLinkProcess
from rovlink.link.acoustic.process import _status as acoustic_status
from rovlink.link.acoustic.wire import OrderRefused
from rovlink.link.process import CALLS, LinkProcessDown, MasterProcess, _serve_calls
from rovlink.link.process import _status as radio_status
from rovlink.link.radio.master import Master

K = bytes(range(32))


class Served:
    """`machine` behind the child's command thread, `link`'s commands pipe its console end."""

    def __init__(self, link, machine, status, calls, **serving) -> None:
        console_end, child_end = multiprocessing.Pipe(duplex=True)
        self.gone = threading.Event()
        self.thread = threading.Thread(
            target=_serve_calls, args=(child_end,),
            kwargs={"what": link.what, "calls": calls, "machine": machine, "lock": threading.Lock(),
                    "status": lambda: status(machine), "gone": self.gone.set, **serving}, daemon=True)
        self.thread.start()
        link._commands = console_end
        link.up = True
        self.link = link

    def end(self) -> None:
        self.link._tell_to_end()
        self.thread.join(5)
        self.link._close_pipes()


def test_the_acoustic_machines_refusal_reaches_the_console_in_its_own_words_and_its_status_with_it():
    link = AcousticLinkProcess("wlmodem:///dev/null?role=a", K)
    op = AcousticOperator(K)
    served = Served(link, op, acoustic_status, ACOUSTIC_CALLS, refused=(OrderRefused,))
    try:
        with pytest.raises(OrderRefused, match="^no STATUS from the ROV yet in this session$"):
            link.send_order(ThumbRequest(0), 1.0)
        assert not link.stop_active
        stop_no = link.stop(2.0)
        assert op.stop_active and link.stop_active and link.stop_no == stop_no == op.stop_no
        with pytest.raises(ValueError, match="^ValueError: tick is not a call of the acoustic link process$") as refused:
            link._call("tick", 3.0)
        assert not isinstance(refused.value, OrderRefused)
    finally:
        served.end()
    assert served.gone.is_set() and not served.thread.is_alive()  # "quit" ends the thread, and says so
    with pytest.raises(LinkProcessDown, match="^the acoustic link process is not running"):
        link.cancel_stop()


def test_the_radio_masters_calls_answered_with_its_status_and_a_call_not_listed_refused():
    link = MasterProcess("udp://127.0.0.1:9?peer=127.0.0.1:9", bitrate_bps=1900.0, delay_s=0.085,
                         max_frame=None, t0=0.0)
    master = Master(bitrate_bps=1900.0, delay_s=0.085)
    served = Served(link, master, radio_status, CALLS)
    try:
        link.set_pilot_in_force(True)
        assert master.pilot_in_force and link.pilot_in_force
        link.set_pilot_in_force(False)
        assert not master.pilot_in_force and not link.pilot_in_force
        with pytest.raises(ValueError, match="^ValueError: receive is not a call of the link process$"):
            link._call("receive", b"\x00")
    finally:
        served.end()
    assert served.gone.is_set()
    # No link process: a setting is kept for the next one, an order is refused with why.
    link.set_attended(True)
    assert link._kept["set_attended"] == (True,)
    with pytest.raises(LinkProcessDown, match="^the link process is not running"):
        link.cancel_stop()


def test_the_master_loop_sends_a_poll_before_it_hands_on_what_happened():
    """run_master: the poll leaves before the events are handed on, so that a slow
    callback (a console's, a pipe to it) never comes out of its reply's time."""
    import asyncio

    from rovlink.link.aio import run_master
    from rovlink.link.radio.events import PollSent

    class Endpoint:
        max_frame = None

        def __init__(self) -> None:
            self.sent: list[bytes] = []

        def send(self, frame: bytes) -> None:
            self.sent.append(frame)

        async def recv(self) -> bytes:
            await asyncio.sleep(3600)

        def recv_nowait(self):
            return None

    endpoint = Endpoint()
    seen: list[tuple[bytes, int]] = []

    async def main() -> None:
        tasks: list[asyncio.Future] = []

        def on_events(events: list, now: float) -> None:
            for e in events:
                if isinstance(e, PollSent):
                    seen.append((e.frame, len(endpoint.sent)))
                    tasks[0].cancel()

        tasks.append(asyncio.ensure_future(run_master(Master(bitrate_bps=1900, delay_s=0.085), endpoint, on_events)))
        with pytest.raises(asyncio.CancelledError):
            await tasks[0]

    asyncio.run(main())
    frame, sent_before = seen[0]
    assert sent_before == 1 and endpoint.sent[0] == frame
