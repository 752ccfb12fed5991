"""Obstacle costs from the belief grid, and when each tile's costs next change by decay.

Under the ``decay`` policy a cell's costs change without any scan: occupied evidence
fades below the occupied threshold, free evidence fades above the free threshold, and the
cell turns unknown. Fading is monotone toward the prior and the thresholds bracket the
prior, so a cell crosses at most one threshold until new evidence arrives, at

``t_cross = last_observed + half_life * log2(|L - L0| / |l_threshold - L0|)``.

The kernel classifies a window at a stamp and, per square tile of ``tile`` cells, keeps
the earliest crossing of any cell in it, so the costmap revisits only tiles whose time has
come (no timer, no full sweep).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mapserver.costvalues import FREE, LETHAL, UNKNOWN

# A tile is revisited slightly before its computed crossing so float rounding can never
# make it late; visiting early is harmless (the tile is reclassified, nothing changes).
EARLY_FRACTION = 1e-6  # of the half life
EARLY_SECONDS = 1e-6  # [s]


@njit(cache=True, nogil=True)
def classify_window(
    log_odds,
    last_observed,
    width,
    col0,
    row0,
    col1,
    row1,
    stamp,
    fades,
    l0,
    l_occupied,
    l_free,
    half_life_occupied,
    half_life_free,
    out,
    tile,
    tile_next,
):
    """Obstacle costs of cells (col0..col1, row0..row1) at ``stamp`` [s] into ``out``.

    log_odds (float32), last_observed (float64, NaN = never): flat grid arrays.
    out: uint8 (row1 - row0 + 1, col1 - col0 + 1): LETHAL above the occupied threshold,
    FREE below the free threshold, UNKNOWN otherwise (never observed, faded, uncertain).
    fades: the decay policy (else the stored log-odds are read as they are).
    tile_next: float64 (tile rows, tile cols) of the grid; for every tile that the window
    covers, it is *lowered* to the earliest future crossing of the window's cells in that
    tile (the caller resets covered tiles to +inf first, with tile-aligned windows).
    """
    for row in range(row0, row1 + 1):
        trow = row // tile
        base = row * width
        for col in range(col0, col1 + 1):
            idx = base + col
            value = np.float64(log_odds[idx])
            t = last_observed[idx]
            if math.isnan(t):
                out[row - row0, col - col0] = UNKNOWN
                continue
            dev = value - l0
            if fades and t < stamp:
                hl = half_life_occupied if dev > 0.0 else half_life_free
                faded = np.float32(l0 + dev * 2.0 ** (-(stamp - t) / hl))
                value = np.float64(faded)
            if value > l_occupied:
                out[row - row0, col - col0] = LETHAL
                if fades:
                    cross = t + half_life_occupied * math.log2(dev / (l_occupied - l0))
                    cross -= EARLY_FRACTION * half_life_occupied + EARLY_SECONDS
                    tcol = col // tile
                    if cross < tile_next[trow, tcol]:
                        tile_next[trow, tcol] = cross
            elif value < l_free:
                out[row - row0, col - col0] = FREE
                if fades:
                    cross = t + half_life_free * math.log2(dev / (l_free - l0))
                    cross -= EARLY_FRACTION * half_life_free + EARLY_SECONDS
                    tcol = col // tile
                    if cross < tile_next[trow, tcol]:
                        tile_next[trow, tcol] = cross
            else:
                out[row - row0, col - col0] = UNKNOWN
    return out
