"""DUFOMap agreement benchmark: the returns fleetmap's ``dual`` map calls transient against
the points DUFOMap labels dynamic, on one recording, with both speeds, in one run.

Run: ``python -m tests.benchmarks.dufomap_agreement RECORDING [--fixed-sensor X,Y,YAW]
[--resolution R] [--near D] [--d-s D] [--json]``

RECORDING is any recording ``open_recording`` reads; the one it was written for is a laser
standing still while people walk past it (``angusleigh/leg_tracker``,
``rosbags/demos/demo_stationary_simple_environment.bag``, BSD-3-Clause), read with
``--fixed-sensor 0,0,0``. The grid is sized from the data (``fit_grid``) and the scans
are read into memory once; both maps then take the same scans.

The peer is ``dufomap`` (PyPI, the ``bench`` extra): the DUFOMap authors' own bindings
(Duberg et al., *DUFOMap: Efficient Dynamic Awareness Mapping*, RA-L 2024), 3D and
offline. Each scan's returns go in as points (x, y, 0) in the map frame with the
sensor's pose as a 4x4 matrix at z = 0 (``run``, one thread). ``d_p`` = 0: no inflation
of unknown space, since in a plane every cell borders unobserved height. ``d_s``, how
far before its hit a ray stops marking space void, is 0.2 m, the authors' default
(``inflate_hits_dist`` in their ``assets/config.toml``). They keep it at 0.2 m whatever
the voxel (0.1 m in the paper, 0.15 m and 0.2 m in their HiMo and SeFlow scripts): a
distance, not a count of voxels, so it is 0.2 m on this 0.05 m grid too (``--d-s``).
After the last scan the map is propagated (``oncePropagateCluster(if_propagate=True,
if_cluster=False)``, as the authors' ``main.py`` does before reading it) and ``segment``
labels every scan's points dynamic or static, against the whole recording.

fleetmap's map is a ``BeliefGrid`` under ``dual`` with the default sensor model
(docs/dual.md), fed the same scans one at a time. Each return gets two labels:

- *at fusion*: its cell was void (history 255) just before the scan was fused. This is
  the dual rule's online verdict: what appears in space seen free is transient.
- *at the end*: its cell is not occupied structure in the final map (history 253 or 254
  and OCCUPIED): the map did not keep it.

Printed: the recording and grid, then a table with, per labelling, the share of returns
labelled dynamic nearer than ``--near`` (3.5 m: where the people walk) and farther (the
wall, and anyone walking in front of it), and, for fleetmap's, agreement with DUFOMap
(share of returns labelled the same) and precision, recall and F1 of "dynamic" with
DUFOMap's labels as the reference. Speeds are scans/s on one thread: DUFOMap's ``run``
per scan (its propagation and ``segment`` apart) and fleetmap's ``fuse`` per scan, after
the numba kernels are loaded. Measures only; tests assert behaviour.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from types import ModuleType

import numpy as np

from mapserver.cli.recording_args import pose_triple
from mapserver.core.belief import BeliefGrid, CellState, load_fusion_kernels
from mapserver.core.fusion_kernel import HISTORY_VOID
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import BEAM_RETURN, Pose2D, Scan
from mapserver.core.sensor_model import Policy, SensorModel
from mapserver.store.recordings import RecordingError, RecordingOptions, open_recording
from mapserver.store.recordings.grid_fit import fit_grid
from scenarios.evaluate.octomap_peer import return_cloud

D_S = 0.2  # [m] DUFOMap's d_s: the authors' default (assets/config.toml), in metres
NEAR = 3.5  # [m] where the people of the leg_tracker demo walk, from the laser
INSTALL_HINT = "pip install 'fleetmap[bench]'"
BAG_HINT = (
    "pass a recording that exists, e.g. rosbags/demos/demo_stationary_simple_environment.bag "
    "of github.com/angusleigh/leg_tracker with --fixed-sensor 0,0,0"
)


# ------------------------------------------------------------------------ the maths
def ratio(numerator: float, denominator: float) -> float:
    """``numerator / denominator``, NaN when there is nothing to divide."""
    return numerator / denominator if denominator else math.nan


@dataclass(frozen=True)
class Agreement:
    """Labels against reference labels, "dynamic" the positive class."""

    points: int
    agreement: float  # share of points labelled as the reference labels them
    precision: float  # of the points labelled dynamic, the share the reference calls so
    recall: float  # of the points the reference calls dynamic, the share labelled so
    f1: float


def agreement(reference: np.ndarray, labels: np.ndarray) -> Agreement:
    """How ``labels`` (bool per point, True dynamic) agree with ``reference`` (the same)."""
    ref = np.asarray(reference, dtype=bool)
    lab = np.asarray(labels, dtype=bool)
    if ref.shape != lab.shape:
        raise ValueError(f"{lab.shape[0]} labels for {ref.shape[0]} reference labels")
    tp = int(np.count_nonzero(ref & lab))
    fp = int(np.count_nonzero(~ref & lab))
    fn = int(np.count_nonzero(ref & ~lab))
    return Agreement(
        points=ref.size,
        agreement=ratio(int(np.count_nonzero(ref == lab)), ref.size),
        precision=ratio(tp, tp + fp),
        recall=ratio(tp, tp + fn),
        f1=ratio(2 * tp, 2 * tp + fp + fn),
    )


def dynamic_share(labels: np.ndarray, where: np.ndarray) -> float:
    """The share of the points ``where`` selects that ``labels`` calls dynamic."""
    lab = np.asarray(labels, dtype=bool)
    sel = np.asarray(where, dtype=bool)
    return ratio(int(np.count_nonzero(lab & sel)), int(np.count_nonzero(sel)))


# ------------------------------------------------------------------------ the points
def return_points(scan: Scan) -> np.ndarray:
    """(n, 3) the scan's returns [m] in the map frame at z = 0, in beam order."""
    return return_cloud(scan, 0.0)


