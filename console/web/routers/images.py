"""Pictures to look back at: the last completed (and abandoned) images with
their metadata, each as PNG and as a sidecar JSON (Save on the page).

The Operator keeps each image's DEBT stream (at most 8 KB), not its picture:
a picture is decoded when first asked for and its PNG kept in a small cache
by serial (`n`, which never wraps, unlike the link's IMG)."""

from __future__ import annotations

import collections
import io
import json
import threading
import time

from fastapi import APIRouter, HTTPException, Query, Request, Response
from PIL import Image, PngImagePlugin

from rovlink import debt
from rovlink.console.session.images import IMAGE_HISTORY

from ...session.state import PastImage
from ..deps import OperatorDep
from ..models import ErrorBody

router = APIRouter(prefix="/api/images", tags=["image"])

PNG_CACHE = 8
NOT_KEPT = {404: {"model": ErrorBody, "description": "no such image is kept (only the last ones are)"},
            422: {"model": ErrorBody, "description": "its bytes cannot be decoded (damaged, or another "
                                                      "DEBT format: an older rovlink's recording)"}}


class HistoryPngs:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._pngs: collections.OrderedDict[int, tuple[bytes, int, int]] = collections.OrderedDict()

    def get(self, entry: dict) -> tuple[bytes, int, int]:
        n = entry["n"]
        with self._lock:
            if n in self._pngs:
                self._pngs.move_to_end(n)
                return self._pngs[n]
        try:
            picture = debt.decode(entry["stream"])
        except ValueError as exc:   # damaged, or another DEBT format (an old recording)
            raise HTTPException(422, f"image {n} cannot be decoded: {exc}") from None
        # The metadata rides in the PNG too (a tEXt chunk "rovlink"), should it travel alone.
        info = PngImagePlugin.PngInfo()
        info.add_text("rovlink", json.dumps(_public(entry)))
        buf = io.BytesIO()
        Image.fromarray(picture).save(buf, format="PNG", compress_level=1, pnginfo=info)
        entry = (buf.getvalue(), picture.shape[1], picture.shape[0])
        with self._lock:
            self._pngs[n] = entry
            while len(self._pngs) > PNG_CACHE:
                self._pngs.popitem(last=False)
        return entry


def _find(operator, n: int) -> dict:
    for entry in operator.image_history():
        if entry["n"] == n:
            return entry
    raise HTTPException(404, f"image {n} is not kept (only the last {IMAGE_HISTORY} are)")


def _pngs(request: Request) -> HistoryPngs:
    cache = getattr(request.app.state, "history_pngs", None)
    if cache is None:
        cache = request.app.state.history_pngs = HistoryPngs()
    return cache


def _stamp(wall: float | None) -> str:
    return "unknown" if wall is None else time.strftime("%Y%m%d-%H%M%S", time.localtime(wall))


def _filename(entry: dict, ext: str) -> str:
    capture = entry.get("capture") or {}
    return f"rov-image-{entry['n']}-{_stamp(capture.get('wall'))}.{ext}"


def _public(entry: dict) -> dict:
    return {k: v for k, v in entry.items() if k != "stream"}


@router.get("", response_model=list[PastImage], summary="The images kept to look back at, oldest first")
def list_images(operator: OperatorDep) -> list[dict]:
    return [_public(e) for e in operator.image_history()]


@router.get("/{n}.png", response_class=Response, responses={
    200: {"content": {"image/png": {}}, "description": "the picture decoded from all the bytes received"},
    **NOT_KEPT}, summary="One kept picture")
def image_png(n: int, request: Request, operator: OperatorDep,
              download: bool = Query(False, description="as an attachment (Save)")) -> Response:
    entry = _find(operator, n)
    png, _, _ = _pngs(request).get(entry)
    headers = {"Cache-Control": "private, max-age=3600"}  # a kept picture never changes
    if download:
        headers["Content-Disposition"] = f'attachment; filename="{_filename(entry, "png")}"'
    return Response(png, media_type="image/png", headers=headers)


@router.get("/{n}.json", responses={200: {"description": "the sidecar metadata of the PNG"}, **NOT_KEPT},
            summary="One kept picture's metadata, the PNG's sidecar")
def image_json(n: int, request: Request, operator: OperatorDep,
               download: bool = Query(False, description="as an attachment (Save)")) -> Response:
    entry = _find(operator, n)
    _, width, height = _pngs(request).get(entry)
    meta = {"picture": _filename(entry, "png"), "width": width, "height": height,
            "protocol_version": operator.link_version, "replay": operator.replaying, **_public(entry)}
    headers = {"Cache-Control": "no-store"}
    if download:
        headers["Content-Disposition"] = f'attachment; filename="{_filename(entry, "json")}"'
    return Response(json.dumps(meta, indent=2), media_type="application/json", headers=headers)
