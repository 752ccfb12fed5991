"""The verdict's measures on one map, from the recording's sight (``sight.py``).

- *structure kept*: the share of all the recording's returns whose endpoint cell the
  final map holds occupied (a return off the grid counts as not kept);
- *ghost cell-seconds* [cell s]: at reads every ``interval`` [s] of recording time, the
  cells the current scan (the latest at or before the read) sees through that some
  return hit earlier and that the map, as it stands after that scan at the read's
  stamp, holds occupied; their count times ``interval``, summed over the reads;
- *unknown share*: the share of the floor the recording saw (cells a returning beam
  crossed or hit) that the final map holds unknown;
- *occupied cells* in the final map, and fusion speed [scans/s] (fusion time alone).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mapserver.core.belief import CellState


@dataclass
class GhostTally:
    """Ghost cells of one map at each read: ``counts`` [cells] at ``stamps`` [s]."""

    interval: float
    stamps: list[float] = field(default_factory=list)
    counts: list[int] = field(default_factory=list)

    def add(self, stamp: float, occupied: np.ndarray) -> None:
        """One read at ``stamp``: ``occupied`` per ghost candidate (bool)."""
        self.stamps.append(stamp)
        self.counts.append(int(np.count_nonzero(occupied)))

    @property
    def cell_seconds(self) -> float:
        """[cell s] the counts summed, times the read interval."""
        return float(sum(self.counts)) * self.interval


@dataclass(frozen=True)
class Verdict:
    """The measures of one map (see the module); ``scans_per_s`` is 0 when no time was
    measured."""

    name: str
    structure_kept: float
    ghost_cell_seconds: float
    unknown_share: float
    occupied_cells: int
    scans_per_s: float

    def as_row(self) -> dict[str, str | float | int]:
        return {
            "map": self.name,
            "structure_kept": self.structure_kept,
            "ghost_cell_seconds": self.ghost_cell_seconds,
            "unknown_share": self.unknown_share,
            "occupied_cells": self.occupied_cells,
            "scans_per_s": self.scans_per_s,
        }


def structure_kept(final: np.ndarray, hit_count: np.ndarray, returns_total: int) -> float:
    """Share of ``returns_total`` whose endpoint cell (``hit_count`` per flat cell) is
    OCCUPIED in ``final`` (CellState per cell); NaN for a recording without returns."""
    if returns_total == 0:
        return float("nan")
    kept = hit_count[final.ravel() == CellState.OCCUPIED].sum()
    return float(kept) / returns_total


def unknown_share(final: np.ndarray, floor: np.ndarray) -> float:
    """Share of the ``floor`` cells (bool per flat cell) UNKNOWN in ``final``; NaN
    when the floor is empty."""
    seen = int(np.count_nonzero(floor))
    if seen == 0:
        return float("nan")
    return float(np.count_nonzero(final.ravel()[floor] == CellState.UNKNOWN)) / seen


def occupied_cells(final: np.ndarray) -> int:
    """Cells OCCUPIED in ``final``."""
    return int(np.count_nonzero(final == CellState.OCCUPIED))
