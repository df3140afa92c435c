"""Dependencies shared by the routers: the Operator, the control desk, the
caller's client id, and the guard that lets only the control holder order.

Everything lives on `app.state` (set by `create_app`), so that two apps in
one process (tests) never share a session."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Header
from starlette.requests import HTTPConnection

from rovlink.console.control import ControlDesk
from rovlink.console.session.contract import VehicleSession


def get_operator(conn: HTTPConnection) -> VehicleSession:
    return conn.app.state.operator


def get_desk(conn: HTTPConnection) -> ControlDesk:
    return conn.app.state.desk


def client_id(x_rovlink_client: Annotated[str | None, Header(
        description="the client id from POST /api/control/take or the WebSocket's hello")] = None) -> str | None:
    return x_rovlink_client or None


OperatorDep = Annotated[VehicleSession, Depends(get_operator)]
DeskDep = Annotated[ControlDesk, Depends(get_desk)]
ClientIdDep = Annotated[str | None, Depends(client_id)]


