"""The state snapshot the REST API returns and the WebSocket pushes.

A snapshot costs a dead-reckoning step and a pass over the link history, so
the WebSockets share one, remade at most every `max_age_s`: ten pages
watching cost what one does.  It is never older than the session's last event
(other than a pose): an event (the wish, an order's fate, the target) reaches
a page before the next telemetry does, and a snapshot taken before it would
take it back for a tick (the wish read "forward", then "neutral" for 50 ms,
with the key held)."""

from __future__ import annotations

import itertools
import math
import threading
import time

from rovlink.console.control import ControlDesk
from rovlink.console.session.contract import VehicleSession


def snapshot(operator: VehicleSession, desk: ControlDesk, client_id: str | None, *, orders: int, log: int) -> dict:
    state = operator.state()
    state["orders"] = state["orders"][-orders:] if orders else []
    state["log"] = state["log"][-log:] if log else []
    state["control"] = desk.status(client_id)
    state["target"] = desk.target_state()
    return state


def finite(value):
    """The value with NaN and infinities as None: browsers' JSON.parse refuses them."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite(v) for v in value]
    return value


class SharedSnapshot:
    def __init__(self, operator: VehicleSession, desk: ControlDesk, *, max_age_s: float = 0.04) -> None:
        self.operator = operator
        self.desk = desk
        self.max_age_s = max_age_s
        self._lock = threading.Lock()
        self._state: dict | None = None
        self._at = -math.inf
        self._count = itertools.count(1)
        self._events = 0      # the session's events so far (poses aside)
        self._made_at = -1    # ... when the shared state was made
        # Subscribed before any WebSocket is: the count moves before a page's
        # sender is handed the event.
        operator.subscribe(self._on_event)

    def _on_event(self, topic: str, payload) -> None:  # any thread
        if topic != "pose":
            self._events = next(self._count)  # one step, whatever thread

    def get(self, client_id: str | None) -> dict:
        """The shared state with this client's own view of control."""
        with self._lock:
            if time.monotonic() - self._at > self.max_age_s or self._events != self._made_at:
                events = self._events  # read before: an event during the making makes it stale
                self._state = finite(snapshot(self.operator, self.desk, None, orders=10, log=10))
                self._at, self._made_at = time.monotonic(), events
            state = self._state
        return {**state, "control": self.desk.status(client_id)}