def return_ranges(scans: Sequence[Scan]) -> np.ndarray:
    """The range [m] of every scan's returns, in the order of ``return_points``."""
    ranges = [scan.ranges[scan.beam_classes() == BEAM_RETURN] for scan in scans]
    return np.concatenate(ranges or [np.zeros(0)])


def pose_matrix(pose: Pose2D) -> np.ndarray:
    """The planar pose as a 4x4 homogeneous transform at z = 0."""
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    matrix = np.eye(4)
    matrix[:2, :2] = [[c, -s], [s, c]]
    matrix[:2, 3] = [pose.x, pose.y]
    return matrix


def point_cells(points: np.ndarray, geometry: GridGeometry) -> np.ndarray:
    """Flat indices of the cells holding ``points`` ((n, 2+) [m]), computed as the fusion
    kernel computes a return's cell (``mark_scan``: times the inverse resolution), so a
    point on a cell's edge lands where its hit did; all must be on the grid."""
    inv_res = 1.0 / geometry.resolution
    cols = np.floor((points[:, 0] - geometry.origin_x) * inv_res).astype(np.int64)
    rows = np.floor((points[:, 1] - geometry.origin_y) * inv_res).astype(np.int64)
    inside = (cols >= 0) & (cols < geometry.width) & (rows >= 0) & (rows < geometry.height)
    if not inside.all():
        raise ValueError(f"{int(np.count_nonzero(~inside))} returns lie off the grid")
    return rows * geometry.width + cols


# ------------------------------------------------------------------------ the labellers
@dataclass(frozen=True)
class PeerLabels:
    """DUFOMap's labels of every scan's returns, in order, and its times [s]."""

    dynamic: np.ndarray  # bool per return
    run_s: float  # ``run`` of every scan: the integration
    label_s: float  # propagation and ``segment`` of every scan


def load_dufomap() -> ModuleType | None:
    """The ``dufomap`` package, or None when it is not installed."""
    try:
        return importlib.import_module("dufomap")
    except ImportError:
        return None


def dufomap_labels(
    scans: Sequence[Scan], resolution: float, d_s: float = D_S, module: ModuleType | None = None
) -> PeerLabels:
    """Every scan into DUFOMap (``resolution`` voxels, ``d_s``, ``d_p`` 0, one thread),
    then every scan's returns labelled against the whole recording (the module's
    docstring)."""
    dufo = module or importlib.import_module("dufomap")
    clouds = [return_points(scan) for scan in scans]
    poses = [pose_matrix(scan.pose) for scan in scans]
    peer = dufo.dufomap(resolution, d_s, 0, num_threads=1)
    start = time.perf_counter()
    for cloud, pose in zip(clouds, poses, strict=True):
        peer.run(cloud, pose, cloud_transform=False)
    run_s = time.perf_counter() - start
    start = time.perf_counter()
    peer.oncePropagateCluster(if_propagate=True, if_cluster=False)
    labels = [peer.segment(c, p, cloud_transform=False) for c, p in zip(clouds, poses, strict=True)]
    label_s = time.perf_counter() - start
    dynamic = np.concatenate([np.asarray(lab, dtype=bool) for lab in labels] or [np.zeros(0, bool)])
    return PeerLabels(dynamic, run_s, label_s)


@dataclass(frozen=True)
class FleetmapLabels:
    """fleetmap's two labels of every scan's returns, in order, and its fusion time [s]."""

    at_fusion: np.ndarray  # bool per return: its cell was void before the scan was fused
    at_end: np.ndarray  # bool per return: its cell is not occupied structure at the end
    fuse_s: float  # ``fuse`` of every scan


