"""Clearing benchmark: how soon after the first scans cross a moved shelf's old place the
shared costmap lets a path through it.

Run: ``python tests/benchmarks/clearing_speed.py [--policies P,...] [--distances D,...]
[--speed V] [--resolution R] [--set KEY=VALUE ...] [--json]``

The set-up (the issue's): a 30 m aisle (x = 5 .. 35 m) on a 40 m x 16 m floor walled
all round, a 1.2 m x 1.2 m pod at (20, 8) m standing 1.4 m in front of a rack row (its
face at y = 10 m: the beams through the pod's old place return from it, as they would
from the racks across an aisle), a unit with a 360-beam, 10 Hz LiDAR (range_max 20 m)
driving along the aisle at ``--speed`` (default 1.5 m/s, a unit's ``max_speed``) with the
pod's centre ``distance`` m to its side (default 2, 3, 4, 5, 6 m). Everything runs through
the map server's own code path in-process (``MapService``: the gate, the journal, fusion, the
layered costmap with inflation), on a fresh data dir per case, and the LiDAR is the
simulator's (PyBullet ``rayTestBatch``, ``fleet.lidar``).

1. *Mapping pass*: the unit drives the aisle with the pod in place; the map holds its
   faces occupied (as strong as the clamp lets them be).
2. The pod is removed, and at once (no time for decay to help) the unit drives the aisle
   again. From the first scan with a beam crossing the pod's old footprint:

- ``open_s``: [s] until a straight path across the footprint opens: the footprint's
  centre row or centre column has no cell INSCRIBED (253) or LETHAL (254) (unknown
  allowed, as the planner allows it);
- ``open_seen_s``: [s] the same opening, counted instead from the scan by which beams
  had crossed every LETHAL cell that blocked that path (within the inscribed radius of
  it): how long the map takes once the unit can see the way, apart from when it can;
- ``clear_s``: [s] until no cell of the footprint is INSCRIBED or LETHAL (the last of
  its old face cells stops blocking);
- each ``None`` if it never happens on the pass.

Two sensors: ``clean`` (no noise, no dropouts) and ``flawed`` (2 cm range noise, 5 %
dropouts, as ``scenarios/dropouts.yaml``). ``--set sensor_model.clamp_max=3.5`` (dotted
server settings, values read as YAML) runs other map settings. Measures only; tests
assert behaviour.
"""

from __future__ import annotations

import sys
from pathlib import Path

# Run as a script, this file's directory comes first on sys.path and this file would
# shadow the ``fleet`` package: drop the directory before importing the project.
HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != HERE]

import argparse  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

from fleet.ground_truth import cells_of_bounds  # noqa: E402
from fleet.layout import Kind, Layout, Obstacle  # noqa: E402
from fleet.lidar import Lidar, LidarConfig  # noqa: E402
from fleet.shapes import Box  # noqa: E402
from fleet.world import World  # noqa: E402
from mapserver.core.costvalues import INSCRIBED, LETHAL  # noqa: E402
from mapserver.core.scan import Pose2D, Scan  # noqa: E402
from mapserver.service.map_service import MapService  # noqa: E402
from mapserver.service.settings import load_settings  # noqa: E402

FLOOR = (40.0, 16.0)  # [m]
POD = (20.0, 8.0, 1.2)  # centre x, y and side [m]
AISLE = (5.0, 35.0)  # [m] where the unit drives
BACK_M = 2.0  # [m] from the pod's centre to the face of the rack row behind it
UNIT_RADIUS = 0.3  # [m]
SENSORS = {
    "clean": {"range_noise": 0.0, "dropout_prob": 0.0},
    "flawed": {"range_noise": 0.02, "dropout_prob": 0.05},
}


@dataclass
class Case:
    """One pass-by: ``policy``, the pod's lateral ``distance`` [m], the ``sensor``."""

    policy: str
    distance: float
    sensor: str


def crossed(
    x: float, y: float, angles: np.ndarray, ranges: np.ndarray, boxes: np.ndarray
) -> np.ndarray:
    """Per box (rows of xmin, ymin, xmax, ymax [m]): whether a beam from (x, y) [m] at
    ``angles`` [rad] enters it before its end, ``ranges`` [m]."""
    c, s, r = np.cos(angles), np.sin(angles), ranges
    with np.errstate(divide="ignore", invalid="ignore"):
        tx0 = (boxes[:, 0:1] - x) / c
        tx1 = (boxes[:, 2:3] - x) / c
        ty0 = (boxes[:, 1:2] - y) / s
        ty1 = (boxes[:, 3:4] - y) / s
    t_in = np.maximum(np.minimum(tx0, tx1), np.minimum(ty0, ty1))
    t_out = np.minimum(np.maximum(tx0, tx1), np.maximum(ty0, ty1))
    return np.any((t_in < t_out) & (t_out > 0) & (t_in < r), axis=1)


