"""``POST /v1/plan`` (docs/http-api.md 2.6): grid A* or Dijkstra on the current costmap.

One plan computes at a time (the planner's buffers are the grid's size) on a worker
thread; up to ``reads.max_queued_plans`` wait for it and more are refused with 429
(``admission``), so plans never fill the threads or the loop the rest of the API needs.
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import APIRouter, Depends, HTTPException, Request, Response

from mapserver.api.auth import READ, require
from mapserver.api.body import body_schema
from mapserver.api.routes_query import answer_on_worker
from mapserver.api.schemas import ErrorOut, PlanIn, PlanOut
from planner.grid_search import PlanRequestError

router = APIRouter(tags=["plan"], dependencies=[Depends(require(READ))])
logger = logging.getLogger(__name__)


@router.post(
    "/v1/plan",
    response_model=PlanOut,
    responses={status: {"model": ErrorOut} for status in (400, 401, 403, 413, 415, 422, 429)},
    openapi_extra=body_schema(PlanIn),
)
async def plan(request: Request) -> Response:
    """Plan from start to goal on the costmap of one version (NavFn cell weights)."""
    planner = request.app.state.planner

    def respond(query: PlanIn) -> dict[str, Any]:
        try:
            result, version = planner.plan(
                query.start, query.goal, query.algorithm, query.allow_unknown
            )
        except PlanRequestError as exc:
            raise HTTPException(422, str(exc)) from None
        logger.debug("plan for %s: found=%s expanded=%d", query.unit_id, result.found,
                     result.expanded)  # fmt: skip
        return {
            "found": result.found,
            "path": [list(p) for p in result.path],
            "length": result.length,
            "cost": result.cost,
            "min_clearance": result.min_clearance,
            "expanded": result.expanded,
            "planning_ms": result.planning_ms,
            "map_version": version,
        }

    return await answer_on_worker(request, PlanIn, request.app.state.plan_admission, respond)
