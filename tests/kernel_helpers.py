"""The fusion kernel's arguments as ``BeliefGrid.fuse_many`` builds them, for tests and
benchmarks that drive the kernel themselves."""

from __future__ import annotations

from collections.abc import Sequence

from mapserver.core import fusion_kernel as kernel
from mapserver.core.belief import BeliefGrid
from mapserver.core.scan import Scan
from mapserver.core.sensor_model import POLICY_CODES


def kernel_arguments(grid: BeliefGrid, scans: Sequence[Scan]) -> tuple:
    """Fuse ``scans`` into ``grid`` and return the arguments its policy's kernel
    (``fusion_kernel.POLICY_FUSE_BATCH``) was called with: (buffers, grid, model, ranges,
    offsets, scan records, boxes, cells)."""
    captured = {}
    code = POLICY_CODES[grid.policy]
    compiled = kernel.POLICY_FUSE_BATCH[code]

    def capture(*args):
        captured["args"] = args
        return compiled(*args)

    kernel.POLICY_FUSE_BATCH[code] = capture
    try:
        grid.fuse_many(scans)
    finally:
        kernel.POLICY_FUSE_BATCH[code] = compiled
    return captured["args"]
