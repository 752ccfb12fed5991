"""Planar ray casting against footprints in a uniform grid, in numba (no Python per ray).

The kernels behind ``fleet.footprint_index``: the world's bodies seen in a horizontal
plane at height ``z`` are oriented rectangles (boxes) and regular ``PRISM_SIDES``-gons
inscribed in circles (cylinders: people, units), exactly the solids the PyBullet world
is built of (``fleet.world``), each standing from ``z_low`` to ``z_high`` [m].

A footprint table is a float64 array, one row per body (``GEOM_COLUMNS`` columns):
centre (x, y) [m], the cosine and sine of its yaw, two half sizes [m] (box: half sides
along its own x and y; prism: circumradius and apothem), ``z_low``, ``z_high`` [m] and
its kind (``BOX`` or ``PRISM``).

A ray ``o + t d`` (``d`` a unit vector, so ``t`` is a distance [m]) from ``t0`` to
``t1`` returns the first crossing of a body's boundary at ``t >= t0``: the entry into a
body ahead, or the exit from a body the ray starts inside (as Bullet's ray test against
closed triangle meshes reports the far wall from inside); a ray lying along a box's side
counts as crossing it. A crossing at ``t1`` or beyond is no return (Bullet reports a
surface at the ray's end as a miss). A body counts at heights ``z_low <= z <= z_high``.

The grid: cells of ``cell`` [m] over ``[x0, x0 + nx cell] x [y0, y0 + ny cell]``; each
cell lists the bodies whose bounding box (padded by ``PAD_M``) touches it, in CSR form
(``starts``, ``items``). A body whose box leaves the grid is listed in ``outside`` and
tested by every ray. A ray walks its cells in order (Amanatides and Woo, *A fast voxel
traversal algorithm for ray tracing*, Eurographics 1987) and stops after the cell in
which its nearest crossing so far lies: a crossing at ``t`` lies in the cell the ray is
in at ``t``, so nothing in a later cell can be nearer.

Prisms in O(1): the ray enters the circumcircle on the arc of one side's sector; the
region between that arc and its chord (the side) touches no other side, so the ray
enters the polygon through that side or not at all, and it leaves through the side of
the sector where it leaves the circle.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fleet.shapes import PRISM_SIDES

GEOM_COLUMNS = 9
"""Columns of a footprint table (module docstring)."""
CX, CY, COS, SIN, HALF_A, HALF_B, Z_LOW, Z_HIGH, KIND = range(GEOM_COLUMNS)
BOX = 0.0
"""``KIND`` of a box: ``HALF_A``, ``HALF_B`` its half sides [m]."""
PRISM = 1.0
"""``KIND`` of a prism: ``HALF_A`` its circumradius, ``HALF_B`` its apothem [m]."""
PAD_M = 1e-6
"""[m] padding of each body's bounding box when it is put in cells (rounding at cell
borders never hides a body from a ray)."""

_SECTOR = 2.0 * math.pi / PRISM_SIDES
_NORMALS = np.array(
    [[math.cos((k + 0.5) * _SECTOR), math.sin((k + 0.5) * _SECTOR)] for k in range(PRISM_SIDES)]
)  # side k joins the vertices at angles k and k + 1 sectors; its outward normal


@njit(cache=True, nogil=True, inline="always")
def _box_crossing(u, v, du, dv, a, b, t0):
    """[m] first crossing at t >= t0 of the boundary of the box of half sides (a, b) [m]
    by the ray (u, v) + t (du, dv) in the box's axes (slab test); inf if none."""
    lo, hi = -np.inf, np.inf
    if du == 0.0:
        if abs(u) > a:
            return np.inf
    else:
        ta, tb = (-a - u) / du, (a - u) / du
        lo, hi = min(ta, tb), max(ta, tb)
    if dv == 0.0:
        if abs(v) > b:
            return np.inf
    else:
        ta, tb = (-b - v) / dv, (b - v) / dv
        lo, hi = max(lo, min(ta, tb)), min(hi, max(ta, tb))
    if lo > hi:
        return np.inf
    if lo >= t0:
        return lo
    if hi >= t0:
        return hi
    return np.inf


@njit(cache=True, nogil=True)
def _side(u, v):
    """The side whose sector holds the direction of point (u, v) (body axes)."""
    angle = math.atan2(v, u)
    if angle < 0.0:
        angle += 2.0 * math.pi
    return min(int(angle / _SECTOR), PRISM_SIDES - 1)


