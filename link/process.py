"""A link in a process of its own (issue 33): what both profiles' link processes
share (`LinkProcess`, the console's side; the child's entry, pipe, endpoint and
command thread), and the radio link's own: the transport, the master and its
clock and deadlines, apart from the console's page, scene, gateway and picture
decoding.  The acoustic profile's stands on the same (link/acoustic/process.py).

Goal: a poll leaves on time whatever the console's process is doing.  The
console's threads share one interpreter lock; a busy page, a software-rendered
scene or a decode there made replies go late (§8.1 counts a reply late 50 ms
past its deadline).  Here the link's loop has a process, an interpreter and
a scheduler's share of its own.

Plan: `MasterProcess` stands in the console for the master (the methods and
read-outs the session uses) and runs the real one in a child process started
with `multiprocessing`'s spawn.  Two pipes join them:
- commands, console to link: ("call", seq, method, args) answered at once with
  ("ok", seq, result, status) or ("error", seq, text, status); ("quit",) to end.
  `seq` numbers the calls: an answer that comes after its call gave up waiting
  (`CALL_TIMEOUT_S`) is told apart from the next call's and handed to whoever
  made the call (`LinkProcessSlow`), never read as another call's;
- what happened, link to console: ("up", pid), ("events", [master events],
  t, status), ("rx", bytes, t), ("reply", payload, sync, t) (version 2: the
  reply the master was given, for the recording), ("port", up, news, reason),
  ("fatal", text).
Messages are the link's own typed events (link/radio/events.py), pickled;
`status` is the master's read-outs (stats, STOP state, estimated BER, bad
CRCs...), a small dict sent with every batch and every answer.

Both processes keep session time on one clock: the child gets the console's
CLOCK_MONOTONIC origin, so times in its events are the console's.

Faults, safe and loud:
- The console's process ends or is killed: the child sees its command pipe
  close, sends STOP (neutral velocity, every poll until a reply confirms it,
  at most `STOP_AFTER_PARENT_S`), then stops polling and exits, so the ROV
  holds in its failsafe.  A console started again never releases that HOLD on
  its own (§5, decided: nobody's neutral releases none).
- The child ends or is killed: `run` tells the session (`on_down`, at once:
  its event pipe closes), starts it again after `RESTART_AFTER_S` and tells
  it (`on_up`).  What the dead master held (orders in flight, a picture half
  in) is the session's to settle: nothing it had is shown done.
"""

from __future__ import annotations

import asyncio
import dataclasses
import itertools
import logging
import multiprocessing
import os
import signal
import threading
import time
from typing import Any, Callable, Coroutine

from .radio.frame import MAX_FRAME
from .radio.master import Master, MasterStats, StopConfirmed
from .radio.messages import Stop
from .radio.secure import SecureMaster

log = logging.getLogger("rovlink.link.process")

STOP_AFTER_PARENT_S = 5.0   # the console gone: STOP is sent this long at most, then polling stops
RESTART_AFTER_S = 0.5       # a link process that ended is started again after this
CALL_TIMEOUT_S = 2.0        # a command the link process has not answered in this time failed
READ_SLICE_S = 0.02         # the link process's messages taken at most this long before the loop's other work
TURN_S = 0.05               # the session's own timers (`on_turn`) while the link process runs

# What the master's methods the session calls may be (the rest are refused).
CALLS = ("set_velocity", "set_pilot_in_force", "set_attended", "recentred", "request_arm", "request_mode",
         "send_order", "cancel_stop", "abandon_image")


LINK_NICE = -10            # the link process's priority where the system allows it (CAP_SYS_NICE, root)
LINK_RT_PRIORITY = 1       # and its real-time priority (SCHED_RR's lowest) where the system allows that


