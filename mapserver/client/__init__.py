"""The HTTP client of the map server (``MapClient``) and the replies it returns.

Importing it loads neither numba, PIL, sqlite3 nor fastapi
(``tests/test_import_directions.py``).
"""

from mapserver.client.map_client import (
    CellInfo,
    Conflict,
    CostmapUpdates,
    Forbidden,
    Grid,
    InvalidRequest,
    MapClient,
    MapClientError,
    MapMeta,
    MapProtocolError,
    MapRequestError,
    MapServerError,
    MapServerUnavailable,
    PlanResult,
    ScanAck,
    SegmentInfo,
    Unauthorized,
    UnitState,
)

__all__ = [
    "CellInfo",
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
    "PlanResult",
    "ScanAck",
    "SegmentInfo",
    "Unauthorized",
    "UnitState",
]