def measured_scan(world: World, lidar: Lidar, stamp: float, pose: Pose2D) -> Scan:
    """Unit ``u1``'s LiDAR scan at ``stamp`` [s] from ``pose`` (already set in ``world``),
    its ranges at the journal's float32 precision, as a unit posts them."""
    config = lidar.config
    ranges = lidar.measure(world, "u1").astype(np.float32).astype(np.float64)
    return Scan(
        "u1", stamp, pose, lidar.angle_min, lidar.angle_increment,
        config.range_min, config.range_max, ranges,
    )  # fmt: skip


def settings_overrides(items: list[str]) -> dict[str, Any]:
    """``--set KEY=VALUE`` items as dotted settings, each value read as YAML."""
    overrides: dict[str, Any] = {}
    for item in items:
        key, _, value = item.partition("=")
        overrides[key] = yaml.safe_load(value)
    return overrides


def settings_for(policy: str, data_dir: Path, resolution: float, extra: dict[str, Any]) -> Any:
    overrides = {
        "data_dir": str(data_dir),
        "policy": policy,
        "grid.width": int(round(FLOOR[0] / resolution)),
        "grid.height": int(round(FLOOR[1] / resolution)),
        "grid.resolution": resolution,
        "journal.synchronous": "OFF",
        **extra,
    }
    return load_settings(None, overrides)


def perimeter_walls(floor: tuple[float, float] = FLOOR, thickness: float = 0.3) -> list[Obstacle]:
    """Walls around a ``floor`` (width, height [m]), so that every beam returns (a
    no-return beam is weak evidence and clears only near the unit: docs/no-return.md)."""
    w, h, t = floor[0], floor[1], thickness
    boxes = {
        "wall-s": Box(w / 2, t / 2, w, t),
        "wall-n": Box(w / 2, h - t / 2, w, t),
        "wall-w": Box(t / 2, h / 2, t, h),
        "wall-e": Box(w - t / 2, h / 2, t, h),
    }
    return [Obstacle(name, Kind.WALL, box) for name, box in boxes.items()]


def blocking(costs: np.ndarray) -> np.ndarray:
    """Cells a unit may not enter: INSCRIBED or LETHAL (unknown, 255, is allowed)."""
    return (costs == INSCRIBED) | (costs == LETHAL)


def cell_boxes(geometry: Any, cells: np.ndarray) -> np.ndarray:
    """[m] (xmin, ymin, xmax, ymax) of each (row, col) in ``cells``."""
    res = geometry.resolution
    x0 = geometry.origin_x + cells[:, 1] * res
    y0 = geometry.origin_y + cells[:, 0] * res
    return np.stack([x0, y0, x0 + res, y0 + res], axis=1)


def lethal_near(costs: np.ndarray, path: tuple[slice, slice], reach: int) -> np.ndarray:
    """(row, col) of the LETHAL cells within ``reach`` cells of the cells of ``path``:
    the ones whose inflation can block it."""
    rows, cols = path
    grown = (
        slice(max(rows.start - reach, 0), rows.stop + reach),
        slice(max(cols.start - reach, 0), cols.stop + reach),
    )
    found = np.argwhere(costs[grown] == LETHAL)
    return found + [grown[0].start, grown[1].start]


