"""Guards in front of the web console, as plain ASGI middleware, and the
access policy that every port the console opens applies (the app's and the
3D scene's, see `guard_viser`).

Who may talk to the console (AccessPolicy):
- DNS rebinding: a page of another site whose name an attacker points at
  this machine reaches our ports with its own name in `Host`.  Every request
  whose Host is not the bound address, a loopback name, or a name given with
  `--allow-host` gets 403, on every port, before anything else.
- Bound to anything but loopback, every HTTP and WebSocket request needs the
  access token the banner prints in its URL: `?token=` once, then the cookie
  the answer sets (HttpOnly, SameSite=Strict; cookies ignore ports, so the
  scene's port gets it too), as Jupyter does.  Without it: 401.  On loopback
  the token is not asked for: whoever runs code on this machine as us can
  read our memory anyway, and the Host check keeps web pages out.
- WebSockets from a page of another origin are refused (the app's own /ws
  checks this itself; the scene's port here).

Goal of the limits: no request can make the console's server do much work
for nothing.  Nothing the page or a script sends is larger than a few
kilobytes, so:

- A request whose body is over `max_body_bytes` (64 KB) gets 413 before
  any of it is read: at once when its Content-Length says so, and as soon as
  the running count passes the limit for a chunked body.  The connection is
  then closed, since the rest of the body is never read.
- At most `max_websockets` WebSocket connections are open at once; one more
  is closed during its handshake with code 1013 ("try again later").  A page
  holds one; a few pages and scripts stay far below the cap, and three
  hundred readers cannot make the server serialise telemetry for all of
  them.

Middleware rather than a route dependency: FastAPI reads a JSON body before
any dependency runs, and the limit must hold for every route, the static
files and routes added later alike.
"""

from __future__ import annotations

import hmac
import ipaddress
import json
import logging
import secrets
import socket
import time
from dataclasses import dataclass, field
from http.cookies import SimpleCookie
from urllib.parse import parse_qs, urlsplit

log = logging.getLogger("rovlink.console.web")

MAX_BODY_BYTES = 64 * 1024
MAX_WEBSOCKETS = 64
TOKEN_COOKIE = "rovlink_token"
LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})


def is_loopback(host: str) -> bool:
    if host.lower() in LOOPBACK_NAMES or host.lower().endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _local_addresses() -> set[str]:
    """This machine's own names and addresses (for a server bound to all interfaces)."""
    names = {socket.gethostname().lower(), socket.getfqdn().lower()}
    for name in list(names):
        try:
            names.update(info[4][0] for info in socket.getaddrinfo(name, None))
        except OSError:
            pass
    return names


def host_name(host_header: str | None) -> str | None:
    """The name part of a Host header ("[::1]:8000" -> "::1"); None if malformed."""
    if not host_header:
        return None
    try:
        parts = urlsplit(f"//{host_header}")
        name = parts.hostname
        _ = parts.port  # a malformed port raises
    except ValueError:
        return None
    return name.lower() if name else None


