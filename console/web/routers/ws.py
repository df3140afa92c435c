"""The WebSocket at /ws: telemetry out, the holder's velocity in.

Query: `name` (how other clients see this one), `scene_key` (the key this
page opened its 3D scene with, so that the scene may order while the page
holds control; see `control`).

Server to client (JSON text messages: "type" and the fields named, flat):
  hello      {client_id, config}: once, first; the page's id for REST and take
  telemetry  {pose, link, image, velocity_wish, orders, log, replaying, control}
             at `telemetry_hz`; `control.you` says whether this client drives
  image      {image: <image state>}: a new picture was decoded (fetch the PNG)
  log        {entry: {t, text}}
  order      {order: <order info>}: an order was queued or changed its fate
             (`state`, a console/session/fates.py Fate, with `reason`, `text`, `outcome`)
  wish       {wish: {vx, vy, vz, vyaw}}: the velocity wish changed (whoever changed it)
  target     {target: {x_m, y_m, z_m, yaw_deg, sent, order_id, points} | null}: the shared target
  control    {control}: the holder changed (also in every telemetry)
  failsafe   {failsafe, t}: the ROV's FAILSAFE flag changed (in a reply at session time t)
  error      {message}: a message of ours was refused
Client to server:
  velocity   {vx, vy, vz, vyaw} fractions -1..1, from the holder only; repeat it
             while it is not neutral, it falls back to neutral after
             `velocity_deadman_s` without one
  stop       STOP, from anyone

Plan: one task sends, the receive loop only reads: a socket has one writer.
Operator events arrive on any thread and reach the sender through a bounded
queue fed with call_soon_threadsafe; when a slow page lets it fill, the
oldest event goes (the next telemetry carries the truth anyway).  Closing
the socket releases control if this client held it; a connection that failed
(not closed by the page) gives it back when the same page (its `scene_key`)
reconnects within the desk's `resume_s`.  A value json cannot write is sent
as its Python value or in words, never cuts the page off; a telemetry tick
that fails is skipped and logged.  Pages of other sites (Origin not ours) are
refused before the hello.
"""

from __future__ import annotations

import asyncio
import collections
import json
import logging

from fastapi import APIRouter, WebSocket, WebSocketDisconnect
from pydantic import ValidationError

from rovlink.console import control
from rovlink.console.control import Caller, NotHolder
from rovlink.console.session.base import OrderError

from ..deps import DeskDep, OperatorDep
from ..errors import describe, same_origin
from ..models import VelocityOrder
from ..telemetry import finite

log = logging.getLogger("rovlink.console.web.ws")

router = APIRouter(tags=["ws"])

INBOX_MAX = 64  # a page's messages waiting to be carried out, at most (velocities coalesce)
PAGE_CLOSED = (1000, 1001)  # the page closed its socket (closed, navigated away): nothing failed
TELEMETRY_FAILING_S = 3.0  # telemetry that cannot be made this long ends the page's socket

EVENT_TOPICS = {"image": "image", "log": "entry", "order": "order", "wish": "wish", "target": "target"}


