"""Requests to the autopilot and their answers, without I/O: the request/ack/resend
tracker the bridge drives, and the tickets the node polls.

Goals
- Every request the ROV makes of ArduSub (arm, disarm, mode change, message
  interval) ends in exactly one known outcome: accepted, failed with a reason the
  node can map to docs/PROTOCOL.md §3's REASON, or cancelled.
- No clock, no socket, no thread: the bridge hands in `now` and MAVLink's answers,
  and gets back what to send (as `link.master` is driven).

Plan
- `CommandTracker.request(...)` registers a COMMAND_LONG; `due(now)` returns the
  ones to (re)send: at once, then every `resend_s` until a COMMAND_ACK comes.
- `on_ack(command, result, now)` resolves the oldest open request of that command:
  accepted (0), failed (any refusal), or "in progress" (5: stop resending, wait).
- `on_state(armed, custom_mode)` accepts a request whose effect the HEARTBEAT
  already shows (the ACK may have been lost), once it has been sent at least once.
- `expire(now, reachable)` fails requests older than `deadline_s` (2 s: the
  protocol's wait for an autopilot answer, §3): REASON 2 (refused) when the
  autopilot is there and said nothing, REASON 1 (impossible now) when it is not.
  A request the autopilot answered "in progress" is its to finish: it is
  watched for `in_progress_s` (30 s) before it counts as unanswered, so that a
  vehicle that arms late is not reported refused while its motors start.
- A newer request of the same kind (arm, or mode) cancels the older one.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

from rovlink.link.radio.messages import Reason
from rovlink.rov.ardusub import MAV_RESULT_NAMES, mavlink

COMMAND_RESEND_S = 0.5
COMMAND_DEADLINE_S = 2.0
COMMAND_IN_PROGRESS_S = 30.0  # an autopilot that said "in progress" has this long to finish


class Ticket:
    """A request the node can poll.  Resolved once (by the bridge's I/O thread)."""

    PENDING, ACCEPTED, FAILED, CANCELLED = "pending", "accepted", "failed", "cancelled"

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self._status = Ticket.PENDING
        self._reason = ""
        self._reject_reason: Reason | None = None
        self._event = threading.Event()

    @property
    def status(self) -> str:
        return self._status

    @property
    def reason(self) -> str:
        """Why it failed or was cancelled, in words (the autopilot's own when it gave some)."""
        return self._reason

    @property
    def reject_reason(self) -> Reason | None:
        """For a failed ticket, docs/PROTOCOL.md §3's REASON: IMPOSSIBLE (now) or REFUSED."""
        return self._reject_reason

    @property
    def done(self) -> bool:
        return self._status != Ticket.PENDING

    @property
    def ok(self) -> bool:
        return self._status == Ticket.ACCEPTED

    def wait(self, timeout_s: float | None = None) -> str:
        """Block until resolved (not for the asyncio loop: poll `.status` there)."""
        self._event.wait(timeout_s)
        return self._status

    def _resolve(self, status: str, reason: str = "", reject_reason: Reason | None = None) -> bool:
        if self._status != Ticket.PENDING:
            return False
        if status == Ticket.FAILED and reject_reason is None:
            reject_reason = Reason.REFUSED
        self._reason = reason
        self._reject_reason = reject_reason if status == Ticket.FAILED else None
        self._status = status
        self._event.set()
        return True

    def fail(self, reason: str, reject_reason: Reason) -> bool:
        return self._resolve(Ticket.FAILED, reason, reject_reason)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.kind} {self._status}{': ' + self._reason if self._reason else ''}>"


class GotoTicket(Ticket):
    def __init__(self, kind: str = "goto") -> None:
        super().__init__(kind)
        self.target: tuple[float, float, float, float | None] | None = None  # x, y, z m, yaw rad
        self.reached = False


@dataclass
class Request:
    """A COMMAND_LONG in flight."""

    ticket: Ticket
    command: int
    params: tuple[float, ...]
    created_s: float
    kind: str = ""  # requests of one kind supersede each other ("arm", "mode"); "" never
    sent_s: float = -math.inf
    sends: int = 0
    acked: bool = False  # answered "in progress": no more resends
    want_mode: int | None = None  # accept when the HEARTBEAT shows this mode
    want_armed: bool | None = None
    timed_out: bool = False  # failed for want of an answer within the deadline


