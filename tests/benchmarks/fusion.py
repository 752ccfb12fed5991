"""Fusion benchmark: fleetmap's BeliefGrid against OctoMap on identical warehouse scans.

Run: ``python -m tests.benchmarks.fusion [--scans N] [--octomap-scans M] [--seed S]
[--repeat K] [--json]``

The scans come from ``fleet.boxworld``: units patrolling the aisles of a 100 m x 50 m
rack warehouse with a 1080-beam, 20 m, 360 degree LiDAR at 10 Hz, noise-free. fleetmap
fuses them into a 2000 x 1000 grid of 0.05 m cells (origin (0, 0), so its cells are
exactly OctoMap's voxels in one z layer) under the ``decay`` policy, on one core, after
a warm-up scan has compiled (or loaded) the numba kernels. OctoMap (``pyoctomap``, an
``OcTree`` of the same resolution with the same hit/miss probabilities and clamping)
inserts the same scans with ``insertPointCloud``, its fastest batch path, each beam
clearing what it clears in the BeliefGrid: a return up to its endpoint, a no-return beam
the sensor model's ``no_return_range`` (1 m) out (``point_cloud``).

``--profile`` adds where fleetmap's time goes per scan: marking (endpoints, beam traces,
the fill between beams; ``mark_scan``) against applying the updates (``apply_marks``), in
one kernel call for all scans (no Python per scan), and the Python per ``fuse`` call.

Printed: scans/s for both, fleetmap's cell updates/s (each cell a scan observes counted
once), the speed ratio, fleetmap again fusing 50 scans a call (``fuse_many``, as the
server's ingest fuses the scans of a group), and the agreement of the two maps: over the cells both
observed, the share whose state (free below p 0.25, occupied above 0.65, unknown
between) is the same, and the intersection over union of their occupied cells. The
headline compares the ``decay`` map at the last scan's stamp; "no fading" removes decay
(clamped log-odds, which is OctoMap's own model) and ``sticky`` also removes the clamp.
The headline fuses with the default sensor model, whose fill between beams clears cells
beyond 8.6 m that no beam crosses and whose guard cuts glancing returns short of their
face (docs/clearing.md); a second line fuses beams only, without either, and the
agreement is measured beams only, as OctoMap traces its beams.

Why the maps differ at all: the BeliefGrid steps beams with 2D Bresenham (one cell per
major-axis step, as Nav2), OctoMap with a 3D DDA (every voxel the ray crosses, ~5%
more cells here), so cells grazed near a surface or seen by few beams get different
counts of misses; a no-return beam's last cell is cleared by the BeliefGrid but not by
OctoMap; and pyoctomap hands OctoMap float32 coordinates. Tests assert behaviour; this
script only measures.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass
from importlib.metadata import version

import numpy as np
import pyoctomap
from numba import njit

from fleet.boxworld import sample_scans, warehouse_layout
from mapserver.core import fusion_kernel
from mapserver.core.belief import BeliefGrid, CellState
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Scan
from mapserver.core.sensor_model import POLICY_CODES, DecayParams, Policy, SensorModel
from scenarios.evaluate.octomap_peer import octree  # fleetmap's sensor model in OctoMap
from tests.kernel_helpers import kernel_arguments

RESOLUTION = 0.05  # [m] cell / voxel edge
WIDTH_M, HEIGHT_M = 100.0, 50.0  # [m] warehouse floor = grid extent
BEAMS = 1080
RANGE_MAX = 20.0  # [m]
Z = RESOLUTION / 2  # [m] height of the scan plane: the centre of OctoMap's voxel layer 0
GROUP = 50  # scans per fuse_many call in the grouped run
NO_FADING = DecayParams(half_life_occupied=1e12, half_life_free=1e12)  # [s]: no decay


@dataclass(frozen=True)
class Timing:
    scans: int
    seconds: float
    cells: int = 0  # cells updated, each counted once per scan (fleetmap only)

    @property
    def scans_per_s(self) -> float:
        return self.scans / self.seconds


def fuse(grid: BeliefGrid, scans: list[Scan]) -> Timing:
    """Fuse ``scans`` into ``grid`` in order; wall time of the fusion alone."""
    cells = 0
    start = time.perf_counter()
    for scan in scans:
        cells += grid.fuse(scan).cells
    return Timing(len(scans), time.perf_counter() - start, cells)


def fuse_grouped(grid: BeliefGrid, scans: list[Scan], group: int) -> Timing:
    """``scans`` fused ``group`` at a time with ``fuse_many``, as the server's ingest fuses
    the scans that arrived together; wall time of the fusion alone."""
    cells = 0
    start = time.perf_counter()
    for i in range(0, len(scans), group):
        cells += sum(r.cells for r in grid.fuse_many(scans[i : i + group]))
    return Timing(len(scans), time.perf_counter() - start, cells)


@njit(cache=True)
def _mark_only(buffers, grid, ranges, offsets, scans, boxes):
    """``mark_scan`` per scan, its marks cleared (a memset per row of the box) unapplied."""
    marks = buffers.marks
    for k in range(offsets.shape[0] - 1):
        box = boxes[k]
        fusion_kernel.mark_scan(marks, grid, scans[k], ranges[offsets[k] : offsets[k + 1]], box)
        for row in range(box[1], box[3] + 1):
            marks[row * grid.width + box[0] : row * grid.width + box[2] + 1] = 0


def profile(geometry: GridGeometry, model: SensorModel, scans: list[Scan], repeat: int) -> dict:
    """[us per scan] the kernel's parts, fastest of ``repeat``: all scans in one call
    (``fuse_batch``), marking alone, applying (their difference) and the Python of one
    ``fuse`` call (the whole loop of ``fuse`` less the batch)."""
    grid = BeliefGrid(geometry, model, policy=Policy.DECAY)
    grid.fuse_many(scans[:1])
    real = fusion_kernel.POLICY_FUSE_BATCH[POLICY_CODES[Policy.DECAY]]  # decay's kernel
    buffers, kgrid, kmodel, ranges, offsets, params, boxes, cells = kernel_arguments(grid, scans)
    _mark_only(buffers, kgrid, ranges, offsets[:2], params, boxes)  # compile, untimed
    batch = mark = per_fuse = math.inf
    for _ in range(repeat):
        fresh = BeliefGrid(geometry, model, policy=Policy.DECAY)
        b = fresh._kernel_buffers  # the benchmark drives the kernel itself
        start = time.perf_counter()
        real(b, kgrid, kmodel, ranges, offsets, params, boxes, cells)
        batch = min(batch, time.perf_counter() - start)
        start = time.perf_counter()
        _mark_only(b, kgrid, ranges, offsets, params, boxes)
        mark = min(mark, time.perf_counter() - start)
        per_fuse = min(
            per_fuse, fuse(BeliefGrid(geometry, model, policy=Policy.DECAY), scans).seconds
        )
    n = len(scans)
    return {
        "batch_us": 1e6 * batch / n,
        "mark_us": 1e6 * mark / n,
        "apply_us": 1e6 * (batch - mark) / n,
        "python_per_fuse_us": 1e6 * (per_fuse - batch) / n,
        "box_cells": float(
            np.mean((boxes[:, 2] - boxes[:, 0] + 1) * (boxes[:, 3] - boxes[:, 1] + 1))
        ),
    }


@dataclass(frozen=True)
class PeerCloud:
    """One scan as OctoMap's ``insertPointCloud`` takes it: the returns' endpoints and the
    no-return beams' points [m] ((n, 3) each, at height Z), the latter cleared
    ``clearing`` [m] out and no farther."""

    returns: np.ndarray
    no_returns: np.ndarray
    clearing: float


def point_cloud(scan: Scan, clearing: float) -> PeerCloud:
    """The scan for OctoMap, each beam clearing exactly what it clears in the BeliefGrid.

    Returns keep their endpoints (inserted with ``max_range = range_max``, which holds
    them all). No-return beams (REP 117: > range_max, here +inf) clear ``clearing`` [m]
    out, fleetmap's ``BeliefGrid.no_return_clearing`` (the sensor model's
    ``no_return_range``, 1 m by default), and mark no endpoint: they get a point just
    beyond it and are inserted apart with ``max_range = clearing``, first, so that a
    return's endpoint near the sensor is the last word on its cell as in the BeliefGrid
    (where a hit outranks a pass in the same scan). Until 2026-12-06 they were cleared
    out to range_max, 20 m: OctoMap traced about 400 voxels for each such beam where the
    BeliefGrid traces 20 cells, and its scans/s were counted against fleetmap's for work
    fleetmap did not do. None of them when ``clearing <= 0``. Invalid beams (NaN, below
    range_min) are dropped, as the BeliefGrid drops them; the warehouse scans have none.
    """
    r = scan.ranges
    angles = scan.pose.yaw + scan.angle_min + scan.angle_increment * np.arange(r.size)
    is_return = (r >= scan.range_min) & (r <= scan.range_max)  # False for NaN
    no_return = r > scan.range_max if clearing > 0 else np.zeros(r.size, dtype=bool)

    def points(distances: np.ndarray, at: np.ndarray) -> np.ndarray:
        return np.column_stack(
            (
                scan.pose.x + distances * np.cos(at),
                scan.pose.y + distances * np.sin(at),
                np.full(distances.size, Z),
            )
        )

    beyond = np.full(int(no_return.sum()), clearing + RESOLUTION)
    return PeerCloud(
        points(r[is_return], angles[is_return]), points(beyond, angles[no_return]), clearing
    )


def insert(tree: pyoctomap.OcTree, scans: list[Scan], clouds: list[PeerCloud]) -> Timing:
    """Insert each scan's clouds from its sensor origin; wall time of OctoMap alone.

    ``lazy_eval=True`` skips the inner-node update after each scan, and one
    ``updateInnerOccupancy`` at the end (timed) makes the tree consistent: OctoMap's
    documented fast path for batches. (pyoctomap 1.2.2's ``lazy_eval=False`` runs a
    full-tree ``updateInnerOccupancy`` after every scan on top of OctoMap's own, ~1.7x
    slower here.) ``discretize`` stays False, the default: pyoctomap's discretize
    deduplicates endpoints in a Python loop before OctoMap sees them.
    """
    start = time.perf_counter()
    for scan, cloud in zip(scans, clouds, strict=True):
        origin = np.array([scan.pose.x, scan.pose.y, Z])
        if cloud.no_returns.size:
            tree.insertPointCloud(
                cloud.no_returns, origin, max_range=cloud.clearing, lazy_eval=True
            )
        if cloud.returns.size:
            tree.insertPointCloud(cloud.returns, origin, max_range=scan.range_max, lazy_eval=True)
    tree.updateInnerOccupancy()
    return Timing(len(scans), time.perf_counter() - start)


def octomap_states(
    tree: pyoctomap.OcTree, geometry: GridGeometry, cells: np.ndarray, model: SensorModel
) -> tuple[np.ndarray, np.ndarray]:
    """OctoMap's (observed, CellState) for flat grid indices ``cells``, by our thresholds.

    A cell is observed when OctoMap holds a node at its centre at height Z.
    """
    cols = cells % geometry.width
    rows = cells // geometry.width
    xs = geometry.origin_x + (cols + 0.5) * geometry.resolution
    ys = geometry.origin_y + (rows + 0.5) * geometry.resolution
    observed = np.zeros(cells.size, dtype=bool)
    p = np.full(cells.size, 0.5)
    for i, (x, y) in enumerate(zip(xs.tolist(), ys.tolist(), strict=True)):
        node = tree.search((x, y, Z))
        if node is not None:
            observed[i] = True
            p[i] = node.getOccupancy()
    states = np.full(cells.size, CellState.UNKNOWN, dtype=np.uint8)
    states[p > model.occupied_threshold] = CellState.OCCUPIED
    states[p < model.free_threshold] = CellState.FREE
    return observed, states


def compare(grid: BeliefGrid, tree: pyoctomap.OcTree, stamp: float) -> dict:
    """Agreement of ``grid`` (states at ``stamp``) and ``tree`` over cells both observed."""
    seen = np.flatnonzero(~np.isnan(grid.last_observed().ravel()))
    octo_seen, octo = octomap_states(tree, grid.geometry, seen, grid.sensor_model)
    ours = grid.states_at(stamp).ravel()[seen][octo_seen]
    octo = octo[octo_seen]
    confusion = np.zeros((3, 3), dtype=np.int64)
    np.add.at(confusion, (ours, octo), 1)
    both = int(octo_seen.sum())
    occupied = confusion[CellState.OCCUPIED]
    either = occupied.sum() + confusion[:, CellState.OCCUPIED].sum() - occupied[CellState.OCCUPIED]
    return {
        "agreement": float(np.mean(ours == octo)) if both else math.nan,
        # Free cells dominate the agreement; this is the occupied cells' own figure.
        "occupied_iou": float(occupied[CellState.OCCUPIED] / either) if either else math.nan,
        "cells_both": both,
        "cells_fleetmap_only": int(seen.size - both),
        "cells_octomap_only": int(tree.getNumLeafNodes() - both),
        "confusion": confusion.tolist(),
    }


def run(
    n_scans: int, n_octomap: int, seed: int, repeat: int = 1, with_profile: bool = False
) -> dict:
    warehouse = warehouse_layout(WIDTH_M, HEIGHT_M, seed)
    scans = sample_scans(warehouse, n_scans, beams=BEAMS, range_max=RANGE_MAX, seed=seed)
    width, height = round(WIDTH_M / RESOLUTION), round(HEIGHT_M / RESOLUTION)
    geometry = GridGeometry(width=width, height=height, resolution=RESOLUTION)
    model = SensorModel()

    warm = BeliefGrid(geometry, model, policy=Policy.DECAY)  # numba JIT / cache load, untimed
    warm.fuse(scans[0])
    warm.states_at()
    # OctoMap's model: every beam clears up to its endpoint, nothing between beams.
    beams_only = SensorModel(fill_between_beams=False, guard_glancing_faces=False)
    # The default and beams only, taken turn about ``repeat`` times; the fastest of each
    # (a shared machine's noise only ever slows a run down).
    ours = unfilled = grouped = dual = None
    for _ in range(repeat):
        a = fuse(BeliefGrid(geometry, model, policy=Policy.DECAY), scans)
        b = fuse(BeliefGrid(geometry, beams_only, policy=Policy.DECAY), scans)
        c = fuse_grouped(BeliefGrid(geometry, model, policy=Policy.DECAY), scans, GROUP)
        d = fuse(BeliefGrid(geometry, model, policy=Policy.DUAL), scans)
        ours = a if ours is None or a.seconds < ours.seconds else ours
        unfilled = b if unfilled is None or b.seconds < unfilled.seconds else unfilled
        grouped = c if grouped is None or c.seconds < grouped.seconds else grouped
        dual = d if dual is None or d.seconds < dual.seconds else dual

    subset = scans[:n_octomap]
    clearing = BeliefGrid(geometry, model, policy=Policy.DECAY).no_return_clearing
    # numpy prep, untimed: OctoMap's favour
    clouds = [point_cloud(scan, clearing(scan.range_max)) for scan in subset]
    insert(octree(model, RESOLUTION), subset[:1], clouds[:1])  # warm-up, untimed
    tree = octree(model, RESOLUTION)
    theirs = insert(tree, subset, clouds)

    # Agreement needs identical scan sets: fuse OctoMap's subset afresh for each policy.
    stamp = subset[-1].stamp
    agreement = {}
    for name, policy, decay in (
        ("decay", Policy.DECAY, None),
        ("no_fading", Policy.DECAY, NO_FADING),
        ("sticky", Policy.STICKY, None),
    ):
        grid = BeliefGrid(geometry, beams_only, policy=policy, decay=decay)
        fuse(grid, subset)
        agreement[name] = compare(grid, tree, stamp)

    parts = profile(geometry, model, scans, repeat) if with_profile else None
    return {
        "profile_us_per_scan": parts,
        "scans": ours.scans,
        "beams": BEAMS,
        "range_max_m": RANGE_MAX,
        "resolution_m": RESOLUTION,
        "grid": [geometry.width, geometry.height],
        "boxes": len(warehouse.world),
        "stamp_span_s": [scans[0].stamp, scans[-1].stamp],
        "fleetmap_s": ours.seconds,
        "fleetmap_scans_per_s": ours.scans_per_s,
        "fleetmap_cells_per_scan": ours.cells / ours.scans,
        "fleetmap_cell_updates_per_s": ours.cells / ours.seconds,
        "beams_only_scans_per_s": unfilled.scans_per_s,
        "dual_scans_per_s": dual.scans_per_s,
        "grouped_scans_per_s": grouped.scans_per_s,
        "grouped_cell_updates_per_s": grouped.cells / grouped.seconds,
        "grouped_speed_ratio": grouped.scans_per_s / theirs.scans_per_s,
        "beams_only_cells_per_scan": unfilled.cells / unfilled.scans,
        "octomap_scans": theirs.scans,
        "octomap_s": theirs.seconds,
        "octomap_scans_per_s": theirs.scans_per_s,
        "speed_ratio": ours.scans_per_s / theirs.scans_per_s,
        "agreement_stamp_s": stamp,
        "agreement": agreement["decay"]["agreement"],
        "agreement_no_fading": agreement["no_fading"]["agreement"],
        "agreement_sticky": agreement["sticky"]["agreement"],
        "agreement_detail": agreement,
        "pyoctomap": version("pyoctomap"),
    }


def report(r: dict) -> None:
    print(
        f"{r['scans']} scans x {r['beams']} beams, {r['range_max_m']} m range; grid "
        f"{r['grid'][0]} x {r['grid'][1]} at {r['resolution_m']} m; warehouse of "
        f"{r['boxes']} boxes; stamps {r['stamp_span_s'][0]:.3f}..{r['stamp_span_s'][1]:.3f} s"
    )
    print(
        f"fleetmap (decay, 1 core): {r['scans']} scans in {r['fleetmap_s']:.3f} s = "
        f"{r['fleetmap_scans_per_s']:.1f} scans/s, "
        f"{r['fleetmap_cell_updates_per_s'] / 1e6:.1f} M cell updates/s "
        f"({r['fleetmap_cells_per_scan']:.0f} cells/scan)"
    )
    print(
        f"fleetmap beams only (no fill, no guard): {r['beams_only_scans_per_s']:.1f} scans/s "
        f"({r['beams_only_cells_per_scan']:.0f} cells/scan)"
    )
    print(
        f"fleetmap dual (free-space history, 1 B/cell more): {r['dual_scans_per_s']:.1f} "
        f"scans/s ({r['dual_scans_per_s'] / r['fleetmap_scans_per_s']:.2f}x decay)"
    )
    print(
        f"OctoMap (pyoctomap {r['pyoctomap']}, insertPointCloud): {r['octomap_scans']} scans "
        f"in {r['octomap_s']:.3f} s = {r['octomap_scans_per_s']:.1f} scans/s"
    )
    print(f"speed ratio (scans/s, fleetmap / OctoMap): {r['speed_ratio']:.1f}x")
    print(
        f"fleetmap in groups of {GROUP} (fuse_many, as the server's ingest fuses a group): "
        f"{r['grouped_scans_per_s']:.1f} scans/s, "
        f"{r['grouped_cell_updates_per_s'] / 1e6:.1f} M cell updates/s, "
        f"{r['grouped_speed_ratio']:.1f}x OctoMap"
    )
    if r["profile_us_per_scan"] is not None:
        p = r["profile_us_per_scan"]
        print(
            f"profile [us/scan]: one batch {p['batch_us']:.0f} = mark {p['mark_us']:.0f} "
            f"(endpoints, traces, fill) + apply {p['apply_us']:.0f} (box of "
            f"{p['box_cells']:.0f} cells read); Python per fuse call {p['python_per_fuse_us']:.0f}"
        )
    detail = r["agreement_detail"]
    d = detail["decay"]
    print(
        f"agreement on the {r['octomap_scans']} scans OctoMap took, at stamp "
        f"{r['agreement_stamp_s']:.3f} s, over {d['cells_both']} cells both observed "
        f"(fleetmap only {d['cells_fleetmap_only']}, OctoMap only {d['cells_octomap_only']}):"
    )
    labels = {
        "decay": "decay (half lives 30 s occ / 120 s free)",
        "no_fading": "clamped log-odds, no fading (OctoMap's model)",
        "sticky": "sticky (no clamp, no fading)",
    }
    for key, label in labels.items():
        a = detail[key]
        print(
            f"  {label}: {100 * a['agreement']:.2f} % "
            f"(occupied cells IoU {100 * a['occupied_iou']:.1f} %)"
        )
    print("  confusion, decay (rows fleetmap, columns OctoMap; unknown / free / occupied):")
    for name, row in zip(("unknown", "free", "occupied"), d["confusion"], strict=True):
        print(f"    {name:>8}: " + " ".join(f"{v:>9}" for v in row))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=300, help="scans fleetmap fuses (300)")
    parser.add_argument(
        "--octomap-scans",
        type=int,
        default=None,
        help="the first M of them for OctoMap and the agreement (default: all)",
    )
    parser.add_argument("--seed", type=int, default=0, help="warehouse and patrol seed (0)")
    parser.add_argument(
        "--repeat", type=int, default=1, help="fleetmap runs, default and beams only in turn (1)"
    )
    parser.add_argument("--json", action="store_true", help="print the figures as JSON last")
    parser.add_argument(
        "--profile", action="store_true", help="also time the kernel's parts (mark, apply)"
    )
    args = parser.parse_args(argv)
    if args.scans < 1:
        parser.error(f"--scans must be >= 1, got {args.scans}")
    n_octomap = args.scans if args.octomap_scans is None else args.octomap_scans
    if not 1 <= n_octomap <= args.scans:
        parser.error(f"--octomap-scans must be in 1..{args.scans}, got {n_octomap}")
    if args.repeat < 1:
        parser.error(f"--repeat must be >= 1, got {args.repeat}")
    result = run(args.scans, n_octomap, args.seed, args.repeat, args.profile)
    report(result)
    if args.json:
        print(json.dumps(result))


if __name__ == "__main__":
    main()
