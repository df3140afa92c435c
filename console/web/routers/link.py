"""Link health: poll rate, round trip, losses, errors, throughput, odometry age."""

from __future__ import annotations

from fastapi import APIRouter

from ..deps import OperatorDep
from ..models import LinkState

router = APIRouter(prefix="/api", tags=["link"])


@router.get("/link", response_model=LinkState, summary="Link statistics and health")
def get_link(operator: OperatorDep) -> dict:
    return operator.link_state()
