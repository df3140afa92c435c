"""The acoustic console's web app: the page at /, the API under /api.

GET  /api/state            everything the page shows, each value with its age
POST /api/stop             STOP: first, every time (no control needed)
POST /api/order            {"order": "hold"|"surface"|"arm"|"disarm"|"mode", "mode": "POS_HOLD"}
POST /api/goto             {"x_m", "y_m", "z_m", "yaw_deg"?, "relative"?, "body"?}
POST /api/thumbnail        {"budget"?: 198, "roi"?: [x0, y0, x1, y1] in 80x60 pixels, "shift"?: 4}
GET  /api/thumbnail.png    the thumbnail as it stands (404 before any)

Bad requests get 422 with the field named, orders the link cannot take now
(no status yet, a STOP unconfirmed) 409 with the reason, a POST from another
site's page 403; every error body has `detail` and `message`.  The same
request guard (Host names, access token off loopback, body size) and error
answers (console/web/errors.py) as the radio console's.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import FastAPI, HTTPException
from fastapi.responses import FileResponse, Response
from pydantic import BaseModel, Field

from rovlink.console.web import errors
from rovlink.console.web.guard import AccessPolicy, RequestGuard

from .session import AcousticSession

STATIC = Path(__file__).with_name("static")


class OrderIn(BaseModel):
    order: str = Field(description="hold, surface, arm, disarm or mode")
    mode: str | None = Field(None, description="for order mode: MANUAL, STABILIZE, DEPTH_HOLD, POS_HOLD, GUIDED, SURFACE")


class GoToIn(BaseModel):
    x_m: float
    y_m: float
    z_m: float = Field(description="depth, metres down (relative: metres further down)")
    yaw_deg: float | None = None
    relative: bool = False
    body: bool = False


class ThumbIn(BaseModel):
    budget: int = 198
    roi: tuple[int, int, int, int] | None = Field(None, description="x0, y0, x1, y1 in the 80x60 thumbnail")
    shift: int = Field(4, ge=0, le=15)


def create_acoustic_app(session: AcousticSession, *, policy: AccessPolicy | None = None) -> FastAPI:
    app = FastAPI(title="rovlink acoustic console", version="1",
                  summary="Supervise an ROV over a 64 bit/s acoustic link (docs/PROTOCOL.md §9)")
    # The radio console's answers: a POST from another site's page refused (403: any
    # page the pilot has open could otherwise send a go-to through the pilot's
    # browser), every error as {detail, message}, a body that is no JSON object 422.
    errors.install(app)

    def _do(fn, *args, **kw) -> dict:
        try:
            return fn(*args, **kw)
        except ValueError as exc:
            raise HTTPException(422, str(exc)) from None
        except PermissionError as exc:
            raise HTTPException(409, str(exc)) from None

    @app.get("/api/state")
    def state() -> dict:
        return session.state()

    @app.post("/api/stop")
    def stop() -> dict:
        return session.press_stop()

    @app.post("/api/order")
    def order(body: OrderIn) -> dict:
        return _do(session.order, body.order, body.mode)

    @app.post("/api/goto")
    def goto(body: GoToIn) -> dict:
        return _do(session.goto, body.x_m, body.y_m, body.z_m, body.yaw_deg, relative=body.relative, body=body.body)

    @app.post("/api/thumbnail")
    def thumbnail(body: ThumbIn) -> dict:
        return _do(session.thumbnail, body.budget, body.roi, body.shift)

    @app.get("/api/thumbnail.png")
    def thumbnail_png() -> Response:
        png = session.thumbnail_png()
        if png is None:
            raise HTTPException(404, "no thumbnail yet")
        return Response(png, media_type="image/png", headers={"Cache-Control": "no-store"})

    @app.get("/", include_in_schema=False)
    def page() -> FileResponse:
        return FileResponse(STATIC / "acoustic.html", headers={"Cache-Control": "no-cache"})

    app.add_middleware(RequestGuard, policy=policy or AccessPolicy())
    return app
