"""Guards in front of the web console, as plain ASGI middleware.

Goal: no request can make the console's server do much work for nothing.
Nothing the page or a script sends is larger than a few kilobytes, so:

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

import json
import logging
import time

log = logging.getLogger("rovlink.console.web")

MAX_BODY_BYTES = 64 * 1024
MAX_WEBSOCKETS = 64


class RequestGuard:
    def __init__(self, app, *, max_body_bytes: int = MAX_BODY_BYTES, max_websockets: int = MAX_WEBSOCKETS) -> None:
        if max_body_bytes < 0 or max_websockets < 1:
            raise ValueError("max_body_bytes must be >= 0 and max_websockets >= 1")
        self.app = app
        self.max_body_bytes = max_body_bytes
        self.max_websockets = max_websockets
        self.open_websockets = 0
        self.refused = {"body_too_large": 0, "websockets_over_cap": 0}
        self._last_log = 0.0

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] == "http":
            await self._http(scope, receive, send)
        elif scope["type"] == "websocket":
            await self._websocket(scope, receive, send)
        else:
            await self.app(scope, receive, send)

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


async def _send_413(send, limit: int) -> None:
    body = json.dumps({"detail": f"request body too large: at most {limit} bytes"}).encode()
    await send({"type": "http.response.start", "status": 413,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": body})
