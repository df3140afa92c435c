"""The link's condition, from replies: the one definition of "link lost".

Up means replies arrive, not that polls leave (a dead channel still takes
polls).  No reply for LOST_AFTER_S is a lost link (docs/PROTOCOL.md §5); a
reply lost, or a CRC error, within DEGRADED_WINDOW_S degrades it.  The page,
the scene and the ground-station gateway all read `condition`.

Alerts are raised where the change happens: the link driver calls `watch`
once per turn of its loop (and after every reply), so "LINK LOST" reaches the
log whether or not anybody reads the state, and is marked cleared when the
link is back; reading never logs.
"""

from __future__ import annotations

import time
from typing import Callable

from .odometry import History

LOST_AFTER_S = 3.0
DEGRADED_WINDOW_S = 5.0
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

    # -- events -----------------------------------------------------------

    def event(self, t: float, kind: str, n: int = 0) -> None:
        """"tx"/"rx" (bytes), "lost", "crc" (how many), "forged"."""
        self._history.link_events.append((t, kind, n))

    def reply(self, t: float, round_trip_s: float | None) -> None:
        self.reply_at = t
        if round_trip_s is not None:
            self._history.round_trips.append(round_trip_s)

    def crc_errors(self, total: int, t: float) -> None:
        """The decoder's CRC error count now: new ones become an event."""
        if total != self._crc_seen:
            self.event(t, "crc", total - self._crc_seen)
            self._crc_seen = total

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
        recent = [e for e in list(self._history.link_events)[-200:]
                  if e[1] in ("lost", "crc") and t - e[0] <= DEGRADED_WINDOW_S]
        return ("degraded" if recent else "up"), since

    def silent_s(self, t: float) -> tuple[str, float | None]:
        """The condition, and how long no reply came (since start when none ever did)."""
        state, since = self.condition(t)
        return state, since if since is not None else (t if state == "lost" else None)

    def watch(self, t: float) -> None:
        """Link lost and back into the log, once per change (the driver calls it)."""
        state, silent = self.silent_s(t)
        was, self._shown = self._shown, state
        if was == state or state in ("starting", "replay"):
            return
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
        failsafe_at = time.time() - silent + rov_failsafe_s if inferred else None
        return {
            "state": state,
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
