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
        # A setting is handed over without waiting for its answer; the next call's answer
        # comes after it (one pipe, in order), and with it the status it made.
        link.set_pilot_in_force(True)
        assert link.cancel_stop() is False
        assert master.pilot_in_force and link.pilot_in_force
        link.set_pilot_in_force(False)
        link.abandon_image()
        assert not master.pilot_in_force and not link.pilot_in_force
        assert not link._late  # every answer read, the settings' too
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


class SlowMaster(Master):
    """A master whose send_order waits on the test: a machine too busy to answer in time."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.go_on = threading.Event()

    def send_order(self, order):
        self.go_on.wait(10)
        return super().send_order(order)


def slow_master_served(monkeypatch) -> tuple[MasterProcess, SlowMaster, Served]:
    """A radio link process's console side and its child's command thread serving a
    SlowMaster, calls given up after 0.3 s."""
    from rovlink.link import process

    monkeypatch.setattr(process, "CALL_TIMEOUT_S", 0.3)
    link = MasterProcess("udp://127.0.0.1:9?peer=127.0.0.1:9", bitrate_bps=1900.0, delay_s=0.085,
                         max_frame=None, t0=0.0)
    master = SlowMaster(bitrate_bps=1900.0, delay_s=0.085)
    return link, master, Served(link, master, radio_status, CALLS)


def test_a_call_answered_late_is_told_to_its_caller_and_never_read_as_the_next_calls_answer(monkeypatch):
    """The console's half of the hostile-relay STOP: a link process that is up but slow
    to answer is not "down".  The order was handed over and may yet go: its caller is
    told LinkProcessSlow and, when the answer comes, the result (the master's order id);
    the next call still gets its own answer, not the late one."""
    from rovlink.link import process
    from rovlink.link.radio.messages import Stop

    link, master, served = slow_master_served(monkeypatch)
    told: list = []
    try:
        with pytest.raises(process.LinkProcessSlow, match="did not answer send_order within 0.3 s") as slow:
            link.send_order(Stop())
        assert isinstance(slow.value, LinkProcessDown)  # where only "not now" is understood
        slow.value.when_answered(lambda result: told.append(("ok", result)),
                                 lambda text: told.append(("refused", text)), lambda why: told.append(("lost", why)))
        assert told == []
        master.go_on.set()
        # The next call waits for its own answer, reading the late one on the way.
        # (cancel_stop's own answer: False, the STOP may not be given up here; the late
        # answer, order id 1, read as this call's would have said True)
        assert link.cancel_stop() is False
        assert told == [("ok", 1)] and not link._late and master.stopping
    finally:
        served.end()


def test_a_late_answer_is_read_between_calls_and_a_process_that_ends_first_loses_it(monkeypatch):
    from rovlink.link import process
    from rovlink.link.radio.messages import Stop

    link, master, served = slow_master_served(monkeypatch)
    told: list = []
    try:
        with pytest.raises(process.LinkProcessSlow) as slow:
            link.send_order(Stop())
        master.go_on.set()
        served.thread.join(0.5)  # (it answers meanwhile; nobody reads it yet)
        # What the link loop does each turn: the answer read with no call waiting, and
        # told at once to a caller that says what it wants after it came.
        link._read_late_answers()
        assert not link._late
        slow.value.when_answered(lambda result: told.append(("ok", result)), told.append, told.append)
        assert told == [("ok", 1)]
        # A second slow call, and the process ends before it answers: lost, with why.
        master.go_on.clear()
        with pytest.raises(process.LinkProcessSlow) as slow2:
            link.send_order(Stop())
        slow2.value.when_answered(lambda result: told.append(("ok", result)),
                                  lambda text: told.append(("refused", text)), lambda why: told.append(("lost", why)))
        link._lose_late("the link process ended before it answered")
        assert told[-1] == ("lost", "the link process ended before it answered")
    finally:
        master.go_on.set()
        served.end()


def test_the_pilots_wish_is_taken_while_the_link_process_says_more_than_the_console_can_read(monkeypatch):
    """A link process whose messages come faster than the console takes them (a fast link,
    a console loaded by a browser): the console reads them a slice at a time, so that its
    own timers run between and read the answers to its calls.  Before, it read for as long
    as any message waited: the answers to the wishes it cast piled up unread, the child's
    command thread blocked writing them, and a held stick was not taken for 20 s."""
    import asyncio
    import time

    link = MasterProcess("udp://127.0.0.1:9?peer=127.0.0.1:9", bitrate_bps=1900.0, delay_s=0.085,
                         max_frame=None, t0=0.0)
    master = Master(bitrate_bps=1900.0, delay_s=0.085)
    flooding = threading.Event()
    flooding.set()
    threads: list[threading.Thread] = []

    class Child:  # the process's place, for the supervisor's join
        exitcode = 0

        def join(self, timeout=None) -> None:
            for thread in threads:
                thread.join(timeout)

    def spawn() -> None:
        commands, child_commands = multiprocessing.Pipe(duplex=True)
        child_events, events = multiprocessing.Pipe(duplex=False)

        def flood() -> None:  # what a link process polling a fast link says: for 15 s at most
            events.send(("up", 1))             # (a console stuck reading would hang the test)
            n, until = 0, time.monotonic() + 15.0
            try:
                while flooding.is_set() and time.monotonic() < until:
                    n += 1
                    events.send(("rx", bytes(24), float(n)))
            except OSError:
                pass  # the console's end closed at the test's end
            flooding.clear()
            events.close()

        threads[:] = [threading.Thread(target=flood, daemon=True),
                      threading.Thread(target=_serve_calls, args=(child_commands,), daemon=True, kwargs={
                          "what": "link", "calls": CALLS, "machine": master, "lock": threading.Lock(),
                          "status": lambda: radio_status(master), "gone": lambda: None})]
        for thread in threads:
            thread.start()
        link._process, link._commands, link._events = Child(), commands, child_events

    monkeypatch.setattr(link, "_spawn", spawn)
    taken = [0]

    def take(message: tuple) -> None:  # a console slower than the link process
        taken[0] += 1
        time.sleep(0.0002)

    sent = [0]

    def turn() -> None:  # the session's timers: the pilot's pad, read and cast every turn (twenty here)
        if link.up and sent[0] < 20:
            sent[0] += 1
            link.set_velocity(sent[0], 0, 0, 0, float(sent[0]))

    async def main() -> None:
        task = asyncio.ensure_future(link._supervise(take, turn=turn, up=lambda pid: None, down=lambda why: None))
        try:
            deadline = time.monotonic() + 12.0
            # Twenty wishes cast and taken by the master, all answers read, while the flood goes on.
            while time.monotonic() < deadline and not (master.velocity.vx == 20 and not link._late):
                await asyncio.sleep(0.05)
            assert flooding.is_set() and taken[0] > 1000, \
                f"the flood ended first ({taken[0]} messages taken, {sent[0]} wishes cast): the console's timers did not run"
            assert master.velocity.vx == 20 and not link._late, \
                (sent, master.velocity, len(link._late), taken)
        finally:
            flooding.clear()
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task

    try:
        asyncio.run(main())
    finally:
        flooding.clear()
        link._tell_to_end()
        link._close_pipes()


def test_a_link_process_refused_real_time_says_so_and_keeps_the_nice_it_got(monkeypatch, caplog):
    """raise_priority where the system refuses real-time scheduling (a container without
    CAP_SYS_NICE or real-time time): nice -10 if allowed, and one warning that says why."""
    import os

    from rovlink.link import process

    calls = []

    def refuse(pid, policy, param):
        calls.append((pid, policy, param.sched_priority))
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "setpriority", lambda which, who, prio: calls.append(("nice", prio)))
    monkeypatch.setattr(os, "getpriority", lambda which, who: process.LINK_NICE)
    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with caplog.at_level("WARNING", logger="rovlink.link.process"):
        got = process.raise_priority()
    assert calls == [("nice", process.LINK_NICE), (0, os.SCHED_RR, process.LINK_RT_PRIORITY)]
    assert got == f"nice {process.LINK_NICE}"
    assert [r.getMessage() for r in caplog.records] == [
        f"no real-time priority for the link process (Operation not permitted): it runs at nice {process.LINK_NICE}; "
        "a busy machine may delay its polls"]
