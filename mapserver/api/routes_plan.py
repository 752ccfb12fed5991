"""``POST /v1/plan`` (CONTRACT 2.6): grid A* or Dijkstra on the current costmap."""

from __future__ import annotations

import logging

from fastapi import APIRouter, Depends, HTTPException, Request

from mapserver.api.auth import READ, require
from mapserver.api.schemas import ErrorOut, PlanIn, PlanOut
from planner.grid_search import PlanRequestError

router = APIRouter(tags=["plan"], dependencies=[Depends(require(READ))])
logger = logging.getLogger(__name__)


@router.post(
    "/v1/plan",
    response_model=PlanOut,
    responses={status: {"model": ErrorOut} for status in (401, 403, 422)},
)
def plan(request: Request, body: PlanIn) -> PlanOut:
    """Plan from start to goal on the costmap of one version (NavFn cell weights)."""
    service = request.app.state.service
    try:
        result, version = service.plan(body.start, body.goal, body.algorithm, body.allow_unknown)
    except PlanRequestError as exc:
        raise HTTPException(422, str(exc)) from None
    logger.debug("plan for %s: found=%s expanded=%d", body.unit_id, result.found, result.expanded)
    return PlanOut(
        found=result.found,
        path=[list(p) for p in result.path],
        length=result.length,
        cost=result.cost,
        min_clearance=result.min_clearance,
        expanded=result.expanded,
        planning_ms=result.planning_ms,
        map_version=version,
    )
