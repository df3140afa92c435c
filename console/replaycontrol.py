"""A timeline over a recorded session: play, pause, seek and change speed.

Goals: `rovlink replay` shows a recording as if live, and the pilot (or a
script) can stop it, go back to any moment and look again, faster or slower.
Going back must show exactly what plain playing to that moment shows.

Plan: the controller owns the Operator's clock.  Session time is a position
on the recording's timeline: it runs at `speed` times the wall clock while
playing and stands still while paused, so everything that reads
`operator.now()` (odometry age, dead reckoning, the plots) pauses with it.
Records are fed in file order, each at its own recorded time (the clock reads
the record's `t` while it is fed), so feeding is deterministic whatever the
scheduling: playing, seeking forward (the records up to the point fed at
once, without their timing) and seeking back give the same state.

Seeking back resets the Operator in place (its state rebuilt as a new
Operator's, keeping its identity, lock, subscribers, decoder and settings,
so the web app's, the control desk's and the scene's references stay valid),
then feeds the records from the start up to the point.  Events of a seek's
fast feed are not published one by one (a page would get thousands); the
resulting state is published once at the end.

One player thread feeds records when they fall due; the commands (`pause`,
`resume`, `set_speed`, `seek`) may come from any thread and wake it.  Nothing
here reaches a vehicle: a replay console refuses every order.

Cost: a seek feeds every record up to its point again (from the start when
going back): about 0.15 ms a reply on this project's 2-core test machine, so
about 1 s for 7000 replies (some tens of minutes at 1.9 kbit/s).  The web app finds the
controller of its Operator with `controller_of`.
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
import time
import weakref
from pathlib import Path
from typing import Callable

from .recording import read_records

log = logging.getLogger("rovlink.console.replay")

MIN_SPEED = 0.1
MAX_SPEED = 64.0
SPEEDS = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0)  # what the page offers

# operator -> weak reference to its controller (the operator's clock, a bound
# method of the controller, keeps the controller alive as long as the operator).
_controllers: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def controller_of(operator) -> "ReplayController | None":
    """The controller replaying into `operator`, if any."""
    ref = _controllers.get(operator)
    return ref() if ref is not None else None


def _wall0(meta: dict) -> float | None:
    """Clock time of the recording's session time 0, from its meta record."""
    if isinstance(meta.get("wall0"), (int, float)):
        return float(meta["wall0"])
    started = meta.get("started")
    if isinstance(started, str):
        try:
            return time.mktime(time.strptime(started, "%Y-%m-%dT%H:%M:%S"))
        except (ValueError, OverflowError):
            return None
    return None


