"""``evaluate.png``: the final maps side by side and the ghost curve over time.

Drawn with matplotlib's object API on an Agg canvas (no display, no pyplot state). Map
panels: occupied black, free white, unknown grey, as a ROS map; x right, y up in metres;
each cropped to the cells some map knows. Curve: ghost cells at each read [cells]
against recording time [s] from the first scan, one line per map.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure

from mapserver.core.belief import CellState
from scenarios.evaluate.run import Evaluation

DPI = 100
PANEL_INCHES = 4.0  # [in] width of one map panel
STATE_COLOURS = ListedColormap(["#b0b0b0", "#ffffff", "#000000"])  # unknown, free, occupied


def known_box(finals: list[np.ndarray]) -> tuple[slice, slice]:
    """(rows, cols) slices of the smallest box holding every cell any map knows, with a
    one-cell border; the whole grid when no map knows a cell."""
    known = np.zeros(finals[0].shape, dtype=bool)
    for states in finals:
        known |= states != CellState.UNKNOWN
    rows, cols = np.flatnonzero(known.any(axis=1)), np.flatnonzero(known.any(axis=0))
    if rows.size == 0:
        return slice(None), slice(None)
    h, w = known.shape
    return (
        slice(max(rows[0] - 1, 0), min(rows[-1] + 2, h)),
        slice(max(cols[0] - 1, 0), min(cols[-1] + 2, w)),
    )


def write_picture(evaluation: Evaluation, path: str | os.PathLike[str]) -> Path:
    """Draw ``evaluation`` (see the module) as a PNG at ``path``."""
    names = [v.name for v in evaluation.verdicts]
    figure = Figure(
        figsize=(PANEL_INCHES * len(names), PANEL_INCHES * 1.75), dpi=DPI, layout="constrained"
    )
    FigureCanvasAgg(figure)
    grid = figure.add_gridspec(2, len(names), height_ratios=(1.0, 0.7))
    rows, cols = known_box([evaluation.finals[n] for n in names])
    g = evaluation.geometry
    r0, r1 = rows.indices(g.height)[:2]
    c0, c1 = cols.indices(g.width)[:2]
    extent = (
        g.origin_x + c0 * g.resolution,
        g.origin_x + c1 * g.resolution,
        g.origin_y + r0 * g.resolution,
        g.origin_y + r1 * g.resolution,
    )
    for k, verdict in enumerate(evaluation.verdicts):
        ax = figure.add_subplot(grid[0, k])
        ax.imshow(
            evaluation.finals[verdict.name][rows, cols],
            cmap=STATE_COLOURS,
            vmin=0,
            vmax=2,
            origin="lower",  # row 0 is the bottom row (docs/contract.md)
            extent=extent,
            interpolation="nearest",
        )
        ax.set_title(
            f"{verdict.name}\nkept {verdict.structure_kept:.2f}, "
            f"ghosts {verdict.ghost_cell_seconds:,.0f} cell-s",
            fontsize=10,
        )
        ax.set_xlabel("x [m]")
        if k == 0:
            ax.set_ylabel("y [m]")
    curve = figure.add_subplot(grid[1, :])
    for name in names:
        tally = evaluation.ghosts[name]
        t = np.asarray(tally.stamps) - evaluation.first_stamp
        curve.plot(t, tally.counts, label=name, linewidth=1.0)
    curve.set_xlabel("recording time [s]")
    curve.set_ylabel(f"ghost cells (read every {evaluation.read_every:g} s)")
    curve.legend(loc="upper right")
    curve.grid(alpha=0.3)
    figure.savefig(path, format="png", dpi=DPI)
    return Path(path)
