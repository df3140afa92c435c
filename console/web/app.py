"""The operator's web console: the page at /, the REST API under /api, the
telemetry WebSocket at /ws, the OpenAPI schema at /openapi.json.

Goals: a pilot with a browser (keyboard or gamepad) and a script with an
HTTP client drive the ROV through the same API, one at a time; everything
the console knows can be read by anyone watching.  The app never owns the
session: the caller creates the Operator, runs `operator.run()` in the loop
uvicorn runs in, and hands both to us.

Plan: FastAPI's "bigger applications" layout.  `create_app` puts the
Operator, the control desk (`rovlink.console.control.ControlDesk`: the one command layer), the shared snapshot and
the page's configuration on `app.state`; the routers (state, orders, image,
link, control, ws) reach them through the dependencies in `deps`.  A
lifespan task ticks the desk's timers (script leases, the velocity dead man)
even when no page is connected.  `serve` binds the socket itself, so that a
port in use is an OSError the CLI can report (uvicorn would exit the
process), and stops gracefully when cancelled.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
from pathlib import Path

from fastapi import FastAPI
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

from rovlink.console.control import DEADMAN_S, LEASE_S, UNATTENDED_WARN_S, ControlDesk, page_config
from rovlink.console.session.contract import VehicleSession

from . import errors
from .guard import MAX_BODY_BYTES, MAX_WEBSOCKETS, AccessPolicy, RequestGuard
from .routers import control, image, images, link, orders, replay, state, ws
from .routers.image import PngCache
from .telemetry import SharedSnapshot

log = logging.getLogger("rovlink.console.web")

STATIC = Path(__file__).with_name("static")


def create_app(operator: VehicleSession, *, viser_url: str | None = None, scene=None, telemetry_hz: float = 10.0,
               lease_s: float = LEASE_S, velocity_deadman_s: float = DEADMAN_S, max_body_bytes: int = MAX_BODY_BYTES,
               max_websockets: int = MAX_WEBSOCKETS, policy: AccessPolicy | None = None,
               unattended_warn_s: float = UNATTENDED_WARN_S, disarm_unattended_s: float | None = None,
               rov_failsafe_s: float | None = None) -> FastAPI:
    """The web console for `operator` (which the caller runs).

    `viser_url` is the 3D scene the page embeds (none shown if None); `scene`
    is kept on `app.state.scene` for whoever needs it, and its viewers order
    only for the page holding control (it orders through this app's desk).  `lease_s`: a script
    holding control and silent that long loses it.  `velocity_deadman_s`: a
    velocity streamed over a WebSocket goes neutral when not repeated within it.
    `unattended_warn_s`: armed with nobody in control this long, every page is
    warned; `disarm_unattended_s`: ... and this long, the console disarms (off
    when None).  `rov_failsafe_s`: the ROV's failsafe time (the operator's own
    value, 3 s, when None), after which a lost link means an ROV in FAILSAFE.
    """
    for name, value in (("telemetry_hz", telemetry_hz), ("lease_s", lease_s),
                        ("velocity_deadman_s", velocity_deadman_s)):
        if not value > 0:
            raise ValueError(f"{name} must be positive, got {value!r}")
    desk = ControlDesk(operator, lease_s=lease_s, deadman_s=velocity_deadman_s,
                       unattended_warn_s=unattended_warn_s, disarm_unattended_s=disarm_unattended_s)
    if rov_failsafe_s is not None:
        operator.rov_failsafe_s = float(rov_failsafe_s)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):
        async def tick() -> None:
            while True:
                await asyncio.sleep(0.25)
                try:
                    desk.tick()
                except Exception:  # a timer must outlive one bad tick
                    log.exception("control desk tick failed")

        task = asyncio.create_task(tick(), name="control desk")
        try:
            yield
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    app = FastAPI(
        title="rovlink console",
        summary="Teleoperate an underwater ROV over a ~1.9 kbit/s link",
        description=(
            "Read the session (pose, link health, image) freely; orders need control: "
            "`POST /api/control/take`, then send the returned id as `X-Rovlink-Client`. "
            "STOP is accepted from anyone. Telemetry streams on the WebSocket `/ws`:\n\n"
            "```\n" + _ws_protocol() + "\n```"
        ),
        version="1",
        lifespan=lifespan,
    )
    app.state.operator = operator
    app.state.scene = scene
    app.state.desk = desk
    if scene is not None and hasattr(scene, "use_desk"):
        scene.use_desk(desk)  # its viewers order through the same desk
    # Shared by all pages, but younger than a telemetry period: a snapshot
    # reused by the next tick would repeat the same predicted pose.
    app.state.snapshot = SharedSnapshot(operator, desk, max_age_s=min(0.04, 0.5 / float(telemetry_hz)))
    app.state.png_cache = PngCache()
    caps = operator.capabilities
    app.state.config = page_config(
        capabilities=caps.as_dict(), image_budget_max=caps.image_budget_max,
        viser_url=viser_url, telemetry_hz=float(telemetry_hz), velocity_deadman_s=float(velocity_deadman_s),
        lease_s=float(lease_s), lost_after_s=operator.lost_after_s, rov_failsafe_s=operator.rov_failsafe_s,
        unattended_warn_s=float(unattended_warn_s),
        disarm_unattended_s=None if disarm_unattended_s is None else float(disarm_unattended_s))
    errors.install(app)
    for module in (state, orders, image, images, link, control, ws):
        app.include_router(module.router)
    app.include_router(replay.router)  # GET/POST /api/replay: the replay's timeline
    app.mount("/static", StaticFiles(directory=STATIC), name="static")
    # Outermost: a large body is refused before anything reads it (guard.py).
    # `policy`: who may connect (Host names, access token); loopback only by default.
    app.add_middleware(RequestGuard, max_body_bytes=max_body_bytes, max_websockets=max_websockets,
                       policy=policy or AccessPolicy())

    @app.get("/", include_in_schema=False)
    def operator_page() -> FileResponse:
        return FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-cache"})

    return app


def _ws_protocol() -> str:
    """The WebSocket's messages, as its module documents them (OpenAPI has no place for them)."""
    doc = ws.__doc__ or ""
    start, end = doc.find("Server to client"), doc.find("\n\nPlan:")
    return doc[start:end if end > 0 else None].strip()


