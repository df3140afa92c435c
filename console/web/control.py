"""Who may drive: one client holds control, every other client watches.

Goals: exactly one pilot at a time, never an ROV left moving by a pilot who
is gone.  A browser page is a client for as long as its WebSocket is open; a
script is a client for as long as it keeps talking.  Taking control is always
explicit and always allowed (the watcher next to the pilot must be able to
take over); what is refused is an order from a client that does not hold it.

Plan: `ControlDesk` keeps the clients by id (an unguessable token, so that
only the holder can send orders in its name) and the holder's id, under a
lock because FastAPI calls it from its loop and its thread pool.  Every
change of holder (take-over, release, the holder leaving) sets the velocity
wish to neutral first.  `tick()`, called a few times a second, does what no
request triggers: a script holder silent for `lease_s` loses control, and a
velocity the holder streams over its WebSocket falls back to neutral when
the stream stops for `deadman_s` (a frozen tab must not keep the thrusters
on).  A velocity sent over REST is a standing order and has no dead man; the
lease covers it.  STOP is not an order of the holder: anyone may press it.

The 3D scene (viser, its own server) orders through the same desk: a page
makes up a random scene key, gives it on its WebSocket (`scene_key`) and
opens the scene with it in the scene's WebSocket path; the scene asks
`scene_refusal(key)` before every order from one of its viewers, so that a
watcher's scene can no more drive than the watcher's page (STOP excepted).
A scene opened on its own, without a key, only watches.
"""

from __future__ import annotations

import re
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from rovlink.console.operator import Operator

NEUTRAL = (0.0, 0.0, 0.0, 0.0)
SCENE_KEY = re.compile(r"[A-Za-z0-9_-]{16,64}")


class NotHolder(Exception):
    """An order from a client that does not hold control (HTTP 409)."""


class Replaying(NotHolder):
    """An order to a console that replays a recording: there is no ROV (HTTP 409)."""


class UnknownClient(Exception):
    """A client id this desk never issued or has forgotten (HTTP 422)."""


@dataclass
class Client:
    id: str
    kind: Literal["browser", "script"]
    name: str
    last_seen: float
    # Monotonic time of the last non-neutral velocity streamed over the
    # WebSocket, None when the last one was neutral (or came over REST).
    streamed_at: float | None = None
    # The key of the 3D scene embedded in this page (browser clients), if any.
    scene_key: str | None = None


