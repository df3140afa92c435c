"""The replay timeline: where a replayed recording is, pause, resume, seek, speed.

Only a console started by `rovlink replay` has a timeline; GET says
`available: false` elsewhere, and the commands answer 409.  The commands need
no control: nothing of a replay reaches a vehicle (every order is refused),
and whoever may read the console (its Host and token checks apply to every
request) may move through its recording.  A POST from another site's page is
refused like any other (403)."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException
from pydantic import BaseModel, Field

from rovlink.console.replaycontrol import MAX_SPEED, MIN_SPEED, ReplayController, controller_of

from ..deps import OperatorDep
from ..models import ErrorBody, Request

router = APIRouter(prefix="/api/replay", tags=["replay"])

NOT_REPLAYING = {409: {"model": ErrorBody, "description": "this console is not replaying a recording"}}
INVALID = {422: {"model": ErrorBody, "description": "the value is malformed or out of range"}}


class ReplayState(BaseModel):
    available: bool = Field(description="whether this console replays a recording (the rest is null if not)")
    file: str | None = Field(None, description="the recording's file name")
    t: float | None = Field(None, description="session time shown, seconds from the recording's start")
    duration: float | None = Field(None, description="the recording's length in seconds")
    paused: bool | None = None
    ended: bool | None = Field(None, description="the end was reached (resume plays from the start)")
    speed: float | None = Field(None, description="playback factor (1: as recorded)")
    speeds: list[float] = Field(default_factory=list, description="the factors the page offers")
    min_speed: float = MIN_SPEED
    max_speed: float = MAX_SPEED
    seeks: int = Field(0, description="seeks (and restarts from the end) so far: when it changes, what a page "
                                      "keeps of the session's past (its log) was rewritten")


class SeekRequest(Request):
    t: float = Field(ge=0.0, description="session time to show, 0..duration seconds")


class SpeedRequest(Request):
    speed: float = Field(ge=MIN_SPEED, le=MAX_SPEED, description=f"playback factor, {MIN_SPEED:g}..{MAX_SPEED:g}")


def _controller(operator) -> ReplayController:
    controller = controller_of(operator)
    if controller is None:
        raise HTTPException(409, "this console is not replaying a recording (start one with `rovlink replay FILE`)")
    return controller


@router.get("", response_model=ReplayState, summary="The replay's position, length, pause and speed")
def get_replay(operator: OperatorDep) -> dict:
    controller = controller_of(operator)
    return controller.state() if controller is not None else {"available": False}


@router.post("/pause", response_model=ReplayState, responses=NOT_REPLAYING, summary="Pause the replay")
def pause(operator: OperatorDep) -> dict:
    controller = _controller(operator)
    controller.pause()
    return controller.state()


@router.post("/resume", response_model=ReplayState, responses=NOT_REPLAYING,
             summary="Play on (from the start again once the end was reached)")
def resume(operator: OperatorDep) -> dict:
    controller = _controller(operator)
    controller.resume()
    return controller.state()


@router.post("/seek", response_model=ReplayState, responses={**NOT_REPLAYING, **INVALID},
             summary="Show the session as it was at time t (back or forward; a pause stays paused)")
def seek(body: SeekRequest, operator: OperatorDep) -> dict:
    controller = _controller(operator)
    if body.t > controller.duration:
        raise HTTPException(422, f"t must be within the recording, 0..{controller.duration:g} s; got {body.t:g}")
    controller.seek(body.t)
    return controller.state()


@router.post("/speed", response_model=ReplayState, responses={**NOT_REPLAYING, **INVALID},
             summary="Change the playback speed")
def set_speed(body: SpeedRequest, operator: OperatorDep) -> dict:
    controller = _controller(operator)
    controller.set_speed(body.speed)
    return controller.state()
