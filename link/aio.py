"""Thin asyncio drivers around the sans-I/O machines: master, slave, channel.

Goals: all protocol decisions stay in `link.master`, `link.slave` and
`link.channel`; these loops only move bytes between them and an `Endpoint`
and feed them the clock (the event loop's monotonic time).

Each driver runs until cancelled and hands events to a callback
`on_events(events, now)`; a callback that raises is logged and the link goes
on (a bug in a display must not stop the vehicle's commands).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from typing import Callable

from .emulators.channel import Channel
from .radio.master import Master
from .radio.slave import Slave
from .transports.transport import Endpoint

log = logging.getLogger("rovlink.link")

EventSink = Callable[[list, float], None]

# The console polls no sooner than this after its previous poll (docs/PROTOCOL.md §5,
# decided): over a link faster than a radio (a tether, a test's loopback) it would cycle
# every millisecond, far more often than the autopilot's odometry changes, and spend both
# ends' CPU on it.  A radio's cycle (100 ms and more) or an acoustic one never meets it.
CONSOLE_POLL_FLOOR_S = 0.02


def _now() -> float:
    return asyncio.get_running_loop().time()


async def recv_within(endpoint: Endpoint, timeout_s: float | None) -> bytes | None:
    """Next bytes from endpoint, or None after timeout_s.

    asyncio.timeout rather than wait_for: in Python 3.11 wait_for swallows a
    cancellation that arrives just as the inner get completes, and a fast
    link loop would then never stop.
    """
    try:
        async with asyncio.timeout(timeout_s):
            return await endpoint.recv()
    except TimeoutError:
        return None


def _safely(fn: Callable | None, *args) -> None:
    if fn is None:
        return
    try:
        fn(*args)
    except Exception:
        log.exception("event handler failed; the link goes on")


def _hand(on_events: EventSink | None, events: list, now: float) -> None:
    if events:
        _safely(on_events, events, now)


async def run_master(
    master: Master,
    endpoint: Endpoint,
    on_events: EventSink | None = None,
    *,
    idle_poll_s: float = 0.05,
    clock: Callable[[], float] | None = None,
    lock: contextlib.AbstractContextManager | None = None,
    on_bytes: Callable[[bytes, float], None] | None = None,
    on_turn: Callable[[float], None] | None = None,
    poll_floor_s: float = 0.0,
) -> None:
    """Poll, wait for the reply or its timeout, repeat.  Cancel to stop.

    The one master loop (the console's operator runs it too).  `clock`: the
    time the master is fed (default the event loop's); `lock`: held around every
    call into the master (other threads order through it); `on_bytes(data,
    now)`: bytes received, before the master sees them (a recording);
    `on_turn(now)`: once per turn of the loop (timers of the caller's own);
    `poll_floor_s`: no poll starts sooner than this after the one before
    (docs/PROTOCOL.md §5, the console's CONSOLE_POLL_FLOOR_S)."""
    clock = clock or _now
    guard = lock if lock is not None else contextlib.nullcontext()
    last_poll_at = -math.inf
    while True:
        now = clock()
        frame, events = None, []
        if now >= last_poll_at + poll_floor_s:
            with guard:
                frame = master.next_poll(now)
                events = master.take_events()
            if frame is not None:
                last_poll_at = now
        # The poll first: its timer runs from `now`, and whatever the callbacks take
        # (a busy console, a pipe to it) must not come out of its reply's time.
        if frame is not None:
            endpoint.send(frame)
        _hand(on_events, events, now)
        _safely(on_turn, now)
        with guard:
            deadline = master.deadline()
        if deadline is None and poll_floor_s > 0:
            deadline = last_poll_at + poll_floor_s  # the token is ours: the next poll once the floor passed
        wait = idle_poll_s if deadline is None else max(0.0, deadline - clock())
        data = await recv_within(endpoint, wait)
        # Whatever else already arrived too, before polling again.
        while data is not None:
            now = clock()
            _safely(on_bytes, data, now)
            with guard:
                events = master.receive_bytes(data, now)
            _hand(on_events, events, now)
            data = endpoint.recv_nowait()


async def run_slave(
    slave: Slave,
    endpoint: Endpoint,
    on_events: EventSink | None = None,
    *,
    tick_s: float = 0.1,
) -> None:
    """Answer polls as they come; check the failsafe every `tick_s`."""
    while True:
        data = await recv_within(endpoint, tick_s)
        if data is None:
            now = _now()
            _hand(on_events, slave.tick(now), now)
            continue
        now = _now()
        out = slave.receive_bytes(data, now)
        if out.reply:
            endpoint.send(out.reply)
        _hand(on_events, out.events, now)


async def run_channel(channel: Channel, a: Endpoint, b: Endpoint) -> None:
    """Carry bytes between two endpoints through the emulated channel."""
    wake = asyncio.Event()
    ends = {"a": a, "b": b}

    async def pump(side: str) -> None:
        end = ends[side]
        while True:
            data = await end.recv()
            channel.send(side, data, _now())
            wake.set()

    async def deliver() -> None:
        while True:
            for d in channel.deliver(_now()):
                ends[d.to].send(d.data)
            nxt = channel.next_time()
            wake.clear()
            timeout = None if nxt is None else max(0.0, nxt - _now())
            try:
                async with asyncio.timeout(timeout):
                    await wake.wait()
            except TimeoutError:
                pass

    tasks = [asyncio.create_task(pump("a")), asyncio.create_task(pump("b")), asyncio.create_task(deliver())]
    try:
        await asyncio.gather(*tasks)
    finally:
        for t in tasks:
            t.cancel()
