"""The acoustic link in a process of its own (issue 33): the operator's machine
(`AcousticOperator`), the modem endpoint, the pacing (a packet whenever the
modem's queue is empty, flushed for a STOP) and the machine's clock, apart
from the console's page, scene, gateway and thumbnail decoding.

Goal: as the radio link's (link/process.py, whose `LinkProcess` and child's
pieces this stands on): a
packet goes to the modem when its queue empties, whatever the console's
process is doing, and a fault on either side is safe and loud.

Plan: `AcousticLinkProcess` stands in the console for the machine (the calls
and read-outs `console/session/acoustic.py` uses) and runs the real one in a
child process started with `multiprocessing`'s spawn.  Two pipes join them:
- commands, console to link: ("call", method, args) answered at once with
  ("ok", result, status), ("refused", text, status) (the machine's
  `OrderRefused`) or ("error", text, status); ("quit",) to end;
- what happened, link to console: ("up", pid), ("rx", packet, [events], now,
  status) for each packet received, ("tx", packet, now, status) for each one
  handed to the modem, ("events", [events], now, status) from the machine's
  clock (and a STOP's cancellations), ("port", up, news, reason), ("fatal",
  text).
Events are the machine's own (link/acoustic/events.py), pickled; `status` is
what the session reads of the machine (when it last heard an authentic frame,
the order on the air, the STOP, when the next STATUS is due, resyncing...).
`now` is the machine's clock: both processes read CLOCK_MONOTONIC
(time.monotonic), so the machine's times are the console's.

Faults, safe and loud:
- The console's process ends or is killed: the child sees its command pipe
  close, presses STOP (flushed first, in every slot, §9.3), waits for the ROV
  to take it (StopTaken, or StopImpossible: no autopilot to hold) at most
  `STOP_AFTER_CONSOLE_S`, then hands the modem nothing more and exits; the ROV
  holds, and its failsafe follows.
- The child ends or is killed: `run` tells the session (`on_down`, at once:
  its event pipe closes), starts it again after `RESTART_AFTER_S` and tells it
  (`on_up`).  The new machine knows nothing of the old one's orders: what the
  session had not seen settled is its to show unknown; a STOP is pressed again.
"""

from __future__ import annotations

import threading
import time
from typing import Any, Callable

from ..process import (
    LinkProcess,
    PortMirror,
    child_entry,
    end_loops,
    serve_until_console_gone,
    until_set,
)
from .operator import AcousticOperator
from .pump import AcousticPump
from .wire import PACKET_BYTES, OrderRefused

# The console gone: STOP is sent until the ROV takes it, this long at most (§9.5: confirmed
# within 5 s at p95 on a clean channel, 12.6 s with 30 % of packets lost), then nothing more.
STOP_AFTER_CONSOLE_S = 15.0

CALLS = ("send_order", "stop", "cancel_stop")


def _status(op: AcousticOperator) -> dict:
    return {
        "last_authentic_at": op.last_authentic_at,
        "sending_oid": op.sending_oid,
        "stop_active": bool(op.stop_active),
        "stop_no": op.stop_no,
        "next_status_at": op.next_status_at,
        "resyncing": bool(op.resyncing),
        "orders_waiting": op.orders_waiting,
        "malformed": int(getattr(op.counters, "malformed", 0)),
    }


IDLE_STATUS = {"last_authentic_at": None, "sending_oid": None, "stop_active": False, "stop_no": 0,
               "next_status_at": None, "resyncing": True, "orders_waiting": 0, "malformed": 0}


# ---------------------------------------------------------------------------
# The child
# ---------------------------------------------------------------------------

def acoustic_child_main(commands, events, spec: dict) -> None:
    """The acoustic link process's entry (multiprocessing's target)."""
    child_entry(_child, commands, events, spec, "acoustic link")


async def _child(commands, send: Callable[[tuple], None], endpoint, spec: dict) -> int:
    from ..transports.transport import port_change, port_down_reason
    from .events import StopImpossible, StopTaken

    op = AcousticOperator(spec["key"])
    lock = threading.Lock()
    stop_settled = threading.Event()  # the ROV took the STOP (or cannot hold): the console gone, the child may end
    port_seen = [None]

    def status() -> dict:
        with lock:
            return _status(op)

    def told(batch: list, now: float) -> None:
        if any(isinstance(e, (StopTaken, StopImpossible)) for e in batch):
            stop_settled.set()
        send(("events", batch, now, status()))

    def received(packet: bytes, batch: list, now: float) -> None:
        if any(isinstance(e, (StopTaken, StopImpossible)) for e in batch):
            stop_settled.set()
        send(("rx", packet, batch, now, status()))

    def port(now: float) -> None:
        port_seen[0], news = port_change(endpoint, port_seen[0])
        if news is not None:
            send(("port", port_seen[0], news, port_down_reason(endpoint)))

    pump = AcousticPump(op, endpoint, lock=lock, clock=time.monotonic, pace_s=float(spec["pace_s"]),
                        on_received=received, on_events=told,
                        on_sent=lambda packet, now: send(("tx", packet, now, status())), before_tick=port)
    tasks = await serve_until_console_gone(commands, send, endpoint, [pump.receiving(), pump.pumping()],
                                           what="acoustic link",
                                           calls=CALLS, machine=op, lock=lock, status=lambda: _status(op),
                                           refused=(OrderRefused,))
    if tasks is None:
        return 3
    # The console is gone: STOP (the pump flushes the modem and sends it in every slot), then silence.
    with lock:
        stop_settled.clear()
        op.stop(time.monotonic())
    print("rovlink acoustic link process: the console is gone; sending STOP, then nothing more", flush=True)
    await until_set(stop_settled, STOP_AFTER_CONSOLE_S, 0.05)
    await end_loops(tasks)
    # Nothing more leaves: a packet still in the modem's queue (a POLL behind the STOP) is dropped.
    flush = getattr(endpoint, "flush", None)
    if flush is not None:
        flush()
    await endpoint.close()
    print("rovlink acoustic link process: STOP " +
          ("taken by the ROV" if stop_settled.is_set() else f"not confirmed within {STOP_AFTER_CONSOLE_S:g} s") +
          "; sending stopped", flush=True)
    return 0


