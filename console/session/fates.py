"""An order's fate, typed once: what each fate means, whether the vehicle has
said it, and the words the pilot reads.

Goal: a fate is told only as the vehicle said it.  Until the ROV answers, or
the replies show the order done, it is pending (queued, requested, sent,
waiting) with its age; the console never turns its own impatience into
"refused".  An arm or mode request the vehicle follows late becomes
"followed" then, whatever it showed before.

Every surface reads the enum and the flags made here (`outcome`, `ended`),
never the words: the page (console.js reads `outcome` and `state`), the
ground-station gateway (its COMMAND_ACK), the recording and the log.  The
words are made by `words()` alone; `parse_recorded` reads a recording made
before fates were typed (its states were words) and is the one place that
reads words back.
"""

from __future__ import annotations

from enum import StrEnum


class Fate(StrEnum):
    QUEUED = "queued"              # the console has it; not on the wire yet
    REQUESTED = "requested"        # an arm or mode request handed to the link; not on the wire yet
    SENT = "sent"                  # on the wire; nothing heard of it yet
    WAITING = "waiting"            # the link has done its part (an arm or mode request is no longer
    #                                repeated); the vehicle has not shown it done yet, and may still
    ACKNOWLEDGED = "acknowledged"  # the ROV took it (a go-to: GUIDED has it; a STOP: the ROV holds)
    FOLLOWED = "followed"          # the vehicle's reported state shows it done (arm, disarm, mode)
    ARRIVED = "arrived"            # a go-to: the replies put the vehicle at its target
    DONE = "done"                  # the ROV says it is done (a hold, a surfacing, a thumbnail)
    REJECTED = "rejected"          # the ROV said no, and why
    NOT_CARRIED_OUT = "not carried out"  # a STOP the ROV took while no autopilot holds the vehicle
    ABORTED = "aborted"            # a go-to given up, and why (replaced, STOP, FAILSAFE, left GUIDED)
    CANCELLED = "cancelled"        # it will not be carried out, and why (superseded, a STOP, the pilot)
    REFUSED = "refused"            # the console would not send it, and why: it never reached the wire
    UNKNOWN = "unknown"            # nobody can tell, and why (the ROV restarted, the link process ended)

    @property
    def pending(self) -> bool:
        """The vehicle has not said yet: shown with its age."""
        return self in _PENDING

    @property
    def ended(self) -> bool:
        """Nothing more will come of it on the link (ACKNOWLEDGED is not: a go-to
        goes on to arrive or abort).  An arm or mode request whose fate is UNKNOWN
        is still watched: the vehicle may yet show it followed."""
        return not self.pending and self is not Fate.ACKNOWLEDGED

    @property
    def outcome(self) -> str:
        """What the page colours it: pending, done, bad (the pilot is alerted), or
        ended (by someone's choice: cancelled, aborted)."""
        if self in _PENDING:
            return "pending"
        if self in _GOOD:
            return "done"
        return "bad" if self in _BAD else "ended"

    @property
    def alert(self) -> bool:
        """Went wrong: said loudly in the log (and popped up on the page)."""
        return self in _BAD


_PENDING = frozenset({Fate.QUEUED, Fate.REQUESTED, Fate.SENT, Fate.WAITING})
_GOOD = frozenset({Fate.ACKNOWLEDGED, Fate.FOLLOWED, Fate.ARRIVED, Fate.DONE})
_BAD = frozenset({Fate.REJECTED, Fate.NOT_CARRIED_OUT, Fate.REFUSED, Fate.UNKNOWN})


def words(fate: Fate, reason: str = "") -> str:
    """The one place a fate becomes words: "rejected: impossible now"."""
    return f"{fate.value}: {reason}" if reason else fate.value


def fields(fate: Fate, reason: str = "") -> dict:
    """What an order's published state carries of its fate."""
    return {"state": fate.value, "reason": reason, "text": words(fate, reason), "outcome": fate.outcome}


def parse_recorded(state: str, reason: str | None = None) -> tuple[Fate, str]:
    """A recorded state: typed (with its reason), or the words of a recording
    made before fates were typed ("rejected: invalid")."""
    if reason is not None:
        try:
            return Fate(state), reason
        except ValueError:
            pass
    for fate in sorted(Fate, key=lambda f: -len(f.value)):
        head = fate.value
        if state == head:
            return fate, ""
        if state.startswith(head + ":"):
            return fate, state[len(head) + 1:].strip()
        if state.startswith(head + " "):  # "cancelled ... (never sent)" in the oldest recordings
            return fate, state[len(head):].strip()
    return Fate.UNKNOWN, f"recorded as {state!r}"
