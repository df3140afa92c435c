"""Orders to the ROV.  All but STOP need control (409 otherwise); a value the
Operator refuses is a 422 carrying its message (see `create_app`)."""

from __future__ import annotations

from fastapi import APIRouter, Request

from ..deps import ClientIdDep, DeskDep, HolderDep, OperatorDep
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
    desk.rest_velocity(cid, order.vx, order.vy, order.vz, order.vyaw)
    return order.model_dump()


@router.post("/position", response_model=OrderQueued, responses=HOLDER_ONLY,
             summary="Go to a position (GUIDED)")
def post_position(order: PositionOrder, operator: OperatorDep, _: HolderDep) -> dict:
    order_id = operator.send_position(order.x_m, order.y_m, order.z_m, order.yaw_deg, relative=order.relative,
                                      body=order.body)
    return {"id": order_id, "kind": "POSITION"}


@router.post("/position/preview", response_model=PathPreview, responses=INVALID,
             summary="Where a position order would take the vehicle (nothing is sent)")
def preview_position(order: PositionOrder, operator: OperatorDep, request: Request) -> dict:
    if order.relative:
        # The preview works in absolute coordinates; relative targets are the
        # scene's business (it knows the heading it drew them with).
        from rovlink.console.operator import OrderError

        raise OrderError("the preview takes absolute targets only (relative=false)")
    scene = getattr(request.app.state, "scene", None)
    if scene is not None and hasattr(scene, "preview_target_ned"):
        # The 3D view shows the ghost at the target and its path, as if the
        # gizmo had been moved there; still nothing is sent.
        scene.preview_target_ned(order.x_m, order.y_m, order.z_m, order.yaw_deg)
    return {"points": operator.preview_path(order.x_m, order.y_m, order.z_m, order.yaw_deg)}


@router.post("/stop", response_model=OrderQueued,
             responses={409: {"model": ErrorBody, "description": "a replay: there is no ROV"}},
             summary="STOP: neutral velocity, cancel targets, hold depth; anyone may press it")
def post_stop(operator: OperatorDep, desk: DeskDep, cid: ClientIdDep) -> dict:
    desk.check_live()
    desk.touch(cid)
    return {"id": operator.stop(), "kind": "STOP"}


@router.post("/arm", response_model=Requested, responses=HOLDER_ONLY,
             summary="Arm or disarm the thrusters")
def post_arm(order: ArmOrder, operator: OperatorDep, _: HolderDep) -> dict:
    operator.arm(order.armed)
    return {"kind": "ARM" if order.armed else "DISARM"}


@router.post("/mode", response_model=Requested, responses=HOLDER_ONLY,
             summary="Change the flight mode")
def post_mode(order: ModeOrder, operator: OperatorDep, _: HolderDep) -> dict:
    operator.set_mode(order.mode)
    return {"kind": "MODE", "mode": order.mode}