class ReplayController:
    """Plays the recording at `path` into `operator` (see the module's docstring).

    `speed`: playback factor, MIN_SPEED..MAX_SPEED.  `paused`: start paused at 0.
    `monotonic`: the wall clock (tests give a fake one and call `advance`
    instead of `start`).  `on_done(counts)`: called each time the end is reached.
    """

    def __init__(self, operator, path: str | Path, *, speed: float = 1.0, paused: bool = False,
                 monotonic: Callable[[], float] = time.monotonic, on_done=None) -> None:
        _check_speed(speed)
        records = list(read_records(path))
        self.path = Path(path)
        self.meta = records[0]
        self._records = records[1:]
        # File order is feeding order; times made non-decreasing (records from
        # two threads can be written a hair out of order).
        self._times: list[float] = []
        last = 0.0
        for r in self._records:
            t = r.get("t", 0.0)
            last = max(last, float(t) if isinstance(t, (int, float)) and math.isfinite(t) else last)
            self._times.append(last)
        self.duration = self._times[-1] if self._times else 0.0
        self.operator = operator
        self.on_done = on_done
        self._monotonic = monotonic
        self._cond = threading.Condition(threading.RLock())
        # The timeline: session position `_pos` at wall time `_anchor`, advancing
        # at `_speed` unless paused.  While a record is fed, the clock reads its time.
        self._pos, self._anchor, self._speed, self._paused = 0.0, monotonic(), float(speed), bool(paused)
        self._feeding_t: float | None = None
        self._index = 0  # the next record to feed
        self._ended = False
        self.seeks = 0  # seeks and restarts so far: a page reloads what a jump rewrote (its log)
        self._closed = False
        self._thread: threading.Thread | None = None
        self.counts = _zero_counts()
        self._take(operator)
        _controllers[operator] = weakref.ref(self)

    # ------------------------------------------------------------------
    # The clock
    # ------------------------------------------------------------------

    def clock(self) -> float:
        """Session time now (the Operator's clock)."""
        feeding = self._feeding_t
        if feeding is not None:
            return feeding
        pos, anchor, speed, paused = self._pos, self._anchor, self._speed, self._paused
        if paused:
            return pos
        return min(self.duration, pos + (self._monotonic() - anchor) * speed)

    def _set_timeline(self, pos: float, *, paused: bool | None = None, speed: float | None = None) -> None:
        # Caller holds the lock.  Anchor first: a reader without the lock sees
        # at worst a clock a few microseconds off.
        self._anchor = self._monotonic()
        self._pos = pos
        if speed is not None:
            self._speed = speed
        if paused is not None:
            self._paused = paused

    # ------------------------------------------------------------------
    # State (any thread)
    # ------------------------------------------------------------------

    @property
    def position(self) -> float:
        """Where the replay stands: after a seek or a feed in progress, never in
        the middle of one (the clock reads each record's time while it is fed)."""
        with self._cond:
            return self.clock()

    @property
    def paused(self) -> bool:
        return self._paused

    @property
    def speed(self) -> float:
        return self._speed

    @property
    def ended(self) -> bool:
        return self._ended

    def state(self) -> dict:
        with self._cond:
            return self._state_locked()

    def _state_locked(self) -> dict:
        return {"available": True, "file": self.path.name, "t": round(self.clock(), 3),
                "duration": round(self.duration, 3), "paused": self._paused, "ended": self._ended,
                "speed": self._speed, "speeds": list(SPEEDS), "min_speed": MIN_SPEED, "max_speed": MAX_SPEED,
                "seeks": self.seeks}

    # ------------------------------------------------------------------
    # Commands (any thread)
    # ------------------------------------------------------------------

    def pause(self) -> None:
        with self._cond:
            if not self._paused:
                self._set_timeline(self.clock(), paused=True)
            self._cond.notify_all()

    def resume(self) -> None:
        """Play on; from the start again when the end was reached."""
        with self._cond:
            if self._ended:
                self._seek_locked(0.0)
            if self._paused:
                self._set_timeline(self.clock(), paused=False)
            self._cond.notify_all()

    def set_speed(self, speed: float) -> None:
        _check_speed(speed)
        with self._cond:
            self._set_timeline(self.clock(), speed=float(speed))
            self._cond.notify_all()

    def seek(self, t: float) -> None:
        """Show the session as it was at `t` (0..duration); paused stays paused."""
        if not isinstance(t, (int, float)) or not math.isfinite(t) or not 0.0 <= t <= self.duration:
            raise ValueError(f"t must be a session time in 0..{self.duration:g} s, got {t!r}")
        with self._cond:
            self._seek_locked(float(t))
            self._cond.notify_all()

    # ------------------------------------------------------------------
    # Playing
    # ------------------------------------------------------------------

    def advance(self) -> float | None:
        """Feed the records due by now; seconds (wall) until the next falls due,
        None while paused or at the end.  The player thread calls it; tests with
        a fake clock call it themselves."""
        with self._cond:
            if self._paused or self._ended or self._closed:
                return None
            pos = self.clock()
            self._feed_until(pos)
            if self._index >= len(self._records):
                self._finish()
                return None
            return max(0.0, (self._times[self._index] - pos) / self._speed)

    def start(self) -> "ReplayController":
        """Play in a thread of its own until `close`."""
        self._thread = threading.Thread(target=self._run, name="replay", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(10)

    def _run(self) -> None:
        with self._cond:
            while not self._closed:
                try:
                    wait = self.advance()
                except Exception:  # a failure of ours must not end the replay
                    log.exception("replay: feeding failed at record %d", self._index - 1)
                    continue
                # Woken early by any command; never asleep long, whatever the clock did.
                self._cond.wait(timeout=1.0 if wait is None else min(wait, 1.0))

    def _finish(self) -> None:
        self._set_timeline(self.duration, paused=True)
        self._ended = True
        c = self.counts
        self.operator.note(f"replay finished: {c['rx']} frames received, {c['tx']} sent")
        if self.on_done is not None:
            self.on_done(dict(c))

    def _seek_locked(self, t: float) -> None:
        # Records already fed that lie after t: start again from nothing.
        if self._index > 0 and self._times[self._index - 1] > t:
            self._reset()
        self._ended = False
        self._fast_feed_until(t)
        self._set_timeline(t)
        self.seeks += 1
        self.operator.note(f"replay: at {_clock_text(t)} of {_clock_text(self.duration)}")

    def _fast_feed_until(self, t: float) -> None:
        # One state published at the end, not every event of the way.
        with self.operator.quiet():
            self._feed_until(t)

    def _feed_until(self, t: float) -> None:
        records, times = self._records, self._times
        try:
            while self._index < len(records) and times[self._index] <= t:
                self._feeding_t = times[self._index]
                record = records[self._index]
                self._index += 1
                try:
                    self._feed(record)
                except (KeyError, TypeError, ValueError) as exc:  # a damaged record: skipped, played on
                    self.counts["damaged"] += 1
                    log.debug("replay: record %d skipped: %r", self._index - 1, exc)
        finally:
            self._feeding_t = None

    def _feed(self, record: dict) -> None:
        """One record to the session, whose driver replays its own profile's records."""
        kind = record.get("k")
        counted = _COUNTED_AS.get(kind, kind)
        if counted in self.counts:
            self.counts[counted] += 1
        self.operator.replayed(record)

    # ------------------------------------------------------------------
    # The Operator
    # ------------------------------------------------------------------

    def _take(self, op) -> None:
        """Make `op` show this recording: its clock, its link's rate and delay."""
        op.bitrate_bps = self.meta.get("bitrate_bps", op.bitrate_bps)
        op.delay_s = self.meta.get("delay_s", op.delay_s)
        op.use_clock(self.clock, wall0=_wall0(self.meta))
        op.replaying = True
        op.reset()

    def _reset(self) -> None:
        """The Operator's state as a new one's, in place (see the module's docstring)."""
        self.operator.reset()
        self._index = 0
        self.counts = _zero_counts()


# What each record counts as: a radio reply and an acoustic status are both the vehicle's report.
_COUNTED_AS = {"reply": "replies", "status": "replies", "order": "orders", "order_state": "orders"}


def _zero_counts() -> dict:
    return {"rx": 0, "tx": 0, "wish": 0, "orders": 0, "replies": 0, "damaged": 0}


def _check_speed(speed) -> None:
    if not isinstance(speed, (int, float)) or not math.isfinite(speed) or not MIN_SPEED <= speed <= MAX_SPEED:
        raise ValueError(f"speed must be a factor in {MIN_SPEED:g}..{MAX_SPEED:g}, got {speed!r}")


def _clock_text(t: float) -> str:
    return f"{int(t // 60)}:{t % 60:04.1f}"


async def replay(operator, path: str | Path, *, speed: float = 1.0, on_done=None) -> dict:
    """Play a recording into `operator` in (scaled) real time, to its end; returns
    counts (`ReplayController` for a timeline to pause, seek and change speed)."""
    if not speed > 0:
        raise ValueError("speed must be positive")
    controller = ReplayController(operator, path, speed=speed, on_done=on_done).start()
    try:
        while not controller.ended:
            await asyncio.sleep(0.02)
    finally:
        controller.close()
    return dict(controller.counts)
