"""Link health: poll rate, round trip, losses, errors, throughput, odometry age."""

from __future__ import annotations

from fastapi import APIRouter

from ..deps import OperatorDep
from ..models import LinkState
from ..telemetry import finite

router = APIRouter(prefix="/api", tags=["link"])


@router.get("/link", response_model=LinkState, summary="Link statistics and health")
def get_link(operator: OperatorDep) -> dict:
    # An estimate can be NaN or infinite; JSON cannot carry either.
    return finite(operator.link_state())
