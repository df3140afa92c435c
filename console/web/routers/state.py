"""Reading the session: the whole state at once, or one part of it (and "Frame it", an
order on the world's objects, beside the world it reads)."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request

from rovlink.console import control
from rovlink.console.control import Caller

from ..deps import ClientIdDep, DeskDep, OperatorDep
from ..models import Config, ErrorBody, FrameQueued, LogEntry, OrderInfo, PoseState, State, WorldState
from ..telemetry import finite, snapshot

router = APIRouter(prefix="/api", tags=["state"])


@router.get("/state", response_model=State, summary="Everything the console knows, at once")
def get_state(operator: OperatorDep, desk: DeskDep, cid: ClientIdDep) -> dict:
    desk.touch(cid)
    return finite(snapshot(operator, desk, cid, orders=50, log=20))


@router.get("/pose", response_model=PoseState, summary="Received and predicted pose, armed, mode, failsafe")
def get_pose(operator: OperatorDep) -> dict:
    return finite(operator.pose_state())


@router.get("/world", response_model=WorldState,
            summary="The world the ROV measured: the seabed's depth and the objects it recognised")
def get_world(operator: OperatorDep) -> dict:
    return finite(operator.world_state())


@router.get("/world/objects/{object_id}/approach", summary="A go-to target short of an object, facing it",
            responses={404: {"model": ErrorBody}})
def get_approach(object_id: int, operator: OperatorDep) -> dict:
    """Where a go-to to the object would stop (its stand-off), for the page to preview and send."""
    target = operator.object_approach(object_id)
    if target is None:
        raise HTTPException(404, f"no object #{object_id}: the ROV does not hold it (or no pose yet)")
    return target


@router.post("/world/objects/{object_id}/frame", response_model=FrameQueued, summary="Frame it: the next picture's "
             "ROI on an object, and FOLLOW where the link carries it", responses={
                 409: {"model": ErrorBody, "description": "the caller does not hold control, or the object is not "
                                                          "in view from where the ROV is (said in one line)"},
                 422: {"model": ErrorBody, "description": "no such object"}})
def post_frame(object_id: int, desk: DeskDep, cid: ClientIdDep) -> dict:
    return desk.submit(control.FrameObject(object_id), Caller(cid))


@router.get("/orders", response_model=list[OrderInfo], summary="The last 50 one-shot orders and their progress")
def get_orders(operator: OperatorDep) -> list[dict]:
    return operator.orders_state()


@router.get("/log", response_model=list[LogEntry], summary="The log lines kept (the last 500), oldest first")
def get_log(operator: OperatorDep) -> list[dict]:
    return operator.log_entries()


@router.get("/config", response_model=Config, summary="What the operator page needs to start")
def get_config(request: Request) -> dict:
    return request.app.state.config
