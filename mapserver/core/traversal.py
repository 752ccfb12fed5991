"""The one ray traversal of the grid, shared by fusion (beams) and queries (segments).

A segment [m] is clipped to the map rectangle (Liang-Barsky: Liang and Barsky, 1984) and
its cells are those of the integer Bresenham line between the cells of its two clipped
ends (Bresenham, 1965; as Nav2's ``raytraceLine``): one cell per step along the major
axis, ``max(|dc|, |dr|) + 1`` cells in all, 8-connected. The line walks a flat row-major
index (``row * width + col``), so a caller reads or writes ``grid.ravel()[idx]``::

    idx, cells, major, minor, a, b, err = line_start(c0, r0, c1, r1, width)
    for _ in range(cells):
        ...  # visit idx
        idx, err = line_next(idx, err, major, minor, a, b)

Both steps are inlined into the kernels that use them (numba ``inline="always"``).
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True, nogil=True)
def clip_segment(x0, y0, x1, y1, xmin, ymin, xmax, ymax):
    """Liang-Barsky clip of segment (x0,y0)-(x1,y1) to the box; returns (ok, t0, t1)."""
    t0 = 0.0
    t1 = 1.0
    dx = x1 - x0
    dy = y1 - y0
    for k in range(4):
        if k == 0:
            p, q = -dx, x0 - xmin
        elif k == 1:
            p, q = dx, xmax - x0
        elif k == 2:
            p, q = -dy, y0 - ymin
        else:
            p, q = dy, ymax - y0
        if p == 0.0:
            if q < 0.0:
                return False, t0, t1
        else:
            r = q / p
            if p < 0.0:
                if r > t1:
                    return False, t0, t1
                if r > t0:
                    t0 = r
            else:
                if r < t0:
                    return False, t0, t1
                if r < t1:
                    t1 = r
    return True, t0, t1


@njit(cache=True, nogil=True)
def cell_of(v, origin, inv_res, n):
    """Cell index along one axis of coordinate v [m], clamped into [0, n - 1]."""
    c = int(math.floor((v - origin) * inv_res))
    if c < 0:
        return 0
    if c >= n:
        return n - 1
    return c


@njit(cache=True, nogil=True, inline="always")
def clipped_cells(x0, y0, x1, y1, origin_x, origin_y, resolution, width, height):
    """Segment (x0, y0)-(x1, y1) [m] clipped to the map: (ok, t0, t1, c0, r0, c1, r1),
    the kept part's fractions along it and the cells of its two ends (ok False: none)."""
    inv_res = 1.0 / resolution
    ok, t0, t1 = clip_segment(
        x0, y0, x1, y1, origin_x, origin_y,
        origin_x + width * resolution, origin_y + height * resolution,
    )  # fmt: skip
    if not ok:
        return False, t0, t1, 0, 0, 0, 0
    dx = x1 - x0
    dy = y1 - y0
    c0 = cell_of(x0 + t0 * dx, origin_x, inv_res, width)
    r0 = cell_of(y0 + t0 * dy, origin_y, inv_res, height)
    c1 = cell_of(x0 + t1 * dx, origin_x, inv_res, width)
    r1 = cell_of(y0 + t1 * dy, origin_y, inv_res, height)
    return True, t0, t1, c0, r0, c1, r1


@njit(cache=True, nogil=True, inline="always")
def line_start(c0, r0, c1, r1, width):
    """The Bresenham line from cell (c0, r0) to (c1, r1) on a grid ``width`` cells wide:
    (idx, cells, major, minor, a, b, err): the flat index of its first cell, its number
    of cells (both ends included), the index steps along the major and minor axes, the
    major and minor extents [cells] and the initial error term."""
    dc = c1 - c0
    dr = r1 - r0
    adc = abs(dc)
    adr = abs(dr)
    step_c = 1 if dc > 0 else -1
    step_r = width if dr > 0 else -width
    if adc >= adr:
        major, minor, a, b = step_c, step_r, adc, adr
    else:
        major, minor, a, b = step_r, step_c, adr, adc
    return r0 * width + c0, a + 1, major, minor, a, b, a >> 1


@njit(cache=True, nogil=True, inline="always")
def line_next(idx, err, major, minor, a, b):
    """The flat index of the line's next cell and the new error term (without a branch:
    a minor step is taken where the error term goes negative, about every a / b cells,
    a pattern branch prediction misses)."""
    err -= b
    step = err >> 63  # -1 when negative (int64, arithmetic shift), else 0
    return idx + major + (minor & step), err + (a & step)
