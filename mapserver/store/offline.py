"""Offline map building: fuse a list of scans and write the map files.

Used by ``fleetmap map build`` (and by ``fleetmap replay``). Outputs, in one folder:
``map.yaml`` + ``map.pgm`` (ROS map_server, trinary) and ``logodds.npy`` (float32,
(height, width), row 0 at the origin's y, evaluated at the map's stamp). All three are
staged in a temporary folder beside them and moved into place only once all are written.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sized
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mapserver.core.belief import BeliefGrid, load_fusion_kernels
from mapserver.core.occupancy import trinary_occupancy
from mapserver.core.scan import Scan
from mapserver.store.atomic import staged_files
from mapserver.store.mapfiles import write_ros_map

MAP_FILES = ("map.yaml", "map.pgm", "logodds.npy")


@dataclass(frozen=True)
class FusionStats:
    """scans fused, fusion_s [s] spent in fusion (parsing and kernel load excluded),
    cells_updated, kernel_load_s [s] spent compiling or loading the fusion kernel first."""

    scans: int
    fusion_s: float
    cells_updated: int
    kernel_load_s: float = 0.0

    @property
    def scans_per_s(self) -> float:
        """Fusion speed, the kernel load excluded (0 for no scans)."""
        return self.scans / self.fusion_s if self.fusion_s > 0 else 0.0

    def as_dict(self) -> dict[str, float | int]:
        return {
            "scans": self.scans,
            "fusion_s": self.fusion_s,
            "cells_updated": self.cells_updated,
            "kernel_load_s": self.kernel_load_s,
            "scans_per_s": self.scans_per_s,
        }


def fuse_all(
    belief: BeliefGrid,
    scans: Iterable[Scan],
    progress: Callable[[int, int | None], None] | None = None,
    total: int | None = None,
) -> FusionStats:
    """Fuse scans in order, streamed (an iterator is read once, one scan at a time);
    ``progress(done, total)`` is called after every scan, ``total`` being
    ``len(scans)`` for a sequence, else the ``total`` given (None: unknown). The fusion
    kernel is loaded first, timed apart from the fusion."""
    kernel_load_s = load_fusion_kernels([belief.policy])
    if total is None and isinstance(scans, Sized):
        total = len(scans)
    cells = 0
    elapsed = 0.0
    done = 0
    for scan in scans:
        t0 = time.perf_counter()
        cells += belief.fuse(scan).cells
        elapsed += time.perf_counter() - t0
        done += 1
        if progress is not None:
            progress(done, total)
    return FusionStats(
        scans=done, fusion_s=elapsed, cells_updated=cells, kernel_load_s=kernel_load_s
    )


def write_map_outputs(belief: BeliefGrid, out_dir: Path | str, stamp: float | None = None) -> Path:
    """Write map.yaml, map.pgm and logodds.npy for ``belief`` at ``stamp`` into out_dir.

    Returns the YAML path. Either all three files are replaced or none is.
    """
    with staged_files(out_dir, MAP_FILES) as staging:
        occupancy = trinary_occupancy(belief.states_at(stamp))
        write_ros_map(staging, occupancy, belief.geometry, image_name="map.pgm")
        np.save(staging / "logodds.npy", belief.log_odds_at(stamp).astype(np.float32))
    return Path(out_dir) / "map.yaml"
