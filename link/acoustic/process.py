"""The acoustic link in a process of its own (issue 33): the operator's machine
(`AcousticOperator`), the modem endpoint, the pacing (a packet whenever the
modem's queue is empty, flushed for a STOP) and the machine's clock, apart
from the console's page, scene, gateway and thumbnail decoding.

Goal: as the radio link's (link/process.py, whose pieces this reuses): a
packet goes to the modem when its queue empties, whatever the console's
process is doing, and a fault on either side is safe and loud.

Plan: `AcousticLinkProcess` stands in the console for the machine (the calls
and read-outs `console/acoustic/session.py` uses) and runs the real one in a
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

import asyncio
import logging
import math
import multiprocessing
import os
import signal
import threading
import time
from typing import Callable

from ..process import CALL_TIMEOUT_S, RESTART_AFTER_S, TURN_S, LinkProcessDown, PortMirror, raise_priority
from .operator import AcousticOperator, modem_idle
from .wire import PACKET_BYTES, OrderRefused

log = logging.getLogger("rovlink.link.acoustic.process")

# The console gone: STOP is sent until the ROV takes it, this long at most (§9.5: confirmed
# within 5 s at p95 on a clean channel, 12.6 s with 30 % of packets lost), then nothing more.
STOP_AFTER_CONSOLE_S = 15.0
PUMP_S = 0.1  # how often the modem's queue is looked at (a packet a second at the most)

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
    logging.basicConfig(level=logging.WARNING, format="rovlink acoustic link process: %(message)s")
    # Ctrl-C in the console's terminal reaches this process too: the console's end (its
    # pipe closing) is what ends it, with a STOP first.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise_priority()
    try:
        code = asyncio.run(_child(commands, events, spec))
    except KeyboardInterrupt:
        code = 0
    os._exit(code)


async def _child(commands, events, spec: dict) -> int:
    from ..aio import recv_within
    from ..transports.transport import TransportError, port_change, port_down_reason
    from ..transports.urls import open_transport
    from .events import StopImpossible, StopTaken

    loop = asyncio.get_running_loop()
    send_lock = threading.Lock()
    parent_gone = asyncio.Event()

    def send(message: tuple) -> None:
        try:
            with send_lock:
                events.send(message)
        except (OSError, EOFError, ValueError):  # the console is gone: its pipe says so to the command thread
            pass

    try:
        endpoint = open_transport(spec["url"])
        await endpoint.start()
    except (TransportError, OSError, ValueError) as exc:
        send(("fatal", f"could not open {spec['url']}: {exc}"))
        return 2
    op = AcousticOperator(spec["key"])
    lock = threading.Lock()
    stop_settled = threading.Event()  # the ROV took the STOP (or cannot hold): the console gone, the child may end
    pace_s = float(spec["pace_s"])

    def told(batch: list, now: float, kind: str = "events", packet: bytes | None = None) -> None:
        if any(isinstance(e, (StopTaken, StopImpossible)) for e in batch):
            stop_settled.set()
        with lock:
            status = _status(op)
        if kind == "rx":
            send(("rx", packet, batch, now, status))
        elif batch:
            send(("events", batch, now, status))

    async def receiving() -> None:
        while True:
            data = await recv_within(endpoint, 0.1)
            if not data:
                continue
            now = time.monotonic()
            for i in range(0, len(data) - PACKET_BYTES + 1, PACKET_BYTES):
                packet = bytes(data[i:i + PACKET_BYTES])
                with lock:
                    batch = op.receive(packet, now)
                told(batch, now, "rx", packet)

    async def pumping() -> None:
        last_sent = -math.inf
        port_seen = None
        while True:
            now = time.monotonic()
            port_seen, news = port_change(endpoint, port_seen)
            if news is not None:
                send(("port", port_seen, news, port_down_reason(endpoint)))
            with lock:
                batch = op.tick(now)
                if op.wants_flush:
                    flush = getattr(endpoint, "flush", None)
                    if flush is not None:
                        flush()
                ready = op.wants_flush or modem_idle(endpoint, now, last_sent, pace_s)
                packet = op.next_packet(now) if ready else None
                status = _status(op)
            told(batch, now)
            if packet is not None:
                endpoint.send(packet)
                last_sent = now
                send(("tx", packet, now, status))
            await asyncio.sleep(PUMP_S)

    def serve_commands() -> None:
        while True:
            try:
                message = commands.recv()
            except (EOFError, OSError):
                break
            if message[0] == "quit":
                break
            _, name, args = message
            try:
                if name not in CALLS:
                    raise ValueError(f"{name} is not a call of the acoustic link process")
                with lock:
                    result = getattr(op, name)(*args)
                    status = _status(op)
                answer = ("ok", result, status)
            except OrderRefused as exc:  # the machine's own refusal, said in its words
                with lock:
                    status = _status(op)
                answer = ("refused", str(exc), status)
            except Exception as exc:  # said to the caller, whose order it was
                with lock:
                    status = _status(op)
                answer = ("error", f"{type(exc).__name__}: {exc}", status)
            try:
                commands.send(answer)
            except (OSError, EOFError):
                break
        loop.call_soon_threadsafe(parent_gone.set)

    threading.Thread(target=serve_commands, name="acoustic link commands", daemon=True).start()
    send(("up", os.getpid()))
    tasks = {loop.create_task(receiving()), loop.create_task(pumping())}
    gone = loop.create_task(parent_gone.wait())
    done, _ = await asyncio.wait(tasks | {gone}, return_when=asyncio.FIRST_COMPLETED)
    failed = next((t for t in done if t in tasks), None)
    if failed is not None:  # a loop itself failed: said, and the console starts a new one
        send(("fatal", f"the acoustic link loop stopped: {failed.exception()!r}"))
        for task in tasks | {gone}:
            task.cancel()
        await endpoint.close()
        return 3
    # The console is gone: STOP (the pump flushes the modem and sends it in every slot), then silence.
    with lock:
        stop_settled.clear()
        op.stop(time.monotonic())
    print("rovlink acoustic link process: the console is gone; sending STOP, then nothing more", flush=True)
    deadline = time.monotonic() + STOP_AFTER_CONSOLE_S
    while not stop_settled.is_set() and time.monotonic() < deadline:
        await asyncio.sleep(0.05)
    for task in tasks:
        task.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
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


class AcousticLinkProcess:
    """The acoustic operator's machine, run in a process of its own; the session
    calls it as it would the machine (`send_order`, `stop`, `cancel_stop`) and
    reads what it reads of it (`last_authentic_at`, `sending_oid`,
    `stop_active`, `next_status_at`, `resyncing`, `orders_waiting`,
    `counters.malformed`), as of the child's last message."""

    def __init__(self, url: str, key: bytes, *, pace_s: float = 1.0) -> None:
        self.url, self.key, self.pace_s = url, key, pace_s
        self.port = PortMirror(PACKET_BYTES)
        self.counters = _Counts()
        self._status: dict = dict(IDLE_STATUS)
        self._malformed_before = 0  # counts of the link processes that ended
        self._call_lock = threading.Lock()
        self._process = None
        self._commands = None
        self._events = None
        self.pid: int | None = None
        self.up = False
        self.ever_up = False
        self.down_reason: str | None = None  # why it ended, until it runs again
        self.last_exit: str | None = None

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

    # -- what the session orders ------------------------------------------------

    def _call(self, name: str, *args):
        with self._call_lock:
            if not self.up or self._commands is None:
                raise LinkProcessDown("the acoustic link process is not running (it is being started again)")
            try:
                self._commands.send(("call", name, args))
                if not self._commands.poll(CALL_TIMEOUT_S):
                    raise LinkProcessDown(f"the acoustic link process did not answer {name} within "
                                          f"{CALL_TIMEOUT_S:g} s")
                kind, result, status = self._commands.recv()
            except (OSError, EOFError) as exc:
                raise LinkProcessDown(f"the acoustic link process is gone ({exc or type(exc).__name__})") from None
        self._take_status(status)
        if kind == "refused":
            raise OrderRefused(result)
        if kind == "error":
            raise ValueError(result)
        return result

    def send_order(self, body, now: float) -> int:
        return int(self._call("send_order", body, now))

    def stop(self, now: float) -> int:
        return int(self._call("stop", now))

    def cancel_stop(self) -> bool:
        return bool(self._call("cancel_stop"))

    # -- running it -------------------------------------------------------------

    def _spawn(self) -> None:
        ctx = multiprocessing.get_context("spawn")
        commands, child_commands = ctx.Pipe(duplex=True)
        child_events, events = ctx.Pipe(duplex=False)
        spec = {"url": self.url, "key": self.key, "pace_s": self.pace_s}
        process = ctx.Process(target=acoustic_child_main, args=(child_commands, events, spec),
                              name="rovlink-acoustic-link", daemon=False)
        process.start()
        child_commands.close()
        events.close()
        self._process, self._commands, self._events = process, commands, child_events

    async def run(self, *, on_packet: Callable[[bytes, list, float], None],
                  on_sent: Callable[[bytes, float], None],
                  on_events: Callable[[list, float], None],
                  on_turn: Callable[[], None] | None = None,
                  on_up: Callable[[int], None] | None = None,
                  on_down: Callable[[str], None] | None = None) -> None:
        """Run the link process, start it again whenever it ends, until cancelled
        (then it is told to end: it sends STOP first; `close` waits for it).
        Times given to the callbacks are the machine's clock (time.monotonic)."""
        loop = asyncio.get_running_loop()
        try:
            while True:
                self._spawn()
                ended = loop.create_future()

                def readable(ended=ended) -> None:
                    try:
                        while self._events.poll():
                            self._dispatch(self._events.recv(), on_packet, on_sent, on_events, on_up)
                    except (EOFError, OSError):
                        if not ended.done():
                            ended.set_result(None)

                loop.add_reader(self._events.fileno(), readable)
                try:
                    while not ended.done():
                        if on_turn is not None:
                            on_turn()
                        await asyncio.wait({ended}, timeout=TURN_S)
                finally:
                    loop.remove_reader(self._events.fileno())
                # Its end (a pipe closing) is said with its exit code: joined first (at once for a
                # process that ended), then "down" and why are set together.
                await loop.run_in_executor(None, self._process.join, 5.0)
                code = self._process.exitcode
                why = self.last_exit or (f"it ended with exit code {code}" if code is not None and code >= 0
                                         else f"it was killed (signal {-code})" if code is not None
                                         else "its pipe closed")
                was_up = self.up
                self.last_exit = None
                self.down_reason = why if was_up or self.ever_up else f"it could not start: {why}"
                self.up = False
                self._malformed_before = self.counters.malformed
                self._status = dict(IDLE_STATUS)
                self._close_pipes()
                if on_down is not None:
                    on_down(self.down_reason)
                await asyncio.sleep(RESTART_AFTER_S if was_up else max(RESTART_AFTER_S, 1.0))
        finally:
            self._tell_to_end()

    def _dispatch(self, message: tuple, on_packet, on_sent, on_events, on_up) -> None:
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
        elif kind == "port":
            _, up, _news, reason = message
            self.port.is_up = bool(up)
            self.port.stats.last_error = reason
        elif kind == "up":
            self.pid = message[1]
            self.up = self.ever_up = True
            self.down_reason = None
            self.port.is_up = True
            if on_up is not None:
                on_up(self.pid)
        elif kind == "fatal":
            self.last_exit = message[1]

    def _close_pipes(self) -> None:
        for conn in (self._commands, self._events):
            if conn is not None:
                conn.close()
        self._commands = self._events = None

    def _tell_to_end(self) -> None:
        """The console ends: the link process is told (it sends STOP, then nothing more)."""
        self.up = False
        with self._call_lock:
            if self._commands is not None:
                try:
                    self._commands.send(("quit",))
                except (OSError, EOFError):
                    pass

    def close(self, timeout_s: float = STOP_AFTER_CONSOLE_S + 5.0) -> None:
        """End the link process as the console ends and wait for it: its STOP first
        (blocking: call it off the event loop)."""
        self._tell_to_end()
        process = self._process
        if process is not None and process.is_alive():
            process.join(timeout_s)
            if process.is_alive():
                process.kill()
                process.join(2)
        self._close_pipes()
        self._process = None

    @property
    def link_process_state(self) -> dict:
        """The link state's `link_process` fields (console/session/state.py LinkState)."""
        up, reason = self.up, self.down_reason  # (read once: the loop sets them)
        if not up and not self.ever_up and reason is None:
            return {"link_process": "starting", "link_process_reason": None, "link_process_pid": None}
        return {"link_process": "up" if up else "down", "link_process_reason": None if up else reason,
                "link_process_pid": self.pid if up else None}