def run_case(
    case: Case, speed: float, resolution: float, extra: dict[str, Any], trace: bool = False
) -> dict:
    """Both passes of one case; the pass-by's times and counts."""
    pod = Obstacle("pod", Kind.POD, Box(POD[0], POD[1], POD[2], POD[2]))
    # The aisle's far side: a rack row whose face is BACK_M behind the pod's centre.
    back = Obstacle("rack", Kind.RACK, Box(FLOOR[0] / 2, POD[1] + BACK_M + 0.5, 36.0, 1.0))
    layout = Layout(FLOOR[0], FLOOR[1], obstacles=(pod, back, *perimeter_walls()))
    config = LidarConfig(**SENSORS[case.sensor])
    lidar = Lidar(config, UNIT_RADIUS, np.random.default_rng(0))
    lane_y = POD[1] - case.distance
    step = speed * config.period  # [m] per scan
    xs = np.arange(AISLE[0], AISLE[1] + 1e-9, step)
    with tempfile.TemporaryDirectory() as tmp, World(layout) as world:
        service = MapService(settings_for(case.policy, Path(tmp), resolution, extra))
        try:
            geometry = service.geometry
            footprint = cells_of_bounds(geometry, pod.shape.bounds()).slices
            rows, cols = footprint
            # Straight paths across the footprint: its centre row and its centre column.
            mid_row = (rows.start + rows.stop) // 2
            mid_col = (cols.start + cols.stop) // 2
            paths = [(slice(mid_row, mid_row + 1), cols), (rows, slice(mid_col, mid_col + 1))]
            world.add_unit("u1", UNIT_RADIUS, 0.4, Pose2D(xs[0], lane_y, 0.0))
            clock = {"stamp": 0.0}

            def scan_at(x: float) -> Scan:
                clock["stamp"] += config.period
                pose = Pose2D(float(x), lane_y, 0.0)
                world.set_unit_pose("u1", pose)
                scan = measured_scan(world, lidar, clock["stamp"], pose)
                service.ingest([scan])
                return scan

            for x in xs:
                scan_at(x)
            costs = service.costmap_read().data
            mapped = int(blocking(costs[footprint]).sum())
            reach = int(np.ceil(service.settings.inflation.inscribed_radius / resolution))
            # Per path: the lethal cells that block it, and whether a return crossed each.
            blockers = [lethal_near(costs, path, reach) for path in paths]
            seen = [np.zeros(len(b), dtype=bool) for b in blockers]
            seen_at: list[float | None] = [None if len(b) else 0.0 for b in blockers]
            world.remove("pod")
            no_return_m = service.belief.no_return_clearing(config.range_max)
            first = open_at = clear_at = None
            opened = -1
            for x in xs:
                scan = scan_at(x)
                stamp = scan.stamp
                angles = scan.angle_min + scan.angle_increment * np.arange(scan.beam_count)
                # How far each beam reaches: its return, or as far as a no-return clears.
                reach_m = np.where(np.isfinite(scan.ranges), scan.ranges, no_return_m)
                if (
                    first is None
                    and crossed(x, lane_y, angles, reach_m, np.array([pod.shape.bounds()]))[0]
                ):
                    first = stamp
                for k, cells in enumerate(blockers):
                    if seen_at[k] is None:
                        boxes = cell_boxes(geometry, cells)
                        seen[k] |= crossed(x, lane_y, angles, reach_m, boxes)
                        if seen[k].all():
                            seen_at[k] = stamp
                if first is None:
                    continue
                costs = service.costmap_read().data
                block = blocking(costs[footprint])
                if trace:
                    lo = service.belief.log_odds_at()[footprint]
                    print(
                        f"  t {stamp - first:4.1f} s  x {x:5.2f} m  blocking "
                        f"{int(block.sum()):3d}  lethal "
                        f"{int((costs[footprint] == LETHAL).sum()):3d}  max log-odds "
                        f"{lo[np.isfinite(lo)].max():5.2f}  paths seen {seen_at}"
                    )
                if open_at is None:
                    for k, path in enumerate(paths):
                        if not blocking(costs[path]).any():
                            open_at, opened = stamp, k
                            break
                if clear_at is None and not block.any():
                    clear_at = stamp
                if clear_at is not None:
                    break
        finally:
            service.close()
    seen_opened = seen_at[opened] if opened >= 0 else None
    return {
        "policy": case.policy,
        "distance_m": case.distance,
        "sensor": case.sensor,
        "blocking_before": mapped,
        "open_s": since(open_at, first),
        "open_seen_s": since(open_at, seen_opened),
        "clear_s": since(clear_at, first),
    }


def since(end: float | None, start: float | None) -> float | None:
    """[s] from start to end, rounded to a scan; None if either is missing."""
    return None if end is None or start is None else round(end - start, 2)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policies", default="decay,binary,sticky")
    parser.add_argument("--distances", default="2,3,4,5,6", help="[m] comma-separated")
    parser.add_argument("--sensors", default="clean,flawed")
    parser.add_argument("--speed", type=float, default=1.5, help="[m/s]")
    parser.add_argument("--resolution", type=float, default=0.1, help="[m] grid cell")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--trace", action="store_true", help="a line per scan after crossing")
    args = parser.parse_args(argv)
    extra = settings_overrides(args.set)
    rows = []
    for sensor in args.sensors.split(","):
        for policy in args.policies.split(","):
            for distance in (float(d) for d in args.distances.split(",")):
                case = Case(policy, distance, sensor)
                rows.append(run_case(case, args.speed, args.resolution, extra, args.trace))
                r = rows[-1]
                print(
                    f"{sensor:7} {policy:7} {distance:4.1f} m  blocking before "
                    f"{r['blocking_before']:4d}  open {fmt(r['open_s'])}  "
                    f"open after its blockers were seen {fmt(r['open_seen_s'])}  "
                    f"clear {fmt(r['clear_s'])}",
                    flush=True,
                )
    if args.json:
        for r in rows:
            print(json.dumps({"set": extra, **r}))
    return 0


def fmt(value: float | None) -> str:
    return "never" if value is None else f"{value:5.1f} s"


if __name__ == "__main__":
    raise SystemExit(main())