# ---------------------------------------------------------------------------
# The console's side
# ---------------------------------------------------------------------------

class _Counts:
    def __init__(self) -> None:
        self.malformed = 0


class AcousticLinkProcess(LinkProcess):
    """The acoustic operator's machine, run in a process of its own; the session
    calls it as it would the machine (`send_order`, `stop`, `cancel_stop`) and
    reads what it reads of it (`last_authentic_at`, `sending_oid`,
    `stop_active`, `next_status_at`, `resyncing`, `orders_waiting`,
    `counters.malformed`), as of the child's last message."""

    refusal = OrderRefused

    def __init__(self, url: str, key: bytes, *, pace_s: float = 1.0) -> None:
        super().__init__(url, "acoustic link", PortMirror(PACKET_BYTES))
        self.key, self.pace_s = key, pace_s
        self.counters = _Counts()
        self._status: dict = dict(IDLE_STATUS)
        self._malformed_before = 0  # counts of the link processes that ended

    def _child(self) -> tuple[Callable[[Any, Any, dict], None], dict]:
        return acoustic_child_main, {"url": self.url, "key": self.key, "pace_s": self.pace_s}

    # -- what the session reads -------------------------------------------------

    @property
    def last_authentic_at(self) -> float | None:
        return self._status["last_authentic_at"]

    @property
    def sending_oid(self) -> int | None:
        return self._status["sending_oid"]

    @property
    def stop_active(self) -> bool:
        return bool(self._status["stop_active"])

    @property
    def stop_no(self) -> int:
        return int(self._status["stop_no"])

    @property
    def next_status_at(self) -> float | None:
        return self._status["next_status_at"]

    @property
    def resyncing(self) -> bool:
        return bool(self._status["resyncing"])

    @property
    def orders_waiting(self) -> int:
        return int(self._status["orders_waiting"])

    def _take_status(self, status: dict) -> None:
        self._status = status
        self.counters.malformed = self._malformed_before + int(status["malformed"])

    def _carry_counts(self) -> None:
        self._malformed_before = self.counters.malformed
        self._status = dict(IDLE_STATUS)

    # -- what the session orders ------------------------------------------------

    def send_order(self, body, now: float) -> int:
        return int(self._call("send_order", body, now))

    def stop(self, now: float) -> int:
        return int(self._call("stop", now))

    def cancel_stop(self) -> bool:
        return bool(self._call("cancel_stop"))

    # -- running it -------------------------------------------------------------

    async def run(self, *, on_packet: Callable[[bytes, list, float], None],
                  on_sent: Callable[[bytes, float], None],
                  on_events: Callable[[list, float], None],
                  on_turn: Callable[[], None] | None = None,
                  on_up: Callable[[int], None] | None = None,
                  on_down: Callable[[str], None] | None = None) -> None:
        """Run the link process, start it again whenever it ends, until cancelled
        (then it is told to end: it sends STOP first; `close` waits for it).
        Times given to the callbacks are the machine's clock (time.monotonic)."""

        def take(message: tuple) -> None:
            kind = message[0]
            if kind == "rx":
                _, packet, batch, now, status = message
                self._take_status(status)
                on_packet(packet, batch, now)
            elif kind == "tx":
                _, packet, now, status = message
                self._take_status(status)
                on_sent(packet, now)
            elif kind == "events":
                _, batch, now, status = message
                self._take_status(status)
                on_events(batch, now)

        def turn() -> None:
            if on_turn is not None:
                on_turn()

        def up(pid: int) -> None:
            self.port.is_up = True
            if on_up is not None:
                on_up(pid)

        def down(why: str) -> None:
            if on_down is not None:
                on_down(why)

        try:
            await self._supervise(take, turn=turn, up=up, down=down)
        finally:
            self._tell_to_end()

    def close(self, timeout_s: float = STOP_AFTER_CONSOLE_S + 5.0) -> None:
        """End the link process as the console ends and wait for it: its STOP first
        (blocking: call it off the event loop)."""
        self._end(timeout_s)
