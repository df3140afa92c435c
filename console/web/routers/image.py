"""The image being received: progress, the latest decoded picture as PNG, the
raw DEBT prefix, and the settings and skip orders.

The PNG is encoded once per decoded picture (a page refreshes it at every
decode, and several pages may watch), so the last one is kept with the
picture array it was made from: the Operator replaces that array, never
changes it in place.  It also stands in while a new image has no picture
yet (the Operator drops the old one when the next begins)."""

from __future__ import annotations

import io
import threading

from fastapi import APIRouter, HTTPException, Request, Response
from PIL import Image

from rovlink.console import control
from rovlink.console.control import Caller

from ..deps import ClientIdDep, DeskDep, OperatorDep
from ..models import ErrorBody, FollowOrder, ImageSettingsOrder, ImageState, OrderQueued

router = APIRouter(prefix="/api/image", tags=["image"])

NO_STORE = {"Cache-Control": "no-store"}
NOT_YET = {404: {"model": ErrorBody, "description": "no image has arrived yet"}}


class PngCache:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._picture = None
        self._png = b""
        self._state: dict | None = None

    def get(self, picture, state: dict) -> tuple[bytes, dict]:
        """The PNG of `picture` and the image state it was made with."""
        with self._lock:
            if picture is self._picture:
                return self._png, self._state
        buf = io.BytesIO()
        Image.fromarray(picture).save(buf, format="PNG", compress_level=1)
        png = buf.getvalue()
        with self._lock:
            self._picture, self._png, self._state = picture, png, state
        return png, state

    def last(self) -> tuple[bytes, dict] | None:
        with self._lock:
            return (self._png, self._state) if self._state is not None else None


def _headers(state: dict, nbytes: int) -> dict:
    return {**NO_STORE, "X-Rovlink-Image": str(state["img"]), "X-Rovlink-Decoded-Bytes": str(nbytes),
            "X-Rovlink-Total-Bytes": str(state["total_bytes"] or 0),
            "X-Rovlink-Complete": "1" if state["complete"] else "0"}


@router.get("", response_model=ImageState, summary="Progress of the image being received")
def get_image(operator: OperatorDep) -> dict:
    return operator.image_state()


@router.get("/latest.png", response_class=Response, responses={
    200: {"content": {"image/png": {}}, "description": "the picture decoded from the longest prefix so far"},
    **NOT_YET}, summary="The latest decoded picture")
def get_png(request: Request, operator: OperatorDep) -> Response:
    # Counters first: the picture read after them is at least as new.
    state = operator.image_state()
    picture = operator.picture()
    cache: PngCache = request.app.state.png_cache
    if picture is not None:
        png, state = cache.get(picture, state)
    elif (last := cache.last()) is not None:
        # A new image has started and has no picture yet: the last one is still the latest.
        png, state = last
    else:
        raise HTTPException(404, "no image decoded yet")
    return Response(png, media_type="image/png", headers=_headers(state, state["decoded_bytes"]))


@router.get("/latest.debt", response_class=Response, responses={
    200: {"content": {"application/octet-stream": {}}, "description": "the DEBT stream prefix received so far"},
    **NOT_YET}, summary="The raw DEBT bytes of the latest image (decode with debt.decode)")
def get_debt(operator: OperatorDep) -> Response:
    state = operator.image_state()
    stream = operator.image.stream
    if not stream:
        raise HTTPException(404, "no image bytes received yet")
    return Response(stream, media_type="application/octet-stream",
                    headers={**_headers(state, len(stream)),
                             "Content-Disposition": f'attachment; filename="image-{state["img"]}.debt"'})


@router.post("/settings", response_model=OrderQueued, responses={
    409: {"model": ErrorBody, "description": "the caller does not hold control"},
    422: {"model": ErrorBody, "description": "a setting is malformed or out of range"}},
    summary="ROI, shift, mono and budget for the next images")
def post_settings(order: ImageSettingsOrder, desk: DeskDep, cid: ClientIdDep) -> dict:
    # A field left out keeps its value; only an explicit null clears the ROI.
    roi = order.roi if "roi" in order.model_fields_set else control.KEEP
    order_id = desk.submit(control.ChangeImage(roi=roi, shift=order.shift, mono=order.mono,
                                               budget_bytes=order.budget_bytes), Caller(cid))
    return {"id": order_id, "kind": "IMAGE"}


@router.post("/next", status_code=204, response_class=Response, responses={
    409: {"model": ErrorBody, "description": "the caller does not hold control"}},
    summary="Abandon the image being received and start the next one")
def post_next(desk: DeskDep, cid: ClientIdDep) -> Response:
    desk.submit(control.NextImage(), Caller(cid))
    return Response(status_code=204)


@router.post("/follow", response_model=OrderQueued, responses={
    409: {"model": ErrorBody, "description": "the caller does not hold control"},
    422: {"model": ErrorBody, "description": "no ROI, or a value out of range"}},
    summary="The ROI follows its object (FOLLOW, docs/PROTOCOL.md §10); POST /settings ends it")
def post_follow(order: FollowOrder, desk: DeskDep, cid: ClientIdDep) -> dict:
    order_id = desk.submit(control.FollowRoi(roi=order.roi, keep=order.keep, drawn_on=order.img), Caller(cid))
    return {"id": order_id, "kind": "IMAGE"}