@router.websocket("/ws")
async def telemetry_socket(websocket: WebSocket, operator: OperatorDep, desk: DeskDep) -> None:
    app = websocket.app
    config = app.state.config
    if not same_origin(websocket.headers):
        # Browsers let any site open a WebSocket here; only our page may.
        await websocket.close(code=1008, reason="cross-site WebSocket refused")
        return
    await websocket.accept()
    client = desk.connect(websocket.query_params.get("name", "")[:40],
                          scene_key=websocket.query_params.get("scene_key"))
    loop = asyncio.get_running_loop()
    outbox: asyncio.Queue = asyncio.Queue(maxsize=256)

    def post(message: dict) -> None:  # in the loop
        if outbox.full():
            outbox.get_nowait()
        outbox.put_nowait(message)

    failsafe_seen = [False]

    def on_event(topic: str, payload) -> None:  # any thread
        if topic == "pose":
            if bool(payload.get("failsafe")) == failsafe_seen[0]:
                return
            # The ROV says FAILSAFE in the first reply after a silence and
            # clears it soon after: a flag that short could fall between two
            # telemetry ticks, so its changes are events of their own.
            failsafe_seen[0] = not failsafe_seen[0]
            message = {"type": "failsafe", "failsafe": failsafe_seen[0], "t": payload["t"]}
        elif topic in EVENT_TOPICS:
            message = {"type": topic, EVENT_TOPICS[topic]: finite(payload)}
        else:
            return
        try:
            loop.call_soon_threadsafe(post, message)
        except RuntimeError:  # loop closed
            pass

    def tick_and_state(control_version: int) -> tuple[dict | None, dict]:
        # (a worker thread: the desk's and the session's locks may be held a while by an
        # order waiting on the link process, and the loop must go on reading the page,
        # its pongs included)
        desk.tick()
        control = desk.status(client.id) if desk.version != control_version else None
        return control, app.state.snapshot.get(client.id)

    async def send_loop() -> None:
        period = 1.0 / config["telemetry_hz"]
        control_version = desk.version
        await websocket.send_text(_dumps({"type": "hello", "client_id": client.id, "config": config}))
        next_at = loop.time()
        failing_since = None
        while True:
            # Events between telemetry ticks; a busy outbox never delays a tick.
            wait = next_at - loop.time()
            if wait > 0:
                try:
                    async with asyncio.timeout(wait):
                        message = await outbox.get()
                    await websocket.send_text(_dumps(message))
                    continue
                except TimeoutError:
                    pass
            next_at = max(next_at + period, loop.time())
            version = desk.version
            try:
                control, state = await asyncio.to_thread(tick_and_state, control_version)
            except Exception:
                # A tick that failed is skipped, and said; one that keeps failing ends the
                # socket (a page without telemetry must not look alive).
                if failing_since is None:
                    log.exception("telemetry to %s failed", client.name)
                    failing_since = loop.time()
                elif loop.time() - failing_since > TELEMETRY_FAILING_S:
                    log.error("telemetry to %s failing for %g s: closing its socket", client.name,
                              TELEMETRY_FAILING_S)
                    await websocket.close(1011)
                    return
                continue
            failing_since = None
            if control is not None:
                control_version = version
                await websocket.send_text(_dumps({"type": "control", "control": control}))
            await websocket.send_text(_dumps({"type": "telemetry", **state}))

    async def send_or_close() -> None:
        try:
            await send_loop()
        except (WebSocketDisconnect, OSError):
            pass  # the page is gone; the receive loop learns it too
        except RuntimeError as exc:  # Starlette: a send after the socket closed
            log.debug("telemetry to %s ended: %s", client.name, exc)
        except Exception:
            log.exception("telemetry to %s failed", client.name)
            await websocket.close(1011)

    # What the page sends is carried out in a worker thread, in order, one at a time:
    # an order may wait on the link process (2 s at most), and meanwhile the loop goes
    # on reading, so a pong is never stuck behind it (the keepalive would close the
    # page's socket, and its control with it).  A velocity still waiting when a newer
    # one comes is replaced by it: the newest wish is the one that counts.
    inbox: collections.deque[str] = collections.deque()
    arrived = asyncio.Event()

    def threadsafe_post(message: dict) -> None:  # a worker thread
        try:
            loop.call_soon_threadsafe(post, message)
        except RuntimeError:  # loop closed
            pass

    async def carry_out() -> None:
        while True:
            await arrived.wait()
            arrived.clear()
            while inbox:
                text = inbox.popleft()
                try:
                    await asyncio.to_thread(_handle, text, client.id, operator, desk, threadsafe_post)
                except Exception as exc:  # said, and the next message is carried out
                    log.exception("a message from %s failed", client.name)
                    post({"type": "error", "message": f"{_kind(text) or 'message'} failed: {exc}"})

    def take(text: str) -> None:
        kind = _kind(text)
        if kind == "stop":  # the wishes before it are over: none is carried out after it
            for old in [m for m in inbox if _kind(m) == "velocity"]:
                inbox.remove(old)
        if inbox and kind == "velocity" and _kind(inbox[-1]) == "velocity":
            inbox[-1] = text
        elif len(inbox) >= INBOX_MAX:
            post({"type": "error", "message": f"message dropped: more than {INBOX_MAX} waiting to be carried out"})
            return
        else:
            inbox.append(text)
        arrived.set()

    unsubscribe = operator.subscribe(on_event)
    sender = asyncio.create_task(send_or_close(), name=f"ws sender {client.name}")
    worker = asyncio.create_task(carry_out(), name=f"ws orders {client.name}")
    how, code = "its WebSocket ended", None
    try:
        while True:
            # A page gone while the sender writes also ends this receive.
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect":
                code = message.get("code")
                how = _how_it_closed(code, message.get("reason"))
                break
            if message.get("text") is None:
                post({"type": "error", "message": "binary messages are not understood; send JSON text"})
                continue
            take(message["text"])
    except WebSocketDisconnect as exc:
        code = exc.code
        how = _how_it_closed(exc.code, exc.reason)
    finally:
        # Release before any await: a cancelled handler must still let go.  A connection
        # that failed (not one the page closed) gives the page its control back if it
        # reconnects in time (control.RESUME_S).
        desk.disconnect(client.id, how, failed=code is not None and code not in PAGE_CLOSED)
        log.info("WebSocket of %s ended: %s", client.name, how)
        unsubscribe()
        sender.cancel()
        worker.cancel()
        await asyncio.gather(sender, worker, return_exceptions=True)