def raise_priority(nice: int = LINK_NICE) -> str:
    """Ask for a scheduling priority above the machine's other work, and say what it got.

    A poll's deadline is tens of milliseconds, and a CPU-bound process beside the link
    takes whole time slices: at nice -10 a loaded core still answered 2 or 3 polls in 256
    late (issue 39; 0 in 249 under SCHED_RR).  So real-time round-robin at its lowest
    priority, before any thread starts (they inherit it).  Safe because the link's work is
    bounded: a poll at most every CONSOLE_POLL_FLOOR_S, a wait on the link between (and the
    kernel keeps 5 % of each core for the rest).  Refused (no CAP_SYS_NICE, no RLIMIT_RTPRIO,
    a container without real-time time): nice -10; refused too, said once, and it runs at
    the console's priority."""
    try:
        os.setpriority(os.PRIO_PROCESS, 0, nice)
    except (PermissionError, OSError) as exc:
        log.warning("could not raise the link process's priority to nice %d (%s): it runs at the console's; "
                    "a busy machine may delay its polls", nice, exc)
    try:
        os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(LINK_RT_PRIORITY))
    except (PermissionError, OSError) as exc:
        got = f"nice {os.getpriority(os.PRIO_PROCESS, 0)}"
        log.warning("no real-time priority for the link process (%s): it runs at %s; a busy machine may delay "
                    "its polls", exc.strerror or exc, got)
        return got
    return f"real-time (round-robin, priority {LINK_RT_PRIORITY})"


class LinkProcessDown(RuntimeError):
    """The link process is not running (it ended and is being started again)."""


class LinkProcessSlow(LinkProcessDown):
    """The link process runs but did not answer a call within `CALL_TIMEOUT_S`: the
    call was handed to it and may yet be made there (a busy machine).  Its caller
    says what then with `when_answered`.  Never a refusal: an order it carried may
    reach the ROV."""

    def __init__(self, text: str, pending: "_PendingCall") -> None:
        super().__init__(text)
        self._pending = pending

    def when_answered(self, on_result: Callable[[Any], None], on_refused: Callable[[str], None],
                      on_lost: Callable[[str], None]) -> None:
        """`on_result(result)` when the answer comes; `on_refused(text)` if the call was
        refused or failed there; `on_lost(why)` if no answer will come (the process
        ended first).  Called on the thread that reads the answer, with no lock held."""
        self._pending.attach(on_result, on_refused, on_lost)