class CommandTracker:
    def __init__(self, resend_s: float = COMMAND_RESEND_S, deadline_s: float = COMMAND_DEADLINE_S,
                 in_progress_s: float = COMMAND_IN_PROGRESS_S) -> None:
        self.resend_s = resend_s
        self.deadline_s = deadline_s
        self.in_progress_s = in_progress_s
        self.requests: list[Request] = []
        # ACKs still owed to requests that are over (each send of a request may be
        # answered, and MAVLink's ACK names only the command): [command, count, until].
        # They come before any answer to a newer request of the command, so they are
        # taken as theirs, never as its (a POSHOLD sent twice and refused twice once
        # failed the ALT_HOLD sent after the first refusal).
        self._owed: list[list] = []

    def _over(self, request: Request, answered: bool, now: float) -> None:
        """`request` is over; the answers still owed to its sends are expected."""
        owed = request.sends - (1 if answered else 0)
        if owed > 0:
            self._owed.append([request.command, owed, max(now, request.sent_s) + self.deadline_s])

    def request(
        self,
        ticket: Ticket,
        command: int,
        params: tuple[float, ...],
        now: float,
        *,
        kind: str = "",
        want_mode: int | None = None,
        want_armed: bool | None = None,
    ) -> Request:
        if kind:
            self.cancel_kind(kind, "superseded by a newer request")
        params = tuple(float(p) for p in params) + (0.0,) * (7 - len(params))
        request = Request(ticket, command, params, now, kind, want_mode=want_mode, want_armed=want_armed)
        self.requests.append(request)
        return request

    def arm(self, ticket: Ticket, arm: bool, now: float) -> Request:
        return self.request(
            ticket, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (1.0 if arm else 0.0,), now, kind="arm", want_armed=arm
        )

    def mode(self, ticket: Ticket, custom_mode: int, now: float) -> Request:
        return self.request(
            ticket,
            mavlink.MAV_CMD_DO_SET_MODE,
            (float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(custom_mode)),
            now,
            kind="mode",
            want_mode=int(custom_mode),
        )

    def due(self, now: float) -> list[Request]:
        """Requests to send now (first send or resend); the caller sends each one."""
        out = []
        for request in self.requests:
            if not request.acked and now - request.sent_s >= self.resend_s:
                request.sent_s = now
                request.sends += 1
                out.append(request)
        return out

    def on_ack(self, command: int, result: int, now: float, detail: str = "") -> Request | None:
        """A COMMAND_ACK: resolve the oldest open request of that command; return it.
        An answer still owed to a request that is over is taken as its own (None)."""
        self._owed = [o for o in self._owed if o[2] > now and o[1] > 0]
        for owed in self._owed:
            if owed[0] == command:
                owed[1] -= 1
                return None
        for request in self.requests:
            if request.command != command or request.sends == 0:
                continue
            if result == mavlink.MAV_RESULT_ACCEPTED:
                request.ticket._resolve(Ticket.ACCEPTED)
                self.requests.remove(request)
                self._over(request, True, now)
            elif result == mavlink.MAV_RESULT_IN_PROGRESS:
                request.acked = True
            else:
                words = f"autopilot answered {MAV_RESULT_NAMES.get(result, result)}"
                request.ticket.fail(f"{words}: {detail}" if detail else words, Reason.REFUSED)
                self.requests.remove(request)
                self._over(request, True, now)
            return request
        return None

    def on_state(self, armed: bool, custom_mode: int | None) -> list[Request]:
        """The HEARTBEAT's armed state and mode: accept requests it shows done."""
        done = []
        for request in list(self.requests):
            shown = (request.want_mode is not None and custom_mode == request.want_mode) or (
                request.want_armed is not None and armed == request.want_armed
            )
            if shown and request.sends > 0:
                request.ticket._resolve(Ticket.ACCEPTED)
                self.requests.remove(request)
                self._over(request, request.acked, request.sent_s)
                done.append(request)
        return done

    def expire(self, now: float, reachable: bool) -> list[Request]:
        """Fail requests past their deadline; return them."""
        expired = []
        for request in list(self.requests):
            deadline_s = self.in_progress_s if request.acked else self.deadline_s
            if now - request.created_s >= deadline_s:
                request.timed_out = True
                if reachable:
                    said = "did not finish" if request.acked else "did not answer"
                    request.ticket.fail(f"autopilot {said} within {deadline_s:g} s", Reason.REFUSED)
                else:
                    request.ticket.fail("autopilot not reachable", Reason.IMPOSSIBLE)
                self.requests.remove(request)
                self._over(request, request.acked, now)
                expired.append(request)
        return expired

    def cancel_kind(self, kind: str, why: str) -> None:
        for request in list(self.requests):
            if request.kind == kind:
                request.ticket._resolve(Ticket.CANCELLED, why)
                self.requests.remove(request)
                self._over(request, request.acked, request.sent_s)

    def discard(self, request: Request | None) -> None:
        if request is not None and request in self.requests:
            self.requests.remove(request)

    def cancel_all(self, why: str) -> None:
        for request in self.requests:
            request.ticket._resolve(Ticket.CANCELLED, why)
        self.requests.clear()
