"""The HTTP client of the map server (``MapClient``) and the replies it returns.

The replies are the API's own models (``mapserver.api.schemas``), re-exported here:
``ScanAck``, ``MapMeta``, ``CostmapUpdates`` (of ``PatchOut``), ``CellOut``,
``SegmentOut``, ``PlanOut``, ``UnitState`` (with ``UnitPose``; ``ACTIVITIES`` are the
values of its ``activity``); ``Grid`` holds a raw grid.
Importing it loads neither numba, PIL, sqlite3 nor fastapi
(``tests/test_import_directions.py``).
"""

from mapserver.api.schemas import (
    ACTIVITIES,
    CellOut,
    CostmapUpdates,
    MapMeta,
    PatchOut,
    PlanOut,
    ScanAck,
    SegmentOut,
    UnitPose,
    UnitState,
)
from mapserver.client.map_client import (
    Conflict,
    Forbidden,
    Grid,
    InvalidRequest,
    MapClient,
    MapClientError,
    MapProtocolError,
    MapRequestError,
    MapServerError,
    MapServerUnavailable,
    Unauthorized,
)

__all__ = [
    "ACTIVITIES",
    "CellOut",
    "Conflict",
    "CostmapUpdates",
    "Forbidden",
    "Grid",
    "InvalidRequest",
    "MapClient",
    "MapClientError",
    "MapMeta",
    "MapProtocolError",
    "MapRequestError",
    "MapServerError",
    "MapServerUnavailable",
    "PatchOut",
    "PlanOut",
    "ScanAck",
    "SegmentOut",
    "Unauthorized",
    "UnitPose",
    "UnitState",
]