@dataclass
class AccessPolicy:
    """Who may talk to the console's ports (see the module's docstring)."""

    bound_host: str = "127.0.0.1"
    allow_hosts: tuple[str, ...] = ()
    token: str | None = None  # None: no token asked for (loopback)
    allowed: set[str] = field(init=False)

    def __post_init__(self) -> None:
        bound = self.bound_host.strip("[]").lower()
        self.allowed = set(LOOPBACK_NAMES) | {bound} | {h.strip("[]").lower() for h in self.allow_hosts}
        if bound in ("0.0.0.0", "::", ""):
            self.allowed |= _local_addresses()

    @classmethod
    def for_server(cls, host: str, allow_hosts=(), token: str | None = None) -> "AccessPolicy":
        """The policy for a server bound to `host`: a new random token unless on loopback."""
        if token is None and not is_loopback(host.strip("[]")):
            token = secrets.token_urlsafe(24)
        return cls(host, tuple(allow_hosts), token)

    def host_allowed(self, host_header: str | None) -> bool:
        name = host_name(host_header)
        return name is not None and (name in self.allowed or name.endswith(".localhost"))

    def origin_allowed(self, origin: str | None) -> bool:
        """A page's Origin: absent (not a browser), or one of our allowed names (any port)."""
        if origin is None:
            return True
        try:
            name = urlsplit(origin).hostname
        except ValueError:
            return False
        return name is not None and (name.lower() in self.allowed or name.lower().endswith(".localhost"))

    def token_given(self, query: str, cookie_header: str | None) -> tuple[bool, bool]:
        """(authorised, set_cookie): whether the request carries the token, and
        whether it came in the query (the answer then sets the cookie)."""
        if self.token is None:
            return True, False
        for value in parse_qs(query).get("token", ()):
            if hmac.compare_digest(value.encode(), self.token.encode()):
                return True, True
        if cookie_header:
            cookie = SimpleCookie()
            try:
                cookie.load(cookie_header)
            except Exception:  # a malformed cookie header is no token
                return False, False
            morsel = cookie.get(TOKEN_COOKIE)
            if morsel is not None and hmac.compare_digest(morsel.value.encode(), self.token.encode()):
                return True, False
        return False, False

    def set_cookie_header(self) -> str:
        return f"{TOKEN_COOKIE}={self.token}; Path=/; HttpOnly; SameSite=Strict"

    def refusal(self, headers, query: str, websocket: bool) -> tuple[int, str] | None:
        """(status, reason) when the request must be refused, else None.
        `headers`: a mapping with .get() of lower-case names."""
        if not self.host_allowed(headers.get("host")):
            return 403, f"Host {headers.get('host')!r} refused (not this server's name; see --allow-host)"
        if websocket and not self.origin_allowed(headers.get("origin")):
            return 403, f"WebSocket from {headers.get('origin')} refused"
        authorised, _ = self.token_given(query, headers.get("cookie"))
        if not authorised:
            return 401, "access token missing or wrong: open the URL the console printed (it has ?token=)"
        return None


class _Headers:
    """An ASGI scope's headers as a case-insensitive mapping (first value wins)."""

    def __init__(self, raw) -> None:
        self._d: dict[str, str] = {}
        for name, value in raw:
            self._d.setdefault(name.decode("latin-1").lower(), value.decode("latin-1"))

    def get(self, name: str, default=None):
        return self._d.get(name.lower(), default)


class RequestGuard:
    def __init__(self, app, *, max_body_bytes: int = MAX_BODY_BYTES, max_websockets: int = MAX_WEBSOCKETS,
                 policy: AccessPolicy | None = None) -> None:
        if max_body_bytes < 0 or max_websockets < 1:
            raise ValueError("max_body_bytes must be >= 0 and max_websockets >= 1")
        self.app = app
        self.policy = policy or AccessPolicy()
        self.max_body_bytes = max_body_bytes
        self.max_websockets = max_websockets
        self.open_websockets = 0
        self.refused = {"body_too_large": 0, "websockets_over_cap": 0, "host": 0, "token": 0}
        self._last_log = 0.0

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = _Headers(scope.get("headers", ()))
        query = scope.get("query_string", b"").decode("latin-1")
        websocket = scope["type"] == "websocket"
        refusal = self.policy.refusal(headers, query, websocket)
        if refusal is not None:
            status, reason = refusal
            self._note("host" if status == 403 else "token", reason)
            if websocket:
                await receive()  # websocket.connect
                # Closed before the handshake: the client sees HTTP 403.
                await send({"type": "websocket.close", "code": 1008, "reason": reason})
            else:
                await _send_json(send, status, {"detail": reason})
            return
        if not websocket and self.policy.token is not None and self.policy.token_given(query, None)[1]:
            send = _with_cookie(send, self.policy.set_cookie_header())
        if websocket:
            await self._websocket(scope, receive, send)
        else:
            await self._http(scope, receive, send)

    def _note(self, what: str, text: str) -> None:
        self.refused[what] += 1
        now = time.monotonic()
        if now - self._last_log >= 1.0:  # at most a line a second under a flood
            self._last_log = now
            log.warning("%s (refused so far: %s)", text, self.refused)

    async def _http(self, scope, receive, send) -> None:
        length = None
        for name, value in scope.get("headers", ()):
            if name == b"content-length":
                try:
                    length = int(value)
                except ValueError:
                    length = -1
        if length is not None and (length < 0 or length > self.max_body_bytes):
            self._note("body_too_large", f"request body of {length} bytes refused")
            await _send_413(send, self.max_body_bytes)
            return
        started = refused = False
        seen = 0

        async def counting_receive():
            # Past the limit: answer 413 ourselves, and tell the app the
            # client has gone (it stops reading; what it answers is dropped).
            nonlocal seen, refused
            if refused:
                return {"type": "http.disconnect"}
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.max_body_bytes:
                    refused = True
                    self._note("body_too_large", f"chunked request body over {self.max_body_bytes} bytes refused")
                    if not started:
                        await _send_413(send, self.max_body_bytes)
                    return {"type": "http.disconnect"}
            return message

        async def watching_send(message) -> None:
            nonlocal started
            if refused:
                return
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, counting_receive, watching_send)
        except Exception:
            if not refused:
                raise

    async def _websocket(self, scope, receive, send) -> None:
        if self.open_websockets >= self.max_websockets:
            self._note("websockets_over_cap", f"WebSocket refused: {self.open_websockets} open already")
            message = await receive()  # websocket.connect
            if message["type"] == "websocket.connect":
                # Accepted only to be closed with a reason: a close before the
                # handshake reaches a browser as a bare failure (HTTP 403).
                await send({"type": "websocket.accept"})
                await send({"type": "websocket.close", "code": 1013,
                            "reason": f"too many WebSocket clients (at most {self.max_websockets})"})
            return
        self.open_websockets += 1
        try:
            await self.app(scope, receive, send)
        finally:
            self.open_websockets -= 1


