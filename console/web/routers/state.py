"""Reading the session: the whole state at once, or one part of it."""

from __future__ import annotations

from fastapi import APIRouter, Request

from ..deps import ClientIdDep, DeskDep, OperatorDep
from ..models import Config, LogEntry, OrderInfo, PoseState, State
from ..telemetry import finite, snapshot

router = APIRouter(prefix="/api", tags=["state"])


@router.get("/state", response_model=State, summary="Everything the console knows, at once")
def get_state(operator: OperatorDep, desk: DeskDep, cid: ClientIdDep) -> dict:
    desk.touch(cid)
    return finite(snapshot(operator, desk, cid, orders=50, log=20))


@router.get("/pose", response_model=PoseState, summary="Received and predicted pose, armed, mode, failsafe")
def get_pose(operator: OperatorDep) -> dict:
    return finite(operator.pose_state())


@router.get("/orders", response_model=list[OrderInfo], summary="The last 50 one-shot orders and their progress")
def get_orders(operator: OperatorDep) -> list[dict]:
    return operator.orders_state()


@router.get("/log", response_model=list[LogEntry], summary="The log lines kept (the last 500), oldest first")
def get_log(operator: OperatorDep) -> list[dict]:
    return operator.log_entries()


@router.get("/config", response_model=Config, summary="What the operator page needs to start")
def get_config(request: Request) -> dict:
    return request.app.state.config