def fleetmap_labels(
    scans: Sequence[Scan], geometry: GridGeometry, model: SensorModel | None = None
) -> FleetmapLabels:
    """Every scan fused into a ``dual`` BeliefGrid, each fusion timed alone; each return
    labelled by its cell's history before its scan and by the final map."""
    grid = BeliefGrid(geometry, model or SensorModel(), Policy.DUAL)
    history = grid.history()  # the grid's own array, updated in place by ``fuse``
    cells, at_fusion = [], []
    fuse_s = 0.0
    for scan in scans:
        scan_cells = point_cells(return_points(scan), geometry)
        at_fusion.append(history[scan_cells] == HISTORY_VOID)
        start = time.perf_counter()
        grid.fuse(scan)
        fuse_s += time.perf_counter() - start
        cells.append(scan_cells)
    kept = grid.structure_mask().ravel() & (grid.states_at().ravel() == CellState.OCCUPIED)
    flat = np.concatenate(cells or [np.zeros(0, np.int64)])
    void_before = np.concatenate(at_fusion or [np.zeros(0, bool)])
    return FleetmapLabels(void_before, ~kept[flat], fuse_s)


# ------------------------------------------------------------------------ the report
@dataclass(frozen=True)
class Row:
    """One labelling's line of the table."""

    labels: str
    dynamic_near: float
    dynamic_far: float
    scans_per_s: float
    against_dufomap: Agreement | None = None


def rows(peer: PeerLabels, ours: FleetmapLabels, near: np.ndarray, scans: int) -> list[Row]:
    """The table's rows: DUFOMap's labels, then fleetmap's two against them."""
    fuse_speed = ratio(scans, ours.fuse_s)
    out = [
        Row(
            "DUFOMap (offline)",
            dynamic_share(peer.dynamic, near),
            dynamic_share(peer.dynamic, ~near),
            ratio(scans, peer.run_s),
        )
    ]
    for name, labels in (("at fusion", ours.at_fusion), ("at the end", ours.at_end)):
        out.append(
            Row(
                f"fleetmap dual, {name}",
                dynamic_share(labels, near),
                dynamic_share(labels, ~near),
                fuse_speed,
                agreement(peer.dynamic, labels),
            )
        )
    return out


def _share(value: float) -> str:
    return "-" if math.isnan(value) else f"{value:.3f}"


def markdown_table(table: list[Row], near_m: float) -> str:
    """The rows as a Markdown table."""
    lines = [
        f"| labels | dynamic < {near_m:g} m | dynamic >= {near_m:g} m | agreement | precision "
        "| recall | F1 | scans/s |",
        "|---|" + "---:|" * 7,
    ]
    for row in table:
        a = row.against_dufomap
        scores = (a.agreement, a.precision, a.recall, a.f1) if a else (math.nan,) * 4
        cells = [row.labels, _share(row.dynamic_near), _share(row.dynamic_far)]
        cells += [_share(v) for v in scores] + [f"{row.scans_per_s:,.0f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recording", type=Path, metavar="RECORDING")
    parser.add_argument(
        "--fixed-sensor",
        type=pose_triple,
        metavar="X,Y,YAW",
        help="the sensor stood still at this pose (a recording without poses)",
    )
    parser.add_argument("--resolution", type=float, default=0.05, help="[m/cell], both maps")
    parser.add_argument("--near", type=float, default=NEAR, help="[m] from the sensor")
    parser.add_argument("--d-s", type=float, default=D_S, help="[m] DUFOMap's d_s")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON last")
    args = parser.parse_args(argv)
    dufo = load_dufomap()
    if dufo is None:
        print(
            f"error: the DUFOMap peer needs dufomap, which is not installed: {INSTALL_HINT}",
            file=sys.stderr,
        )
        return 2
    if not args.recording.exists():
        print(f"error: no recording at {args.recording}: {BAG_HINT}", file=sys.stderr)
        return 2
    try:
        recording = open_recording(args.recording, RecordingOptions(fixed_sensor=args.fixed_sensor))
        scans = list(recording)
        geometry = fit_grid(scans, args.resolution)
    except RecordingError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    load_fusion_kernels()
    peer = dufomap_labels(scans, args.resolution, args.d_s, dufo)
    ours = fleetmap_labels(scans, geometry)
    near = return_ranges(scans) < args.near
    table = rows(peer, ours, near, len(scans))
    print(
        f"{recording.describe()}\n{len(scans):,} scans, {near.size:,} returns "
        f"({int(near.sum()):,} nearer than {args.near:g} m); grid {geometry.width} x "
        f"{geometry.height} of {args.resolution:g} m; DUFOMap {dufo.__version__}, d_s "
        f"{args.d_s:g} m, d_p 0, one thread\n"
    )
    print(markdown_table(table, args.near))
    print(
        f"DUFOMap: run {peer.run_s:.2f} s, propagation and segment {peer.label_s:.2f} s; "
        f"fleetmap dual: fuse {ours.fuse_s:.2f} s (scans/s: run and fuse alone, one thread)"
    )
    if args.json:
        figures = {"scans": len(scans), "returns": int(near.size), "near": int(near.sum())}
        figures |= {"run_s": peer.run_s, "label_s": peer.label_s, "fuse_s": ours.fuse_s}
        print(json.dumps({**figures, "rows": [asdict(row) for row in table]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
