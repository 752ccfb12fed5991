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

from mapserver.core.costvalues import FREE, LETHAL, UNKNOWN
from mapserver.core.fusion_kernel import fade, fades_by_history

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
    fade_cache,
    history,
    selective,
):
    """Merge obstacle costs of cells (col0..col1, row0..row1) at ``stamp`` [s] into ``out``.

    log_odds (float32), last_observed (float64, NaN = never): flat grid arrays.
    Obstacle costs: LETHAL above the occupied threshold, FREE below the free threshold,
    UNKNOWN otherwise (never observed, faded, uncertain).
    out: uint8 (row1 - row0 + 1, col1 - col0 + 1) master window; each known obstacle cost
    is merged into it as Nav2's MaxWithoutUnknownOverwrite (``layers`` module).
    fades: the decay policy (else the stored log-odds are read as they are).
    tile_next: float64 (tile rows, tile cols) of the grid; for every tile that the window
    covers, it is *lowered* to the earliest future crossing of the window's cells in that
    tile (the caller resets covered tiles to +inf first, with tile-aligned windows).
    fade_cache: scratch for ``fusion_kernel.fade``, shape (FADE_CACHE_SIZE, 3).
    history, selective: under the ``dual`` policy (selective), only the cells whose
    history (flat grid array) says fade (``fusion_kernel.fades_by_history``), and
    ``half_life_occupied`` is then dual's transient half life (``BeliefGrid``'s
    ``occupied_half_life``).
    """
    fade_cache[:, 0] = math.nan
    stamp_bits = last_observed.view(np.int64)
    for row in range(row0, row1 + 1):
        trow = row // tile
        base = row * width
        for col in range(col0, col1 + 1):
            idx = base + col
            value = np.float64(log_odds[idx])
            t = last_observed[idx]
            if math.isnan(t):
                continue  # unknown never overwrites
            dev = value - l0
            cell_fades = fades and (not selective or fades_by_history(history[idx], value, l0))
            if cell_fades and t < stamp:
                faded = fade(value, l0, t, stamp, stamp_bits[idx], fade_cache,
                             half_life_occupied, half_life_free)  # fmt: skip
                value = np.float64(np.float32(faded))  # as the belief's float32 views
            if value > l_occupied:
                _merge(out, row - row0, col - col0, LETHAL)
                if cell_fades:
                    cross = t + half_life_occupied * math.log2(dev / (l_occupied - l0))
                    cross -= EARLY_FRACTION * half_life_occupied + EARLY_SECONDS
                    tcol = col // tile
                    if cross < tile_next[trow, tcol]:
                        tile_next[trow, tcol] = cross
            elif value < l_free:
                _merge(out, row - row0, col - col0, FREE)
                if cell_fades:
                    cross = t + half_life_free * math.log2(dev / (l_free - l0))
                    cross -= EARLY_FRACTION * half_life_free + EARLY_SECONDS
                    tcol = col // tile
                    if cross < tile_next[trow, tcol]:
                        tile_next[trow, tcol] = cross
    return out


@njit(cache=True, nogil=True, inline="always")
def _merge(master, r, c, cost):
    """A known layer cost into the master: it replaces UNKNOWN, otherwise the max wins."""
    old = master[r, c]
    if old == UNKNOWN or cost > old:
        master[r, c] = cost