class _PendingCall:
    """A call its caller stopped waiting for: its answer (or its loss), whenever
    it comes, and the caller's callbacks, whichever is first."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._lock = threading.Lock()
        self._outcome: tuple | None = None  # ("ok", result) / ("refused" or "error", text) / ("lost", why)
        self._callbacks: tuple | None = None

    def attach(self, *callbacks: Callable) -> None:
        with self._lock:
            outcome, self._callbacks = self._outcome, callbacks
        if outcome is not None:
            self._tell(outcome)

    def settle(self, outcome: tuple) -> None:
        """Its answer came (or none will)."""
        with self._lock:
            if self._outcome is not None:
                return
            self._outcome = outcome
            callbacks = self._callbacks
        if callbacks is not None:
            self._tell(outcome)
        elif outcome[0] in ("refused", "error"):  # a setting nobody waited for: said, at least
            log.warning("the link process could not take %s: %s", self.name, outcome[1])

    def _tell(self, outcome: tuple) -> None:
        on_result, on_refused, on_lost = self._callbacks
        kind, value = outcome
        try:
            {"ok": on_result, "lost": on_lost}.get(kind, on_refused)(value)
        except Exception:  # a caller's callback must not stop the link's reading
            log.exception("the late answer to %s could not be taken", self.name)


# ---------------------------------------------------------------------------
# The child, either profile's: its entry, its pipe, its endpoint, its commands
# (`what` names the process in what it says: "link", "acoustic link")
# ---------------------------------------------------------------------------

_ChildRun = Callable[[Any, Callable[[tuple], None], Any, dict], Coroutine[Any, Any, int]]


def child_entry(child: _ChildRun, commands, events, spec: dict, what: str) -> None:
    """A link process's life: its endpoint opened (`spec["url"]`), then `child(commands,
    send, endpoint, spec)` run to its exit code, then the process ends."""
    logging.basicConfig(level=logging.WARNING, format=f"rovlink {what} process: %(message)s")
    # Ctrl-C in the console's terminal reaches this process too: the console's end (its
    # pipe closing) is what ends it, with a STOP first.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise_priority()
    try:
        code = asyncio.run(_child_life(child, commands, events, spec))
    except KeyboardInterrupt:  # the console's Ctrl-C reaches its whole group; the pipe's end says the rest
        code = 0
    os._exit(code)


async def _child_life(child: _ChildRun, commands, events, spec: dict) -> int:
    send = _pipe_sender(events)
    endpoint = await _open_endpoint(spec["url"], send)
    if endpoint is None:
        return 2
    return await child(commands, send, endpoint, spec)


def _pipe_sender(events) -> Callable[[tuple], None]:
    """What the child tells the console, from any of its threads."""
    send_lock = threading.Lock()

    def send(message: tuple) -> None:
        try:
            with send_lock:
                events.send(message)
        except (OSError, EOFError, ValueError):  # the console is gone: its pipe says so to the command thread
            pass

    return send


async def _open_endpoint(url: str, send: Callable[[tuple], None]):
    """The link's transport, started; None (and "fatal", why) where it cannot open."""
    from .transports.transport import TransportError
    from .transports.urls import open_transport

    try:
        endpoint = open_transport(url)
        await endpoint.start()
    except (TransportError, OSError, ValueError) as exc:
        send(("fatal", f"could not open {url}: {exc}"))
        return None
    return endpoint


def _serve_calls(commands, *, what: str, calls: tuple[str, ...], machine, lock: threading.Lock,
                status: Callable[[], dict], gone: Callable[[], None],
                refused: tuple[type[Exception], ...] = ()) -> None:
    """The command thread: each call of `calls` made on `machine` and answered with its
    status; a `refused` exception is the machine's own refusal, answered in its words.
    The console's pipe closing (or "quit") ends it, and `gone` is told."""
    while True:
        try:
            message = commands.recv()
        except (EOFError, OSError):
            break
        if message[0] == "quit":
            break
        _, seq, name, args = message
        try:
            if name not in calls:
                raise ValueError(f"{name} is not a call of the {what} process")
            with lock:
                result = getattr(machine, name)(*args)
                now_status = status()
            answer = ("ok", seq, result, now_status)
        except Exception as exc:  # said to the caller, whose order it was
            with lock:
                now_status = status()
            answer = (("refused", seq, str(exc), now_status) if isinstance(exc, refused)
                      else ("error", seq, f"{type(exc).__name__}: {exc}", now_status))
        try:
            commands.send(answer)
        except (OSError, EOFError):
            break
    gone()


async def serve_until_console_gone(commands, send: Callable[[tuple], None], endpoint, loops: list[Coroutine],
                                   *, what: str, **serving: Any) -> set[asyncio.Task] | None:
    """The child up: its command thread (`_serve_calls` with `serving`), "up" said, its
    `loops` run until the console is gone.  Returns the loops, still running, for the
    child's STOP; None where one of them failed (said "fatal", the endpoint closed)."""
    loop = asyncio.get_running_loop()
    parent_gone = asyncio.Event()
    threading.Thread(target=_serve_calls, args=(commands,),
                     kwargs={"what": what, "gone": lambda: loop.call_soon_threadsafe(parent_gone.set), **serving},
                     name=f"{what} commands", daemon=True).start()
    send(("up", os.getpid()))
    tasks = {loop.create_task(c) for c in loops}
    gone = loop.create_task(parent_gone.wait())
    done, _ = await asyncio.wait(tasks | {gone}, return_when=asyncio.FIRST_COMPLETED)
    failed = next((t for t in done if t in tasks), None)
    if failed is not None:  # a loop itself failed: said, and the console starts a new one
        send(("fatal", f"the {what} loop stopped: {failed.exception()!r}"))
        for task in tasks | {gone}:
            task.cancel()
        await endpoint.close()
        return None
    return tasks


async def until_set(event: threading.Event, within_s: float, step_s: float) -> None:
    """Wait for `event` (a STOP settled) at most `within_s`, looking every `step_s`."""
    deadline = time.monotonic() + within_s
    while not event.is_set() and time.monotonic() < deadline:
        await asyncio.sleep(step_s)


async def end_loops(tasks: set[asyncio.Task]) -> None:
    for task in tasks:
        task.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)


# ---------------------------------------------------------------------------
# The radio's child
# ---------------------------------------------------------------------------

def _status(master) -> dict:
    return {
        "stats": dataclasses.asdict(master.stats),
        "stopping": bool(master.stopping),
        "ber": master.estimated_ber(),
        "crc_errors": master.decoder.crc_errors,
        "image_received": _protocol(master).image_received,
        "pilot_in_force": _protocol(master).pilot_in_force,
    }


def _protocol(master):
    return master.master if isinstance(master, SecureMaster) else master


def child_main(commands, events, spec: dict) -> None:
    """The link process's entry (multiprocessing's target)."""
    child_entry(_child, commands, events, spec, "link")


async def _child(commands, send: Callable[[tuple], None], endpoint, spec: dict) -> int:
    from .aio import CONSOLE_POLL_FLOOR_S, run_master
    from .transports.transport import port_change, port_down_reason

    t0 = spec["t0"]

    def clock() -> float:
        return time.monotonic() - t0

    master: Any = Master(bitrate_bps=spec["bitrate_bps"], delay_s=spec["delay_s"],
                         max_frame=(endpoint.max_frame or MAX_FRAME))
    master.set_pilot_in_force(False)
    if spec.get("key") is not None:
        master = SecureMaster(master, spec["key"])
    # The replies the master was given, kept under its lock and sent after it: the pipe
    # blocks while the console has not read it, and a loop waiting there with the lock
    # held kept the console's calls waiting too (2 s, then "the link process did not
    # answer": a STOP then waited for a restart that never came, shown queued).
    replies: list[tuple] = []
    if spec.get("key") is not None:
        master.on_reply = lambda payload, sync, now: replies.append(("reply", payload, sync, now))
    lock = threading.Lock()
    confirmed = threading.Event()  # a STOP confirmed (after the console went: the child may end)

    def send_replies() -> None:
        with lock:
            kept = replies[:]
            replies.clear()
        for message in kept:
            send(message)

    def on_events(batch: list, t: float) -> None:
        if any(isinstance(e, StopConfirmed) for e in batch):
            confirmed.set()
        send_replies()  # before the events they led to, as before
        with lock:
            status = _status(master)
        send(("events", batch, t, status))

    port_seen: list = [None]

    def on_turn(t: float) -> None:
        send_replies()
        port_seen[0], news = port_change(endpoint, port_seen[0])
        if news is not None:
            send(("port", port_seen[0], news, port_down_reason(endpoint)))

    runner = run_master(master, endpoint, on_events, clock=clock, lock=lock,
                        on_bytes=lambda data, t: send(("rx", data, t)), on_turn=on_turn,
                        poll_floor_s=CONSOLE_POLL_FLOOR_S)
    tasks = await serve_until_console_gone(commands, send, endpoint, [runner], what="link", calls=CALLS,
                                           machine=master, lock=lock, status=lambda: _status(master))
    if tasks is None:
        return 3
    # The console is gone: STOP, then silence (the ROV's failsafe holds it).
    with lock:
        confirmed.clear()
        now = clock()
        master.set_velocity(0, 0, 0, 0, now)
        master.set_pilot_in_force(False)
        if not master.stopping:
            master.send_order(Stop())
    print("rovlink link process: the console is gone; sending STOP, then no more polls", flush=True)
    await until_set(confirmed, STOP_AFTER_PARENT_S, 0.02)
    await end_loops(tasks)
    await endpoint.close()
    print("rovlink link process: STOP " + ("confirmed" if confirmed.is_set() else "not confirmed") +
          "; polling stopped", flush=True)
    return 0


# ---------------------------------------------------------------------------
# The console's side
# ---------------------------------------------------------------------------

class PortMirror:
    """The link process's transport as the console sees it: up or down, and why."""

    def __init__(self, max_frame: int | None) -> None:
        self.max_frame = max_frame
        self.is_up = True
        self.stats = type("PortStats", (), {"last_error": None})()


class LinkProcess:
    """A link process as the console runs it, either profile's: started (spawn), its
    calls answered over one pipe and its messages read from another, watched, and
    started again whenever it ends.  A profile says what its child is and is given
    (`_child`), what it reads of a status (`_take_status`), what the counts of one
    that ended carry (`_carry_counts`), and takes its own messages."""

    refusal: type[Exception] = ValueError  # raised for a call the machine refused ("refused")
    # The process's end said at once (calls refused meanwhile), before it is joined;
    # or joined first (at once for a process that ended), then "down" and why set together.
    down_before_join = False

    def __init__(self, url: str, what: str, port: PortMirror) -> None:
        self.url = url
        self.what = what  # its name in what is said of it: "link", "acoustic link"
        self.port = port
        self._call_lock = threading.Lock()
        self._seq = itertools.count(1)
        self._late: dict[int, _PendingCall] = {}  # calls that gave up waiting, by seq, until answered
        self._process = None
        self._commands = None
        self._events = None
        self.pid: int | None = None
        self.up = False
        self.ever_up = False
        self.down_reason: str | None = None  # why it ended, until it runs again
        self.last_exit: str | None = None

    # -- what a profile says ----------------------------------------------------

    def _child(self) -> tuple[Callable[[Any, Any, dict], None], dict]:
        """The child's entry (multiprocessing's target) and what it is given."""
        raise NotImplementedError

    def _take_status(self, status: dict) -> None:
        raise NotImplementedError

    def _carry_counts(self) -> None:
        """It ended: its counts kept for the next one's, its status as none's."""
        raise NotImplementedError

    # -- what the session reads -------------------------------------------------

    @property
    def link_process_state(self) -> dict:
        """The link state's `link_process` fields (console/session/state.py LinkState)."""
        up, reason = self.up, self.down_reason  # (read once: the loop sets them)
        if not up and not self.ever_up and reason is None:
            return {"link_process": "starting", "link_process_reason": None, "link_process_pid": None}
        return {"link_process": "up" if up else "down", "link_process_reason": None if up else reason,
                "link_process_pid": self.pid if up else None}

    # -- its calls --------------------------------------------------------------

    def _call(self, name: str, *args):
        late: list[tuple] = []
        try:
            with self._call_lock:
                if not self.up or self._commands is None:
                    raise LinkProcessDown(f"the {self.what} process is not running (it is being started again)")
                seq = next(self._seq)
                deadline = time.monotonic() + CALL_TIMEOUT_S
                try:
                    self._commands.send(("call", seq, name, args))
                    while True:
                        remaining = deadline - time.monotonic()
                        if remaining <= 0 or not self._commands.poll(remaining):
                            pending = self._late[seq] = _PendingCall(name)
                            raise LinkProcessSlow(f"the {self.what} process did not answer {name} within "
                                                  f"{CALL_TIMEOUT_S:g} s (a busy machine?); it may yet do it",
                                                  pending)
                        kind, answered, result, status = self._commands.recv()
                        self._take_status(status)
                        if answered == seq:
                            break
                        late.append((self._late.pop(answered, None), kind, result))
                except (OSError, EOFError) as exc:
                    raise LinkProcessDown(f"the {self.what} process is gone ({exc or type(exc).__name__})") from None
        finally:
            self._settle_late(late)
        if kind == "refused":
            raise self.refusal(result)
        if kind == "error":
            raise ValueError(result)
        return result

    def _cast(self, name: str, *args) -> None:
        """A call nobody waits for (a setting, the pilot's wish): handed over in its turn
        among the calls, its answer read later (its status taken, a failure logged).
        A caller holding a lock of its own is then never held up by a busy machine."""
        with self._call_lock:
            if not self.up or self._commands is None:
                raise LinkProcessDown(f"the {self.what} process is not running (it is being started again)")
            seq = next(self._seq)
            self._late[seq] = _PendingCall(name)
            try:
                self._commands.send(("call", seq, name, args))
            except (OSError, EOFError) as exc:
                self._late.pop(seq, None)
                raise LinkProcessDown(f"the {self.what} process is gone ({exc or type(exc).__name__})") from None

    def _read_late_answers(self) -> None:
        """Answers to calls that gave up waiting, read when no call is waiting (each turn)."""
        if not self._late or not self._call_lock.acquire(blocking=False):
            return
        late: list[tuple] = []
        try:
            while self._commands is not None and self._commands.poll(0):
                kind, answered, result, status = self._commands.recv()
                self._take_status(status)
                late.append((self._late.pop(answered, None), kind, result))
        except (OSError, EOFError):
            pass  # the process is ending: its supervisor says so, and loses what is left
        finally:
            self._call_lock.release()
            self._settle_late(late)

    @staticmethod
    def _settle_late(late: list[tuple]) -> None:
        for pending, kind, result in late:
            if pending is not None:
                pending.settle(("ok", result) if kind == "ok" else (kind, str(result)))

    def _lose_late(self, why: str) -> None:
        """The process ended: the calls it never answered never will be."""
        with self._call_lock:
            lost, self._late = list(self._late.values()), {}
        for pending in lost:
            pending.settle(("lost", why))

    # -- running it -------------------------------------------------------------

    def _spawn(self) -> None:
        ctx = multiprocessing.get_context("spawn")
        commands, child_commands = ctx.Pipe(duplex=True)
        child_events, events = ctx.Pipe(duplex=False)
        target, spec = self._child()
        process = ctx.Process(target=target, args=(child_commands, events, spec),
                              name="rovlink-" + self.what.replace(" ", "-"), daemon=False)
        process.start()
        child_commands.close()
        events.close()
        self._process, self._commands, self._events = process, commands, child_events

    async def _supervise(self, take: Callable[[tuple], None], *, turn: Callable[[], None],
                         up: Callable[[int], None], down: Callable[[str], None]) -> None:
        """Run the link process, start it again whenever it ends, until cancelled: its
        messages of every profile taken here, the rest by `take`; `turn` every `TURN_S`
        while it runs; `up` once it is up (its pid), `down` once it ended (why)."""
        loop = asyncio.get_running_loop()
        while True:
            self._spawn()
            ended = loop.create_future()

            def readable(ended=ended) -> None:
                # A slice at a time: a link process whose messages come faster than they
                # are taken (a fast link, a loaded console) must not keep the loop here,
                # or the session's timers and the answers to its calls wait; unread
                # answers then fill their pipe and the child's command thread, blocked on
                # it, takes no more wishes (seen: a stick not taken for 20 s).
                until = time.monotonic() + READ_SLICE_S
                try:
                    while self._events.poll():
                        self._dispatch(self._events.recv(), take, up)
                        if time.monotonic() >= until:
                            break
                except (EOFError, OSError):
                    if not ended.done():
                        ended.set_result(None)

            loop.add_reader(self._events.fileno(), readable)
            try:
                while not ended.done():
                    self._read_late_answers()
                    turn()
                    await asyncio.wait({ended}, timeout=TURN_S)
            finally:
                loop.remove_reader(self._events.fileno())
            was_up = self.up
            if self.down_before_join:
                self.down_reason = "it ended; why is being read"  # never "down" without a word, while joined
                self.up = False
                self._carry_counts()
            await loop.run_in_executor(None, self._process.join, 5.0)
            code = self._process.exitcode
            why = self.last_exit or (f"it ended with exit code {code}" if code is not None and code >= 0
                                     else f"it was killed (signal {-code})" if code is not None
                                     else "its pipe closed")
            self.last_exit = None
            self.down_reason = why if was_up or self.ever_up else f"it could not start: {why}"
            if not self.down_before_join:
                self.up = False
                self._carry_counts()
            self._close_pipes()
            self._lose_late(f"the {self.what} process ended before it answered")
            down(self.down_reason)
            await asyncio.sleep(RESTART_AFTER_S if was_up else max(RESTART_AFTER_S, 1.0))

    def _dispatch(self, message: tuple, take: Callable[[tuple], None], up: Callable[[int], None]) -> None:
        kind = message[0]
        if kind == "port":
            _, is_up, _news, reason = message
            self.port.is_up = bool(is_up)
            self.port.stats.last_error = reason
        elif kind == "up":
            self.pid = message[1]
            self.up = self.ever_up = True
            self.down_reason = None
            up(self.pid)
        elif kind == "fatal":
            self.last_exit = message[1]
        else:
            take(message)

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

    def _end(self, timeout_s: float) -> None:
        """Told to end, and waited for (its STOP first), killed past `timeout_s`."""
        self._tell_to_end()
        process = self._process
        if process is not None and process.is_alive():
            process.join(timeout_s)
            if process.is_alive():
                process.kill()
                process.join(2)
        self._close_pipes()
        self._process = None


class _Decoder:
    def __init__(self) -> None:
        self.crc_errors = 0


class MasterProcess(LinkProcess):
    """The master, run in a process of its own; the session calls it as it would
    the master (the calls of `CALLS`, `stopping`, `stats`, `estimated_ber()`,
    `decoder.crc_errors`, `image_received`, `trunk_bytes`)."""

    down_before_join = True

    def __init__(self, url: str, *, bitrate_bps: float, delay_s: float, max_frame: int | None,
                 t0: float) -> None:
        super().__init__(url, "link", PortMirror(max_frame))
        self.bitrate_bps, self.delay_s, self.t0 = bitrate_bps, delay_s, t0
        self.key: bytes | None = None
        # Frame arithmetic only (trunk sizes): never polls.
        self._frames: Any = Master(bitrate_bps=bitrate_bps, delay_s=delay_s, max_frame=max_frame or MAX_FRAME)
        self.on_reply: Callable[[bytes, bool, float], None] | None = None
        self.decoder = _Decoder()
        self._status: dict = {"stats": dataclasses.asdict(MasterStats()), "stopping": False, "ber": 0.0,
                              "crc_errors": 0, "image_received": 0, "pilot_in_force": False}
        self._stats_before: dict = {}  # counts of the link processes that ended
        # What the session last set, given again to a link process started anew.
        self._kept: dict[str, tuple] = {}

    def authenticate(self, key: bytes) -> None:
        self.key = key
        self._frames = SecureMaster(self._frames, key)

    def _child(self) -> tuple[Callable[[Any, Any, dict], None], dict]:
        return child_main, {"url": self.url, "bitrate_bps": self.bitrate_bps, "delay_s": self.delay_s,
                            "t0": self.t0, "key": self.key}

    # -- what the session reads ---------------------------------------------

    @property
    def stats(self) -> MasterStats:
        """The session's counts: the link processes' before this one, and this one's."""
        now, base = self._status["stats"], self._stats_before
        return MasterStats(**{k: (v + base[k] if isinstance(v, int) and k in base else v) for k, v in now.items()})

    @property
    def stopping(self) -> bool:
        return bool(self._status["stopping"])

    @property
    def image_received(self) -> int:
        return int(self._status["image_received"])

    @property
    def pilot_in_force(self) -> bool:
        return bool(self._status["pilot_in_force"])

    def estimated_ber(self) -> float:
        return float(self._status["ber"])

    def trunk_bytes(self, size: int) -> int:
        return self._frames.trunk_bytes(size)

    def _take_status(self, status: dict) -> None:
        self._status = status
        self.decoder.crc_errors = status["crc_errors"]

    def _carry_counts(self) -> None:
        self._stats_before = {k: v for k, v in self.stats.__dict__.items() if isinstance(v, int)}
        self._status = {**self._status, "stats": dataclasses.asdict(MasterStats()), "stopping": False}

    # -- what the session orders ----------------------------------------------

    def _keep_and_call(self, name: str, *args) -> None:
        """A setting that holds until changed: kept for a new link process, and not
        refused while there is none (it goes with the next one)."""
        self._kept[name] = args
        try:
            self._cast(name, *args)
        except LinkProcessDown:
            pass

    def set_velocity(self, vx: int, vy: int, vz: int, vyaw: int, now: float) -> None:
        self._keep_and_call("set_velocity", vx, vy, vz, vyaw, now)

    def set_pilot_in_force(self, in_force: bool) -> None:
        self._keep_and_call("set_pilot_in_force", bool(in_force))

    def set_attended(self, attended: bool) -> None:
        self._keep_and_call("set_attended", bool(attended))

    def recentred(self) -> None:
        try:
            self._cast("recentred")
        except LinkProcessDown:
            pass

    def request_arm(self, arm: bool, now: float) -> None:
        self._call("request_arm", bool(arm), now)

    def request_mode(self, mode, now: float) -> None:
        self._call("request_mode", int(mode), now)

    def send_order(self, order) -> int:
        return self._call("send_order", order)

    def cancel_stop(self) -> bool:
        return bool(self._call("cancel_stop"))

    def abandon_image(self) -> None:
        self._call("abandon_image")

    # -- running it -----------------------------------------------------------

    async def run(self, on_events: Callable[[list, float], None], *, clock: Callable[[], float],
                  on_bytes: Callable[[bytes, float], None] | None = None,
                  on_turn: Callable[[float], None] | None = None,
                  on_up: Callable[[int, float], None] | None = None,
                  on_down: Callable[[str, float], None] | None = None) -> None:
        """Run the link process, start it again whenever it ends, until cancelled."""

        def take(message: tuple) -> None:
            kind = message[0]
            if kind == "events":
                _, batch, t, status = message
                self._take_status(status)
                on_events(batch, t)
            elif kind == "rx":
                if on_bytes is not None:
                    on_bytes(message[1], message[2])
            elif kind == "reply":
                if self.on_reply is not None:
                    self.on_reply(message[1], message[2], message[3])

        def turn() -> None:
            if on_turn is not None and self.up:
                on_turn(clock())

        def up(pid: int) -> None:
            # What the session had set holds in the new master too (the pilot's wish, whether
            # it is in force, whether a pilot attends).
            for name, args in list(self._kept.items()):
                try:
                    self._call(name, *args)
                except (LinkProcessDown, ValueError):
                    pass
            if on_up is not None:
                on_up(pid, clock())

        def down(why: str) -> None:
            if on_down is not None:
                on_down(why, clock())

        try:
            await self._supervise(take, turn=turn, up=up, down=down)
        finally:
            self.stop()

    def stop(self, timeout_s: float = STOP_AFTER_PARENT_S + 2.0) -> None:
        """End the link process as the console ends: it sends STOP, then stops polling."""
        self._end(timeout_s)
