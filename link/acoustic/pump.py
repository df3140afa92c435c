"""One acoustic end's packets to and from its modem (docs/PROTOCOL.md §9 Queues),
written once for every end that runs a machine: the operator's link process
(link/acoustic/process.py), the console's session when it keeps the machine
itself (console/session/acoustic.py: the tests' stacks), and the ROV's node
(rov/acoustic.py).

Goals: one packet in the modem at a time; STOP (and SYNC) first: when the
machine `wants_flush`, the modem's queue is flushed and the machine's next
packet handed at once; what arrives is split into 8-byte packets, whatever
the transport delivered them in.  No end splits packets or paces on its own.

Plan: `AcousticPump(machine, endpoint, lock=..., clock=..., pace_s=...)`, two
loops for the caller's event loop:
- `receiving()`: each packet to `machine.receive` under `lock`, then
  `on_received(packet, events, now)`;
- `pumping()`: every PUMP_S, `before_tick(now)`, the machine's `tick` (its
  events to `on_events(events, now)`), the flush, and, when the modem is idle
  (`modem_idle`) or was just flushed, the machine's next packet to the endpoint
  and to `on_sent(packet, now)`.
The callbacks run outside `lock` (they may take it, or send to a pipe).
"""

from __future__ import annotations

import asyncio
import math
import threading
from typing import Any, Callable

from .operator import modem_idle
from .wire import PACKET_BYTES

PUMP_S = 0.1  # how often the modem's queue is looked at (a packet a second at the most)


def _nothing(*_args) -> None:
    return None


class AcousticPump:
    def __init__(self, machine: Any, endpoint: Any, *, lock: Any = None, clock: Callable[[], float],
                 pace_s: float = 1.0,
                 on_received: Callable[[bytes, list, float], None] = _nothing,
                 on_events: Callable[[list, float], None] = _nothing,
                 on_sent: Callable[[bytes, float], None] = _nothing,
                 before_tick: Callable[[float], None] = _nothing) -> None:
        self.machine = machine
        self.endpoint = endpoint
        self.lock = lock if lock is not None else threading.Lock()
        self.clock = clock
        self.pace_s = pace_s
        self.on_received, self.on_events, self.on_sent, self.before_tick = on_received, on_events, on_sent, before_tick
        self.last_sent = -math.inf

    def split(self, data: bytes, now: float) -> None:
        """What the transport delivered, packet by packet into the machine."""
        for i in range(0, len(data) - PACKET_BYTES + 1, PACKET_BYTES):
            packet = bytes(data[i:i + PACKET_BYTES])
            with self.lock:
                events = self.machine.receive(packet, now)
            self.on_received(packet, events, now)

    async def receiving(self) -> None:
        from ..aio import recv_within

        while True:
            data = await recv_within(self.endpoint, 0.1)
            if data:
                self.split(data, self.clock())

    def turn(self) -> None:
        """One look at the machine and the modem."""
        now = self.clock()
        self.before_tick(now)
        with self.lock:
            events = self.machine.tick(now)
            flushing = self.machine.wants_flush
            if flushing:
                flush = getattr(self.endpoint, "flush", None)
                if flush is not None:
                    flush()
            ready = flushing or modem_idle(self.endpoint, now, self.last_sent, self.pace_s)
            packet = self.machine.next_packet(now) if ready else None
        if events:
            self.on_events(events, now)
        if packet is not None:
            self.endpoint.send(packet)
            self.last_sent = now
            self.on_sent(packet, now)

    async def pumping(self) -> None:
        while True:
            self.turn()
            await asyncio.sleep(PUMP_S)

    async def run(self) -> None:
        """Both loops until cancelled."""
        tasks = [asyncio.create_task(self.receiving()), asyncio.create_task(self.pumping())]
        try:
            await asyncio.gather(*tasks)
        finally:
            for task in tasks:
                task.cancel()
