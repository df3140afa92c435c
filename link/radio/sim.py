"""Master and slave joined by an emulated channel, in simulated time.

Goals: run a long session (ten minutes of a 1.9 kbit/s link) in seconds, with
the very state machines and channel the real programs use, for tests and
benchmarks.

Plan: a small discrete-event loop.  The clock jumps to the next thing that
can happen (a packet arrives, the master's reply timeout, the slave's
failsafe, a scheduled callback); at each instant deliveries are handed to the
receiving machine and whatever it sends goes back into the channel.  The
master side "a", the slave side "b".  The slave's `OrderStarted` is answered
by `autopilot(event, now)` -> (accepted, reason) or None (no answer yet; the
caller may answer later with `slave.order_outcome`); by default at once, accepted.
"""

from __future__ import annotations

import heapq
import math
from typing import Callable

from ..emulators.channel import Channel
from .master import Master
from .slave import OrderStarted, Slave


def accept_at_once(event: OrderStarted, now: float) -> tuple[bool, int | None]:
    return True, None


class SimLink:
    def __init__(
        self,
        master: Master,
        slave: Slave,
        channel: Channel,
        *,
        turnaround_s: float = 0.002,
        on_master_event: Callable[[object, float], None] | None = None,
        on_slave_event: Callable[[object, float], None] | None = None,
        start: float = 0.0,
        autopilot: Callable[[OrderStarted, float], tuple[bool, int | None] | None] | None = accept_at_once,
    ) -> None:
        self.master = master
        self.slave = slave
        self.channel = channel
        self.turnaround_s = turnaround_s
        self.on_master_event = on_master_event
        self.on_slave_event = on_slave_event
        self.now = start
        self._timers: list[tuple[float, int, Callable[[float], None]]] = []
        self._timer_seq = 0
        self._master_ready_at = start  # the master may poll from here on
        self.master_down = False  # set to emulate an operator that went away
        self.slave_down = False
        self.autopilot = autopilot

    def at(self, t: float, fn: Callable[[float], None]) -> None:
        """Call fn(now) at simulated time t."""
        self._timer_seq += 1
        heapq.heappush(self._timers, (t, self._timer_seq, fn))

    def _master_events(self, events) -> None:
        if self.on_master_event:
            for e in events:
                self.on_master_event(e, self.now)

    def _slave_events(self, events) -> None:
        for e in events:
            if self.on_slave_event:
                self.on_slave_event(e, self.now)
            if isinstance(e, OrderStarted) and self.autopilot is not None:
                answer = self.autopilot(e, self.now)
                if answer is not None:
                    self._slave_events(self.slave.order_outcome(e.token, answer[0], answer[1], self.now))

    def run_until(self, t_end: float) -> None:
        while True:
            now = self.now
            while self._timers and self._timers[0][0] <= now:
                _, _, fn = heapq.heappop(self._timers)
                fn(now)
            for d in self.channel.deliver(now):
                if d.to == "b":
                    if self.slave_down:
                        continue
                    out = self.slave.receive_bytes(d.data, now)
                    self._slave_events(out.events)
                    if out.reply:
                        self.channel.send("b", out.reply, now + self.turnaround_s)
                elif not self.master_down:
                    self._master_events(self.master.receive_bytes(d.data, now))
                    self._master_ready_at = now + self.turnaround_s
            if not self.slave_down:
                self._slave_events(self.slave.tick(now))
            if not self.master_down and now >= self._master_ready_at:
                frame = self.master.next_poll(now)
                self._master_events(self.master.take_events())
                if frame:
                    self.channel.send("a", frame, now)
            if now >= t_end:
                break
            candidates = [t_end]
            nt = self.channel.next_time()
            if nt is not None:
                candidates.append(nt)
            if self._timers:
                candidates.append(self._timers[0][0])
            if not self.master_down:
                dl = self.master.deadline()
                candidates.append(dl if dl is not None else self._master_ready_at)
            failsafe_at = self.slave.failsafe_at
            if not self.slave_down and failsafe_at is not None:
                candidates.append(failsafe_at)
            nxt = min(c for c in candidates if c is not None)
            # Never stand still: a candidate in the past means "now".
            self.now = max(now, nxt) if nxt > now else _next_after(now, nxt)


def _next_after(now: float, nxt: float) -> float:
    # Something is due at or before now but was not consumed (a master ready
    # time that equals now after it already polled): step a hair forward.
    return math.nextafter(now, math.inf) if nxt <= now else nxt
