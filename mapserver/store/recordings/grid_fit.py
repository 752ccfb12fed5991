"""A grid sized from the data: the box around every sensor pose and return, plus a margin."""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import BEAM_RETURN, Scan
from mapserver.store.recordings.base import RecordingError

MAX_FITTED_CELLS = 100_000_000
"""Largest grid ``fit_grid`` makes (400 MB of log-odds): past it, a stray pose or a far
return would have the map build allocate without bound; choose the grid instead."""


def fit_grid(scans: Iterable[Scan], resolution: float, margin: float = 2.0) -> GridGeometry:
    """The grid at ``resolution`` [m/cell] whose box holds every scan's pose and every
    return's endpoint, ``margin`` [m] beyond them on each side; its origin is a whole
    number of cells. RecordingError when there are no scans or the grid would exceed
    MAX_FITTED_CELLS (naming its size and the flags that choose one)."""
    lo = np.array([math.inf, math.inf])
    hi = -lo
    count = 0
    for scan in scans:
        count += 1
        points = [np.array([[scan.pose.x, scan.pose.y]])]
        returns = scan.beam_classes() == BEAM_RETURN
        if returns.any():
            angles = scan.pose.yaw + scan.angle_min + scan.angle_increment * np.flatnonzero(returns)
            r = scan.ranges[returns]
            ends = (scan.pose.x + r * np.cos(angles), scan.pose.y + r * np.sin(angles))
            points.append(np.column_stack(ends))
        stacked = np.concatenate(points)
        lo = np.minimum(lo, stacked.min(axis=0))
        hi = np.maximum(hi, stacked.max(axis=0))
    if count == 0:
        raise RecordingError("no scans to size the grid from (check --topic, --start, --end)")
    origin = np.floor((lo - margin) / resolution) * resolution
    cells = np.ceil((hi + margin - origin) / resolution).astype(int)
    width, height = int(cells[0]), int(cells[1])
    if width * height > MAX_FITTED_CELLS:
        raise RecordingError(
            f"the data spans {width} x {height} cells at {resolution} m/cell "
            f"({hi[0] - lo[0]:.0f} m x {hi[1] - lo[1]:.0f} m), more than {MAX_FITTED_CELLS:,}: "
            "choose the grid with --width, --height and --origin, or a coarser --resolution"
        )
    return GridGeometry(width, height, resolution, float(origin[0]), float(origin[1]))
