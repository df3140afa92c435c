"""Orders to the ROV: each route builds one typed order of the command layer
(`rovlink.console.control`) and submits it with the caller's client id.  The
desk's permission table decides (STOP open to all, the rest the holder's:
409 otherwise); a value the Operator refuses is a 422 carrying its message
(see `create_app`)."""

from __future__ import annotations

from fastapi import APIRouter, Response

from rovlink.console import control
from rovlink.console.control import Caller
from rovlink.console.session.base import OrderError

from ..deps import ClientIdDep, DeskDep
from ..models import (
    ArmOrder,
    ErrorBody,
    ModeOrder,
    OrderQueued,
    PathPreview,
    PositionOrder,
    Requested,
    VelocityOrder,
    VelocityWish,
)

INVALID = {422: {"model": ErrorBody, "description": "the order is malformed or out of range"}}
HOLDER_ONLY = {409: {"model": ErrorBody, "description": "the caller does not hold control"}, **INVALID}

router = APIRouter(prefix="/api/orders", tags=["orders"])


@router.post("/velocity", response_model=VelocityWish, responses=HOLDER_ONLY,
             summary="Set the velocity wish (standing until changed)")
def post_velocity(order: VelocityOrder, desk: DeskDep, cid: ClientIdDep) -> dict:
    desk.submit(control.Drive(order.vx, order.vy, order.vz, order.vyaw), Caller(cid))
    return order.model_dump()


@router.post("/position", response_model=OrderQueued, responses=HOLDER_ONLY,
             summary="Go to a position: the ROV switches to GUIDED to fly it")
def post_position(order: PositionOrder, desk: DeskDep, cid: ClientIdDep) -> dict:
    order_id = desk.submit(control.GoTo(order.x_m, order.y_m, order.z_m, order.yaw_deg, order.relative,
                                        order.body), Caller(cid))
    return {"id": order_id, "kind": "POSITION", "mode": "GUIDED"}


@router.post("/position/preview", response_model=PathPreview, responses=HOLDER_ONLY,
             summary="Make this the target the 3D view shows (ghost and path); nothing is sent")
def preview_position(order: PositionOrder, desk: DeskDep, cid: ClientIdDep) -> dict:
    if order.relative:
        raise OrderError("the preview takes absolute targets only (relative=false)")
    points = desk.submit(control.PreviewTarget(order.x_m, order.y_m, order.z_m, order.yaw_deg), Caller(cid))
    return {"points": points}


@router.post("/stop", response_model=OrderQueued,
             responses={409: {"model": ErrorBody, "description": "a replay: there is no ROV"}},
             summary="STOP: neutral velocity, cancel targets, hold depth; anyone may press it")
def post_stop(desk: DeskDep, cid: ClientIdDep) -> dict:
    return {"id": desk.submit(control.Stop(), Caller(cid)), "kind": "STOP"}


@router.post("/stop/cancel", status_code=204, response_class=Response, responses=HOLDER_ONLY,
             summary="Give up a STOP the ROV cannot carry out (no autopilot), so that a DISARM can go out")
def cancel_stop(desk: DeskDep, cid: ClientIdDep) -> Response:
    desk.submit(control.CancelStop(), Caller(cid))
    return Response(status_code=204)


@router.post("/arm", response_model=Requested, responses=HOLDER_ONLY,
             summary="Arm or disarm the thrusters (followed until the vehicle does, or refused after 3 s)")
def post_arm(order: ArmOrder, desk: DeskDep, cid: ClientIdDep) -> dict:
    order_id = desk.submit(control.Arm(order.armed), Caller(cid))
    return {"kind": "ARM" if order.armed else "DISARM", "id": order_id}


@router.post("/mode", response_model=Requested, responses=HOLDER_ONLY,
             summary="Change the flight mode (followed until the vehicle does, or refused after 3 s)")
def post_mode(order: ModeOrder, desk: DeskDep, cid: ClientIdDep) -> dict:
    order_id = desk.submit(control.SetMode(order.mode), Caller(cid))
    return {"kind": "MODE", "mode": order.mode, "id": order_id}