async def _send_json(send, status: int, doc: dict, close: bool = False) -> None:
    body = json.dumps(doc).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
    if close:
        headers.append((b"connection", b"close"))
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": body})


async def _send_413(send, limit: int) -> None:
    await _send_json(send, 413, {"detail": f"request body too large: at most {limit} bytes"}, close=True)


def _with_cookie(send, cookie: str):
    async def send_with_cookie(message) -> None:
        if message["type"] == "http.response.start":
            message = {**message, "headers": [*message.get("headers", []), (b"set-cookie", cookie.encode())]}
        await send(message)

    return send_with_cookie


# ----------------------------------------------------------------------
# The 3D scene's port
# ----------------------------------------------------------------------
#
# viser serves its page and its WebSocket from a `websockets` server of its
# own, on its own port, with no hook for checking requests.  Its HTTP handler
# is the `process_request` it hands to `websockets.asyncio.server.serve`, so
# `guard_viser` gives viser's module a `websockets` whose `serve` puts the
# policy's check in front of that handler, for the page, its files and the
# WebSocket alike.  Only viser's module sees the wrapper; uvicorn's
# WebSockets are untouched.  One policy for every scene in the process (the
# one of the last console started).  Tested against viser 1.1.1
# (tests/console/test_access.py); if a future viser stops calling
# `websockets.asyncio.server.serve` from `viser.infra._infra`, `guard_viser`
# raises instead of serving an unguarded scene.

_viser_policy: AccessPolicy | None = None


class _Namespace:
    """An attribute view of `real`, with some attributes replaced."""

    def __init__(self, real, **replaced) -> None:
        self._real = real
        self.__dict__.update(replaced)

    def __getattr__(self, name):
        return getattr(self._real, name)


def guard_viser(policy: AccessPolicy) -> None:
    """Make every viser server started from now on apply `policy`."""
    global _viser_policy
    import http

    import websockets.asyncio.server
    from viser.infra import _infra

    _viser_policy = policy
    if isinstance(_infra.websockets, _Namespace):
        return
    if getattr(_infra, "websockets", None) is not websockets or not hasattr(websockets.asyncio.server, "serve"):
        raise RuntimeError("this viser does not serve through websockets.asyncio.server.serve: "
                           "the 3D scene's port cannot be guarded")
    real_serve = websockets.asyncio.server.serve

    def serve(handler, *args, process_request=None, **kwargs):
        def checked(connection, request):
            policy = _viser_policy or AccessPolicy()
            query = request.path.partition("?")[2]
            is_websocket = (request.headers.get("Upgrade") or "").lower() == "websocket"
            refusal = policy.refusal(request.headers, query, is_websocket)
            if refusal is not None:
                status, reason = refusal
                log.warning("3D scene: %s", reason)
                return connection.respond(http.HTTPStatus(status), reason + "\n")
            response = process_request(connection, request) if process_request is not None else None
            if response is not None and policy.token is not None and policy.token_given(query, None)[1]:
                response.headers["Set-Cookie"] = policy.set_cookie_header()
            return response

        return real_serve(handler, *args, process_request=checked, **kwargs)

    server = _Namespace(websockets.asyncio.server, serve=serve)
    _infra.websockets = _Namespace(websockets, asyncio=_Namespace(websockets.asyncio, server=server))