def _bind(host: str, port: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
        sock.listen(128)
    except OSError:
        sock.close()
        raise
    sock.set_inheritable(True)
    return sock


def _quiet_server_class():
    import uvicorn

    class QuietServer(uvicorn.Server):
        """uvicorn without its own signal handling.

        The program that owns the event loop (rovlink demo/console/replay)
        decides what Ctrl-C means; uvicorn's handler would re-raise the
        signal after its shutdown and cut the vehicle side's teardown short.
        Stop it by cancelling `serve`.
        """

        @contextlib.contextmanager
        def capture_signals(self):
            yield

    return QuietServer


async def serve(app: FastAPI, host: str = "127.0.0.1", port: int = 8000, *,
                sock: socket.socket | None = None, log_level: str = "warning") -> None:
    """Serve `app` with uvicorn in the running loop until cancelled.

    OSError if the address cannot be bound.  `sock`: an already bound,
    listening socket to serve on instead (tests bind port 0 and read it back).
    """
    import uvicorn

    _QuietServer = _quiet_server_class()
    if sock is None:
        sock = _bind(host, port)
    config = uvicorn.Config(app, log_level=log_level, lifespan="on", timeout_graceful_shutdown=2,
                            ws_ping_interval=10, ws_ping_timeout=10)
    server = _QuietServer(config)
    task = asyncio.ensure_future(server.serve(sockets=[sock]))
    try:
        await asyncio.shield(task)
    except asyncio.CancelledError:
        # Let uvicorn close its connections and run the lifespan's end.
        server.should_exit = True
        with contextlib.suppress(Exception, asyncio.CancelledError):
            await asyncio.wait_for(task, 5.0)
        raise
    finally:
        sock.close()
