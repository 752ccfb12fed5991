"""The cheapest the live costmap can be: the static map's costs, unknown as free, inflated.

The live costmap composes the static layer, the obstacle layer (MaxWithoutUnknownOverwrite:
it raises a cell above the static cost, or fills one the static map leaves unknown) and
the inflation of every LETHAL cell. Each of the static map's LETHAL cells therefore stays
LETHAL, and its inflation stays at least as high; every other cell costs at least FREE.
So the static map with UNKNOWN read as FREE, inflated alone, is at or below the live
costmap in every cell, whatever the scans add or clear. A planner may build its
heuristic tables on it once (``planner.grid_search.GridPlanner.plan(bounds=...)``, which
checks the bound on every plan all the same).
"""

from __future__ import annotations

import numpy as np

from mapserver.core.costvalues import FREE, UNKNOWN
from mapserver.core.geometry import GridGeometry
from mapserver.core.inflation import InflationParams
from mapserver.costmap.layered import LayeredCostmap
from mapserver.costmap.layers import InflationLayer, StaticLayer
from mapserver.store.mapfiles import RosMap


def static_lower_bound(
    static: RosMap, inflation: InflationParams, geometry: GridGeometry
) -> np.ndarray:
    """uint8 (height, width) costs at or below the live costmap's in every cell (module
    docstring), read-only."""
    layer = StaticLayer(static)
    layer.costs[layer.costs == UNKNOWN] = FREE
    costs = LayeredCostmap(geometry, [layer, InflationLayer(inflation, geometry)], history=1).costs
    bound = np.array(costs, dtype=np.uint8)
    bound.setflags(write=False)
    return bound
