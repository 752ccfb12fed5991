"""The planner the API plans with, injected through ``create_app`` (``planner_factory``):
``mapserver`` outside its API knows nothing of ``planner`` (tests/test_import_directions.py).

One planner is made on the first plan, for the service's grid, and plans one at a time:
its search buffers are the grid's size.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from mapserver.core.geometry import GridGeometry
from mapserver.service.map_service import MapService


class GridPlanning(Protocol):
    """What the API needs of a planner: a plan on a costmap (``planner.GridPlanner``)."""

    def plan(
        self,
        costs: np.ndarray,
        start: tuple[float, float],
        goal: tuple[float, float],
        algorithm: str,
        allow_unknown: bool,
        bounds: np.ndarray | None = None,
    ) -> Any: ...


class CostmapPlanner:
    """Plans on the service's current costmap with a planner from ``factory(geometry)``."""

    def __init__(self, service: MapService, factory: Callable[[GridGeometry], GridPlanning]):
        self.service = service
        self.factory = factory
        self._planner: GridPlanning | None = None
        self._lock = threading.Lock()

    def plan(
        self,
        start: tuple[float, float],
        goal: tuple[float, float],
        algorithm: str = "astar",
        allow_unknown: bool = True,
    ) -> tuple[Any, int]:
        """A plan on the current costmap and that costmap's version."""
        read = self.service.costmap_read()
        with self._lock:
            if self._planner is None:
                self._planner = self.factory(self.service.geometry)
            bounds = self.service.planning_bounds
            extra = {} if bounds is None else {"bounds": bounds}
            return self._planner.plan(
                read.data, start, goal, algorithm, allow_unknown, **extra
            ), read.version