@njit(cache=True, nogil=True, inline="always")
def _prism_crossing(u, v, du, dv, r, apothem, t0):
    """[m] first crossing at t >= t0 of the boundary of the prism of circumradius ``r``
    and ``apothem`` [m] by the ray (u, v) + t (du, dv) in its axes; inf if none (module
    docstring)."""
    b = u * du + v * dv
    disc = b * b - (u * u + v * v - r * r)
    if disc < 0.0:
        return np.inf
    root = math.sqrt(disc)
    t_in, t_out = -b - root, -b + root  # the circumcircle
    if t_out < t0:
        return np.inf
    k = _side(u + t_in * du, v + t_in * dv)
    nx, ny = _NORMALS[k, 0], _NORMALS[k, 1]
    toward = du * nx + dv * ny
    if toward >= 0.0:
        return np.inf
    enter = (apothem - (u * nx + v * ny)) / toward
    if enter > t_out:
        return np.inf
    if enter >= t0:
        return enter
    k = _side(u + t_out * du, v + t_out * dv)
    nx, ny = _NORMALS[k, 0], _NORMALS[k, 1]
    away = du * nx + dv * ny
    if away <= 0.0:
        return np.inf
    leave = (apothem - (u * nx + v * ny)) / away
    return leave if leave >= t0 else np.inf


@njit(cache=True, nogil=True, inline="always")
def crossing(geom, j, ox, oy, dx, dy, z, t0):
    """[m] first crossing of body ``j``'s boundary by the ray at t >= t0 at height ``z``
    [m]; inf if none (or the body is not at that height). (Inlined, as are the other
    kernels that take arrays, so that no array is passed, and reference-counted, per
    ray or per body.)"""
    if z < geom[j, Z_LOW] or z > geom[j, Z_HIGH]:
        return np.inf
    c, s = geom[j, COS], geom[j, SIN]
    lx, ly = ox - geom[j, CX], oy - geom[j, CY]
    u, v, du, dv = c * lx + s * ly, -s * lx + c * ly, c * dx + s * dy, -s * dx + c * dy
    if geom[j, KIND] == PRISM:
        return _prism_crossing(u, v, du, dv, geom[j, HALF_A], geom[j, HALF_B], t0)
    return _box_crossing(u, v, du, dv, geom[j, HALF_A], geom[j, HALF_B], t0)


@njit(cache=True, nogil=True)
def bounds(geom, j):
    """Body ``j``'s axis-aligned bounding box (xmin, ymin, xmax, ymax) [m]."""
    if geom[j, KIND] == PRISM:
        hx = hy = geom[j, HALF_A]
    else:
        c, s = abs(geom[j, COS]), abs(geom[j, SIN])
        hx = c * geom[j, HALF_A] + s * geom[j, HALF_B]
        hy = s * geom[j, HALF_A] + c * geom[j, HALF_B]
    return geom[j, CX] - hx, geom[j, CY] - hy, geom[j, CX] + hx, geom[j, CY] + hy


@njit(cache=True, nogil=True)
def build_cells(geom, n, x0, y0, cell, nx, ny):
    """The grid of bodies ``0 .. n-1`` of ``geom``: (``starts``, ``items``, ``outside``):
    cell ``c = iy * nx + ix`` lists ``items[starts[c]:starts[c + 1]]``; ``outside``: the
    bodies whose padded bounding box leaves the grid."""
    box = np.empty((n, 4), dtype=np.int64)
    inside = np.zeros(n, dtype=np.bool_)
    counts = np.zeros(nx * ny + 1, dtype=np.int64)
    x1, y1 = x0 + nx * cell, y0 + ny * cell
    n_out = 0
    for j in range(n):
        xmin, ymin, xmax, ymax = bounds(geom, j)
        xmin, ymin, xmax, ymax = xmin - PAD_M, ymin - PAD_M, xmax + PAD_M, ymax + PAD_M
        if xmin < x0 or ymin < y0 or xmax >= x1 or ymax >= y1:
            n_out += 1
            continue
        inside[j] = True
        box[j, 0] = int((xmin - x0) / cell)
        box[j, 1] = int((ymin - y0) / cell)
        box[j, 2] = min(int((xmax - x0) / cell), nx - 1)
        box[j, 3] = min(int((ymax - y0) / cell), ny - 1)
        for iy in range(box[j, 1], box[j, 3] + 1):
            for ix in range(box[j, 0], box[j, 2] + 1):
                counts[iy * nx + ix + 1] += 1
    starts = np.cumsum(counts)
    items = np.empty(starts[-1], dtype=np.int64)
    fill = starts[:-1].copy()
    outside = np.empty(n_out, dtype=np.int64)
    k = 0
    for j in range(n):
        if not inside[j]:
            outside[k] = j
            k += 1
            continue
        for iy in range(box[j, 1], box[j, 3] + 1):
            for ix in range(box[j, 0], box[j, 2] + 1):
                c = iy * nx + ix
                items[fill[c]] = j
                fill[c] += 1
    return starts, items, outside