_IN_WORDS: set[type] = set()  # the types already said in the log


def _jsonable(value):
    """What json cannot write as it is: a NumPy number or array as its Python value,
    anything else in words (a page is told the state, never cut off for one value).
    Each such type is said once in the log: it is a slip of whoever made the value."""
    if type(value) not in _IN_WORDS:
        _IN_WORDS.add(type(value))
        log.warning("a value of type %s in a message to the pages (sent as %s)", type(value).__name__,
                    "its Python value" if hasattr(value, "item") else "words")
    for name in ("tolist", "item"):  # NumPy arrays, then NumPy numbers
        method = getattr(value, name, None)
        if callable(method):
            return method()
    if isinstance(value, (set, frozenset)):
        return sorted(value, key=str)
    return str(value)


def _dumps(message: dict) -> str:
    return json.dumps(message, default=_jsonable)


def _kind(text: str) -> str | None:
    """A page's message's type, or None if it has none (`_handle` says what is wrong)."""
    try:
        message = json.loads(text)
    except ValueError:
        return None
    return message.get("type") if isinstance(message, dict) else None


def _how_it_closed(code: int | None, reason: str | None) -> str:
    """A WebSocket's end in words: a page that went away (1000, 1001) or a
    connection that failed (1006, or 1011 when the server's keepalive ping
    went unanswered)."""
    words = {1000: "closed by the page", 1001: "the page went away", 1006: "the connection broke",
             1005: "the connection ended without a closing handshake", 1011: "the connection failed"}.get(code, "its WebSocket closed")
    return f"{words}, code {code}" + (f": {reason}" if reason else "")


def _handle(text: str, client_id: str, operator, desk, post) -> None:
    try:
        message = json.loads(text)
    except ValueError:
        post({"type": "error", "message": "messages must be JSON objects"})
        return
    kind = message.get("type") if isinstance(message, dict) else None
    if kind == "velocity":
        try:
            v = VelocityOrder.model_validate({k: x for k, x in message.items() if k != "type"})
            desk.submit(control.Drive(v.vx, v.vy, v.vz, v.vyaw, streamed=True), Caller(client_id, via="ws"))
        except ValidationError as exc:
            post({"type": "error", "message": f"velocity refused: {describe(exc.errors())}"})
        except (NotHolder, OrderError) as exc:
            post({"type": "error", "message": f"velocity refused: {exc}"})
    elif kind == "stop":
        try:
            desk.submit(control.Stop(), Caller(client_id, via="ws"))
        except (NotHolder, OrderError) as exc:  # said to the page; the socket stays
            post({"type": "error", "message": f"stop refused: {exc}"})
    else:
        post({"type": "error", "message": f"unknown message type {kind!r}; expected 'velocity' or 'stop'"})
