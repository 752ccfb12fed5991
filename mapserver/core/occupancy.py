"""Belief -> ROS OccupancyGrid values (int8): -1 unknown, 0..100 occupancy percent."""

from __future__ import annotations

import numpy as np

from mapserver.core.belief import CellState
from mapserver.core.costvalues import OCC_FREE, OCC_OCCUPIED, OCC_UNKNOWN


def occupancy_percent(probability: np.ndarray) -> np.ndarray:
    """Probability (NaN = unknown) -> int8 percent, rounded half up; NaN -> -1."""
    p = np.asarray(probability, dtype=np.float64)
    out = np.full(p.shape, OCC_UNKNOWN, dtype=np.int8)
    known = ~np.isnan(p)
    out[known] = np.floor(p[known] * 100.0 + 0.5).astype(np.int8)
    return out


def trinary_occupancy(states: np.ndarray) -> np.ndarray:
    """CellState array -> int8 OccupancyGrid values of a trinary map (-1, 0, 100)."""
    lookup = np.empty(3, dtype=np.int8)
    lookup[CellState.UNKNOWN] = OCC_UNKNOWN
    lookup[CellState.FREE] = OCC_FREE
    lookup[CellState.OCCUPIED] = OCC_OCCUPIED
    return lookup[states]