@njit(cache=True, nogil=True, inline="always")
def _nearest_in(geom, members, lo, hi, offset, ox, oy, dx, dy, z, t0, best, hit):
    """Test bodies ``members[lo:hi]``: the nearer of (best, hit) and their crossings
    (a hit's index is the body's plus ``offset``)."""
    for k in range(lo, hi):
        j = members[k]
        t = crossing(geom, j, ox, oy, dx, dy, z, t0)
        if t < best:
            best, hit = t, j + offset
    return best, hit


@njit(cache=True, nogil=True, inline="always")
def cast_ray(ox, oy, dx, dy, z, t0, t1, grid, shape, tables_a, tables_b):
    """(t, hit) of the ray ``o + t d`` over [t0, t1) at height z among two footprint
    tables, each ``(geom, starts, items, outside)`` on the same grid (``grid``: x0, y0,
    cell [m]; ``shape``: nx, ny): the nearest crossing [m] and its body (table a: its
    index; table b: its index plus len(table a)); (inf, -1) for no return."""
    geom_a, starts_a, items_a, out_a = tables_a
    geom_b, starts_b, items_b, out_b = tables_b
    offset = geom_a.shape[0]
    best, hit = t1, -1
    best, hit = _nearest_in(geom_a, out_a, 0, out_a.size, 0, ox, oy, dx, dy, z, t0, best, hit)
    best, hit = _nearest_in(geom_b, out_b, 0, out_b.size, offset, ox, oy, dx, dy, z, t0, best, hit)
    x0, y0, cell = grid[0], grid[1], grid[2]
    nx, ny = shape[0], shape[1]
    lo, hi = _clip(ox, dx, x0, x0 + nx * cell, t0, best)  # the part inside the grid
    lo, hi = _clip(oy, dy, y0, y0 + ny * cell, lo, hi)
    if lo <= hi:
        ix = min(max(int(math.floor((ox + lo * dx - x0) / cell)), 0), nx - 1)
        iy = min(max(int(math.floor((oy + lo * dy - y0) / cell)), 0), ny - 1)
        step_x, next_x, delta_x = _walk(ox, dx, x0, cell, ix)
        step_y, next_y, delta_y = _walk(oy, dy, y0, cell, iy)
        while True:
            c = iy * nx + ix
            best, hit = _nearest_in(
                geom_a, items_a, starts_a[c], starts_a[c + 1], 0, ox, oy, dx, dy, z, t0, best, hit
            )
            best, hit = _nearest_in(
                geom_b, items_b, starts_b[c], starts_b[c + 1], offset,
                ox, oy, dx, dy, z, t0, best, hit,
            )  # fmt: skip
            leave = min(next_x, next_y)
            if best <= leave or leave >= hi:
                break
            if next_x < next_y:
                ix += step_x
                next_x += delta_x
                if ix < 0 or ix >= nx:
                    break
            else:
                iy += step_y
                next_y += delta_y
                if iy < 0 or iy >= ny:
                    break
    if best >= t1:
        return np.inf, -1
    return best, hit


@njit(cache=True, nogil=True)
def _clip(o, d, g0, g1, lo, hi):
    """[lo, hi] cut to where ``o + t d`` lies in [g0, g1] along one axis (lo > hi: empty)."""
    if d == 0.0:
        return (lo, hi) if g0 <= o <= g1 else (np.inf, -np.inf)
    ta, tb = (g0 - o) / d, (g1 - o) / d
    return max(lo, min(ta, tb)), min(hi, max(ta, tb))


@njit(cache=True, nogil=True)
def _walk(o, d, g0, cell, i):
    """Along one axis from cell ``i``: (step, t of the next cell border, t per cell)."""
    if d > 0.0:
        return 1, (g0 + (i + 1) * cell - o) / d, cell / d
    if d < 0.0:
        return -1, (g0 + i * cell - o) / d, -cell / d
    return 0, np.inf, np.inf


@njit(cache=True, nogil=True)
def cast_fans(poses, beam_cos, beam_sin, z, t0, t1, grid, shape, tables_a, tables_b, ranges, hits):
    """Cast a fan of beams from each pose: ``poses`` (m, 3) sensor x, y [m] and heading
    [rad]; beam i leaves at ``atan2(beam_sin[i], beam_cos[i])`` from the heading and is
    cast over [t0, t1) [m] at height z [m] (``cast_ray``). Writes ``ranges`` (m, beams)
    [m] (inf: no return) and ``hits`` (m, beams) (the body, -1: none)."""
    for m in range(poses.shape[0]):
        ox, oy = poses[m, 0], poses[m, 1]
        c, s = math.cos(poses[m, 2]), math.sin(poses[m, 2])
        for i in range(beam_cos.size):
            dx = c * beam_cos[i] - s * beam_sin[i]
            dy = s * beam_cos[i] + c * beam_sin[i]
            ranges[m, i], hits[m, i] = cast_ray(
                ox, oy, dx, dy, z, t0, t1, grid, shape, tables_a, tables_b
            )
