"""Control ownership: who holds it, taking it, giving it back."""

from __future__ import annotations

from fastapi import APIRouter

from ..deps import ClientIdDep, DeskDep
from ..models import ControlStatus, ErrorBody, TakeControl, TakeResult

router = APIRouter(prefix="/api/control", tags=["control"])


@router.get("", response_model=ControlStatus, summary="Who holds control (and whether it is you)")
def get_control(desk: DeskDep, cid: ClientIdDep) -> dict:
    desk.touch(cid)
    return desk.status(cid)


@router.post("/take", response_model=TakeResult,
             responses={422: {"model": ErrorBody, "description": "unknown client id"}},
             summary="Take control, from whoever holds it; without X-Rovlink-Client a new id is issued")
def take_control(desk: DeskDep, cid: ClientIdDep, body: TakeControl | None = None) -> dict:
    client = desk.take(cid, body.name if body else "")
    return {"client_id": client.id, "control": desk.status(client.id)}


@router.post("/release", response_model=ControlStatus,
             responses={409: {"model": ErrorBody, "description": "the caller does not hold control"}},
             summary="Give control back (the velocity wish goes neutral)")
def release_control(desk: DeskDep, cid: ClientIdDep) -> dict:
    desk.release(cid)
    return desk.status(cid)