class ControlDesk:
    def __init__(self, operator: Operator, *, lease_s: float = 30.0, deadman_s: float = 1.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.operator = operator
        self.lease_s = lease_s
        self.deadman_s = deadman_s
        self._clock = clock
        self._lock = threading.RLock()
        self._clients: dict[str, Client] = {}
        self._holder: str | None = None
        self._held_since: float | None = None
        self.version = 0  # bumped at every change of holder, so WebSockets know to tell their pages

    # ------------------------------------------------------------------
    # Clients
    # ------------------------------------------------------------------

    def connect(self, name: str = "", scene_key: str | None = None) -> Client:
        """A browser page's WebSocket opened: a new watcher.  `scene_key`: the
        key its 3D scene was opened with (ignored unless 16-64 characters of
        letters, digits, - and _)."""
        if scene_key is not None and not SCENE_KEY.fullmatch(scene_key):
            scene_key = None
        with self._lock:
            client = Client(secrets.token_urlsafe(16), "browser", name or "browser", self._clock(),
                            scene_key=scene_key)
            self._clients[client.id] = client
            return client

    def disconnect(self, client_id: str) -> None:
        """A WebSocket closed: its page is gone, and control with it."""
        with self._lock:
            client = self._clients.pop(client_id, None)
            if client is not None and self._holder == client_id:
                self._release(f"control released: {client.name} left")

    def _lookup(self, client_id: str) -> Client:
        client = self._clients.get(client_id)
        if client is None:
            raise UnknownClient(f"unknown client id {client_id[:24]!r}: use the id from the WebSocket's hello "
                                f"message, or leave X-Rovlink-Client out to be given a new one")
        return client

    def touch(self, client_id: str | None) -> None:
        if client_id is None:
            return
        with self._lock:
            client = self._clients.get(client_id)
            if client is not None:
                client.last_seen = self._clock()

    # ------------------------------------------------------------------
    # Taking and giving back
    # ------------------------------------------------------------------

    def check_live(self) -> None:
        """Replaying has no ROV to order: Replaying, saying so."""
        if self.operator.replaying:
            raise Replaying("this console replays a recording: there is no ROV to order")

    def take(self, client_id: str | None, name: str = "") -> Client:
        """Give control to `client_id`, or to a new script client if None."""
        self.check_live()
        with self._lock:
            if client_id is None:
                client = Client(secrets.token_urlsafe(16), "script", name or "script", self._clock())
                self._clients[client.id] = client
            else:
                client = self._lookup(client_id)
                client.last_seen = self._clock()
                if name:
                    client.name = name
            if self._holder == client.id:
                return client
            previous = self._clients.get(self._holder) if self._holder else None
            self._set_neutral()
            self._holder, self._held_since = client.id, self._clock()
            client.streamed_at = None
            self.version += 1
        taken = f" from {previous.name}" if previous else ""
        self.operator.note(f"control taken by {client.name}{taken}")
        return client

    def release(self, client_id: str | None) -> None:
        with self._lock:
            self.require(client_id)
            name = self._clients[client_id].name
            self._release(f"control released by {name}")

    def _release(self, why: str) -> None:
        # Caller holds the lock.
        self._set_neutral()
        self._holder, self._held_since = None, None
        self.version += 1
        self.operator.note(why)

    def _set_neutral(self) -> None:
        self.operator.set_velocity(*NEUTRAL)

    def require(self, client_id: str | None) -> Client:
        """The holder's Client, or NotHolder saying why not."""
        self.check_live()
        with self._lock:
            if self._holder is None:
                raise NotHolder("nobody holds control: POST /api/control/take first")
            if client_id is None:
                raise NotHolder(f"control is held by {self._clients[self._holder].name}; send your "
                                f"X-Rovlink-Client header, or POST /api/control/take to take over")
            if client_id != self._holder:
                self._lookup(client_id)
                raise NotHolder(f"control is held by {self._clients[self._holder].name}, not by you: "
                                f"POST /api/control/take to take over")
            client = self._clients[client_id]
            client.last_seen = self._clock()
            return client

    def scene_refusal(self, scene_key: str | None) -> str | None:
        """May a viewer of the 3D scene opened with `scene_key` order now?
        None if so (its page holds control), else why not, in one line."""
        try:
            self.check_live()
        except Replaying as exc:
            return str(exc)
        with self._lock:
            holder = self._clients.get(self._holder) if self._holder else None
            if holder is None:
                return "nobody holds control: take control on the operator page first"
            if scene_key is None:
                return (f"control is held by {holder.name}; this 3D view was not opened from an operator "
                        f"page and can only watch")
            if holder.scene_key != scene_key:
                return f"control is held by {holder.name}, not by this page: take control to order"
            holder.last_seen = self._clock()
            return None

    # ------------------------------------------------------------------
    # Velocity from the holder's WebSocket, and the timers
    # ------------------------------------------------------------------

    def stream_velocity(self, client_id: str, vx: float, vy: float, vz: float, vyaw: float) -> None:
        """A velocity message on the WebSocket; NotHolder if it is not the holder's."""
        with self._lock:
            client = self.require(client_id)
            self.operator.set_velocity(vx, vy, vz, vyaw)
            client.streamed_at = None if (vx, vy, vz, vyaw) == NEUTRAL else self._clock()

    def rest_velocity(self, client_id: str | None, vx: float, vy: float, vz: float, vyaw: float) -> None:
        with self._lock:
            client = self.require(client_id)
            self.operator.set_velocity(vx, vy, vz, vyaw)
            client.streamed_at = None

    def tick(self) -> None:
        now = self._clock()
        with self._lock:
            holder = self._clients.get(self._holder) if self._holder else None
            if holder is not None and holder.streamed_at is not None \
                    and now - holder.streamed_at > self.deadman_s:
                holder.streamed_at = None
                self._set_neutral()
                self.operator.note(f"velocity from {holder.name} stopped arriving: neutral")
            if holder is not None and holder.kind == "script" and now - holder.last_seen > self.lease_s:
                self._release(f"control released: {holder.name} silent for {self.lease_s:g} s")
            for client in [c for c in self._clients.values() if c.kind == "script"]:
                # Forget idle scripts so that memory stays flat.
                if client.id != self._holder and now - client.last_seen > self.lease_s:
                    del self._clients[client.id]

    # ------------------------------------------------------------------
    # Status
    # ------------------------------------------------------------------

    def status(self, client_id: str | None = None) -> dict:
        with self._lock:
            holder = self._clients.get(self._holder) if self._holder else None
            return {
                "held": holder is not None,
                "holder": holder.name if holder else None,
                "holder_kind": holder.kind if holder else None,
                "held_for_s": self._clock() - self._held_since if holder and self._held_since else None,
                "you": holder is not None and client_id == holder.id,
                "lease_s": self.lease_s,
            }
