"""Costmap cell values, as Nav2's ``nav2_costmap_2d/cost_values.hpp``, and their OccupancyGrid view.

The costmap is a uint8 grid (same layout as every grid here: row 0 at the origin's y):

=================  =====  ===============================================
name               value  meaning
=================  =====  ===============================================
``FREE``               0  no obstacle near (Nav2 ``FREE_SPACE``)
graded            1..252  inflated cost, falling with distance to an obstacle
``INSCRIBED``        253  the unit's centre here puts its footprint on an obstacle
                          (Nav2 ``INSCRIBED_INFLATED_OBSTACLE``)
``LETHAL``           254  an obstacle (Nav2 ``LETHAL_OBSTACLE``)
``UNKNOWN``          255  never observed or faded (Nav2 ``NO_INFORMATION``)
=================  =====  ===============================================

This module is the only place these numbers are written; everything else names them.

``costs_to_occupancy`` is the translation Nav2's ``Costmap2DPublisher`` applies when it
publishes a costmap as a ``nav_msgs/OccupancyGrid``: a 256-entry table with 0 -> 0,
253 -> 99, 254 -> 100, 255 -> -1 and, for the graded band, ``1 + (97 * (i - 1)) / 251`` in
C integer division (so 1..252 -> 1..98). Source: navigation2,
``nav2_costmap_2d/src/costmap_2d_publisher.cpp``, constructor of ``Costmap2DPublisher``.
"""

from __future__ import annotations

from typing import Final

import numpy as np

FREE: Final = np.uint8(0)
MAX_GRADED: Final = np.uint8(252)  # the highest non-obstacle cost (Nav2 MAX_NON_OBSTACLE)
INSCRIBED: Final = np.uint8(253)
LETHAL: Final = np.uint8(254)
UNKNOWN: Final = np.uint8(255)

# OccupancyGrid values (ROS nav_msgs): -1 unknown, 0..100 occupancy in percent.
OCC_UNKNOWN: Final = np.int8(-1)
OCC_FREE: Final = np.int8(0)
OCC_OCCUPIED: Final = np.int8(100)


def _occupancy_table() -> np.ndarray:
    """The 256-entry cost -> OccupancyGrid table (int8), built as Nav2 builds it."""
    graded = np.arange(1, int(MAX_GRADED) + 1, dtype=np.int64)
    table = np.empty(256, dtype=np.int8)
    table[int(FREE)] = OCC_FREE
    table[1 : int(MAX_GRADED) + 1] = 1 + (97 * (graded - 1)) // 251  # C integer division
    table[int(INSCRIBED)] = 99
    table[int(LETHAL)] = OCC_OCCUPIED
    table[int(UNKNOWN)] = OCC_UNKNOWN
    table.setflags(write=False)
    return table


COST_TO_OCCUPANCY: Final = _occupancy_table()


def costs_to_occupancy(costs: np.ndarray) -> np.ndarray:
    """Translate Nav2 costs (uint8, any shape) to OccupancyGrid values (int8, same shape).

    0 -> 0, 1..252 -> 1..98, 253 -> 99, 254 -> 100, 255 -> -1 (see the module docstring).
    """
    arr = np.asarray(costs)
    if arr.dtype != np.uint8:
        raise TypeError(f"costs must be a uint8 array, got dtype {arr.dtype}")
    return COST_TO_OCCUPANCY[arr]
