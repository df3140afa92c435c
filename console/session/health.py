"""The link's condition, from replies: the one definition of "link lost".

Up means replies arrive, not that polls leave (a dead channel still takes
polls).  No reply for LOST_AFTER_S is a lost link (docs/PROTOCOL.md §5).  A
link that answers is degraded when one of its figures over the last
DEGRADED_WINDOW_S crosses its threshold (replies lost, bad frames, late
replies: the `Threshold`s), and says which; it is up again only once every figure
is under its lower threshold and DEGRADED_HOLD_S have passed, so that a reply
lost now and then neither raises it nor makes it flap.  The page, the scene
and the ground-station gateway all read `condition`.

Alerts are raised where the change happens: the link driver calls `watch`
once per turn of its loop (and after every reply), so "LINK LOST" reaches the
log whether or not anybody reads the state, and is marked cleared when the
link is back; reading never logs.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from typing import Callable

from .odometry import History

LOST_AFTER_S = 3.0
DEGRADED_WINDOW_S = 10.0
DEGRADED_HOLD_S = 10.0     # degraded at least this long once it is: no flapping


@dataclass(frozen=True)
class Threshold:
    """A link figure over the last DEGRADED_WINDOW_S: the link degrades when it reaches
    `enter` and recovers only when it is below `leave` (hysteresis)."""
    figure: str
    enter: float
    leave: float


LOST_SHARE = Threshold("replies lost", 0.10, 0.04)   # of the polls answered or lost in the window
LOST_AT_LEAST = 2                                    # ...and never on one lost reply alone
BAD_FRAMES = Threshold("bad frames", 3, 1)           # CRC failures (1.1), lengths out of bounds (2)
LATE_REPLIES = Threshold("late replies", 3, 1)       # authentic replies that came too late (2)
AUTH_ALERT_COUNT, AUTH_ALERT_WINDOW_S = 3, 10.0  # more forged replies than this in the window: alert
RATE_WINDOW_S = 10.0


class LinkHealth:
    """Link events and counters of a session.  `history` holds the series it
    appends to (link events, round trips); `note` is the session's log."""

    def __init__(self, *, history: History, note: Callable[..., None], clear: Callable[[str], None]) -> None:
        self._history = history
        self._note = note
        self._clear = clear
        self.lost_after_s = LOST_AFTER_S
        self.replaying = False
        self.reply_at: float | None = None   # when the last reply arrived
        self.inauthentic_frames = 0
        self.late_replies = 0
        self._crc_seen = 0
        self._auth_alerted_at: float | None = None
        self._shown: str | None = None       # the condition last told the pilot
        self._watch_lock = threading.Lock()
        self._watched_t = -math.inf           # the time the condition was last judged for
        # Degraded: since when, and why in a sentence and in a few words (None while not).
        self._degraded_lock = threading.Lock()
        self._degraded_at: float | None = None
        self._degraded_why: tuple[str, str] | None = None
        self._assessed_t = -1e300

    # -- events -----------------------------------------------------------

    def event(self, t: float, kind: str, n: int = 0) -> None:
        """"tx"/"rx" (bytes), "lost", "crc" (how many), "forged"."""
        self._history.link_events.append((t, kind, n))

    def reply(self, t: float, round_trip_s: float | None) -> None:
        self.reply_at = t
        self.event(t, "reply")
        if round_trip_s is not None:
            self._history.round_trips.append(round_trip_s)

    def crc_errors(self, total: int, t: float) -> None:
        """The decoder's CRC error count now: new ones become an event."""
        if total != self._crc_seen:
            self.event(t, "crc", total - self._crc_seen)
            self._crc_seen = total

    def late(self, t: float) -> None:
        """An authentic reply that came too late (version 2)."""
        self.late_replies += 1
        self.event(t, "late")

    def inauthentic(self, t: float) -> None:
        """A frame whose tag did not hold: counted.  Version 2 has no CRC (§8.1), so
        noise and forgery look alike; more than a few while no reply comes is an
        alert (the wrong key, another operator's link, a forger, or noise enough to
        lose the link)."""
        self.inauthentic_frames += 1
        self.event(t, "forged")
        recent = self.auth_recent(t)
        if self._auth_alert(t) and (self._auth_alerted_at is None
                                    or t - self._auth_alerted_at > AUTH_ALERT_WINDOW_S):
            self._auth_alerted_at = t
            self._note(f"ALERT: {recent} frames failed authentication in {AUTH_ALERT_WINDOW_S:g} s and no reply "
                       f"came (another key or operator on the link, a forger, or heavy noise)", "alert")

    def auth_recent(self, t: float) -> int:
        return sum(1 for e in list(self._history.link_events)[-300:]
                   if e[1] == "forged" and t - e[0] <= AUTH_ALERT_WINDOW_S)

    def _auth_alert(self, t: float) -> bool:
        replied = self.reply_at is not None and t - self.reply_at <= AUTH_ALERT_WINDOW_S
        return not replied and self.auth_recent(t) > AUTH_ALERT_COUNT

    # -- the condition ----------------------------------------------------

    def condition(self, t: float) -> tuple[str, float | None]:
        """("up" | "degraded" | "lost" | "replay" | "starting", seconds since the last reply)."""
        since = None if self.reply_at is None else max(0.0, t - self.reply_at)
        if self.replaying:
            return "replay", since
        if since is None:
            return ("lost" if t > self.lost_after_s else "starting"), since
        if since >= self.lost_after_s:
            return "lost", since
        return ("degraded" if self._assess(t) else "up"), since

    # -- degraded, and why ------------------------------------------------

    def figures(self, t: float) -> dict:
        """The link's figures over the last DEGRADED_WINDOW_S."""
        counts = {"reply": 0, "lost": 0, "crc": 0, "late": 0}
        for at, kind, n in reversed(list(self._history.link_events)):
            if t - at > DEGRADED_WINDOW_S:
                break
            if kind in counts and at <= t:
                counts[kind] += n if kind == "crc" else 1
        polls = counts["reply"] + counts["lost"]
        return {"polls": polls, "lost": counts["lost"], "lost_share": counts["lost"] / polls if polls else 0.0,
                "bad_frames": counts["crc"], "late_replies": counts["late"]}

    @staticmethod
    def _crossed(f: dict, level: str) -> tuple[str, str] | None:
        """The first figure at or over its `level` ("enter") or not yet under it ("leave"):
        why, in a sentence and in a few words; None if none is."""
        w = f"{DEGRADED_WINDOW_S:g} s"
        share = f["lost_share"]
        if (share >= LOST_SHARE.enter and f["lost"] >= LOST_AT_LEAST) if level == "enter" \
                else (share >= LOST_SHARE.leave and f["lost"] >= LOST_AT_LEAST):
            return (f"{f['lost']} of {f['polls']} replies lost in the last {w} ({share:.0%}; "
                    f"degraded from {LOST_SHARE.enter:.0%}, up again under {LOST_SHARE.leave:.0%})",
                    f"{share:.0%} lost")
        for th, key, words in ((BAD_FRAMES, "bad_frames", "bad frames"), (LATE_REPLIES, "late_replies", "late")):
            n = f[key]
            if n >= (th.enter if level == "enter" else th.leave + 1):
                return (f"{n} {th.figure} in the last {w} (degraded from {th.enter:g}, up again at "
                        f"{th.leave:g} or fewer)", f"{n} {words}")
        return None

    def _assess(self, t: float) -> bool:
        """Degraded now?  Kept between calls (the hysteresis); a reading older than the
        last one changes nothing."""
        with self._degraded_lock:
            if t < self._assessed_t:
                return self._degraded_at is not None
            self._assessed_t = t
            f = self.figures(t)
            if self._degraded_at is None:
                why = self._crossed(f, "enter")
                if why is not None:
                    self._degraded_at, self._degraded_why = t, why
            else:
                why = self._crossed(f, "leave")
                if why is not None:
                    self._degraded_why = why
                elif t - self._degraded_at >= DEGRADED_HOLD_S:
                    self._degraded_at, self._degraded_why = None, None
            return self._degraded_at is not None

    def degraded_why(self) -> tuple[str, str] | None:
        """Why the link is degraded (a sentence, a few words), as last assessed."""
        with self._degraded_lock:
            return self._degraded_why

    def silent_s(self, t: float) -> tuple[str, float | None]:
        """The condition, and how long no reply came (since start when none ever did)."""
        state, since = self.condition(t)
        return state, since if since is not None else (t if state == "lost" else None)

    def watch(self, t: float) -> None:
        """Link lost and back into the log, once per change (the driver calls it).  A call
        for a time before one already judged is ignored, and calls are taken one at a
        time: the condition at an earlier time (a report's own time, another thread's
        clock read) must not take back what was told (LINK LOST cleared while it lasts)."""
        with self._watch_lock:
            if t < self._watched_t:
                return
            self._watched_t = t
            self._watch(t)

    def _watch(self, t: float) -> None:
        state, silent = self.silent_s(t)
        was, self._shown = self._shown, state
        if was == state or state in ("starting", "replay"):
            return
        if state == "degraded":
            why = self.degraded_why()
            self._note("link degraded: " + (why[0] if why else "replies lost or bad frames"), "warn")
        elif was == "degraded" and state == "up":
            self._note("link no longer degraded: every figure under its threshold", "info")
        if state == "lost":
            self._note("LINK LOST: no reply from the ROV" + (f" for {silent:.0f} s" if silent else ""), "alert",
                       cause="link")
        elif was == "lost":
            self._clear("link")
            self._note("link back: replies arrive again", "warn")

    def state(self, t: float, rov_failsafe_s: float) -> dict:
        """The link's condition and rates (no side effect)."""
        recent = [e for e in list(self._history.link_events) if t - e[0] <= RATE_WINDOW_S]
        span = min(RATE_WINDOW_S, max(t, 1e-6))
        rtts = sorted(self._history.round_trips)
        state, silent = self.silent_s(t)
        inferred = state == "lost" and silent is not None and silent >= rov_failsafe_s
        why = self.degraded_why() if state == "degraded" else None
        failsafe_at = time.time() - silent + rov_failsafe_s if inferred else None
        return {
            "state": state,
            # Which figure degraded the link, against which threshold (None unless degraded).
            "degraded_reason": why[0] if why else None,
            "degraded_short": why[1] if why else None,
            "since_reply_s": silent,
            "lost_after_s": self.lost_after_s,
            "rov_failsafe_s": rov_failsafe_s,
            # No poll has reached the ROV for its failsafe time: it has
            # stopped and holds depth (docs/PROTOCOL.md §3), though it cannot say so.
            "failsafe_inferred": inferred,
            "failsafe_inferred_at": failsafe_at,
            "failsafe_inferred_since": time.strftime("%H:%M:%S", time.localtime(failsafe_at)) if inferred else None,
            "t": t,
            "poll_rate_hz": sum(1 for e in recent if e[1] == "tx") / span,
            "reply_rate_hz": sum(1 for e in recent if e[1] == "rx") / span,
            "round_trip_s": rtts[len(rtts) // 2] if rtts else None,
            "bytes_per_s": sum(e[2] for e in recent) / span,
            "inauthentic_frames": self.inauthentic_frames,
            "late_replies": self.late_replies,
            "auth_alert": self._auth_alert(t),
            # Up means replies arrive, not that polls leave.
            "link_up": state in ("up", "degraded"),
        }
