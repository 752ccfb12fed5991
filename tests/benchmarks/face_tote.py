"""Tote-against-a-face benchmark: a tote set down against a rack face, then taken away
while a unit drives toward it. How soon do the tote's cells clear, and how much of the
face behind and beside it stays lethal?

Run: ``python tests/benchmarks/face_tote.py [--policies P,...] [--sensors clean,flawed]
[--speed V] [--resolution R] [--set KEY=VALUE ...] [--json]``

The set-up: a 20 m x 10 m floor walled all round, a rack row whose face runs along
y = 6 m from x = 2 to 18 m, and a unit with a 360-beam, 10 Hz LiDAR (range_max 20 m,
the simulator's, ``fleet.lidar``). Everything runs through the map server's own code
path in-process (``MapService``: the gate, the journal, fusion, the layered costmap).

1. *Before*: the unit drives the aisle along y = 3 m (x 3 to 17 m at 1.5 m/s) with
   nothing in front of the face: the floor there is seen free, the face is mapped.
2. *Set down*: a 0.6 m x 0.4 m tote is put against the face at x = 10 m (y 5.6 to
   6.0 m), and the unit drives the aisle back: the map holds the tote.
3. *Taken away*: the tote is removed, and a unit at (10, 1) m drives straight toward
   the face at ``--speed`` (default 1 m/s) to y = 4.5 m, then stands there scanning,
   for 15 s in all.

Printed per policy and sensor (``clean``: no noise; ``flawed``: 2 cm range noise and 5 %
dropouts, as ``scenarios/dropouts.yaml``):

- ``tote_before``: the tote's cells LETHAL when phase 3 starts (its cells whose centres
  it covers, but the row against the face, where the face's own returns land);
- ``clear_s``: [s] from the first scan of phase 3 with a beam crossing the tote's
  footprint until none of those cells is LETHAL (None: not within the 15 s);
- ``face_kept``: the share of the face's columns from x = 2.5 to 17.5 m (all of it but
  its ends: square on behind the tote, glancing far to its sides) that hold a LETHAL
  cell in the face's row or the one before it, at the end of phase 3.

Measures only; tests assert behaviour.
"""

from __future__ import annotations

import sys
from pathlib import Path

# Run as a script, this file's folder comes first on sys.path and would shadow the
# ``fleet`` package (tests/benchmarks/fleet.py): this checkout's root instead.
HERE = Path(__file__).resolve().parent
sys.path[:] = [str(HERE.parents[1])] + [p for p in sys.path if Path(p or ".").resolve() != HERE]

import argparse  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402

import numpy as np  # noqa: E402

from fleet.ground_truth import cells_of_bounds  # noqa: E402
from fleet.layout import Kind, Layout, Obstacle  # noqa: E402
from fleet.lidar import Lidar, LidarConfig  # noqa: E402
from fleet.shapes import Box  # noqa: E402
from fleet.world import World  # noqa: E402
from mapserver.core.costvalues import LETHAL  # noqa: E402
from mapserver.core.scan import Pose2D, Scan  # noqa: E402
from mapserver.service.map_service import MapService  # noqa: E402
from tests.benchmarks.clearing_speed import (  # noqa: E402
    SENSORS,
    UNIT_RADIUS,
    crossed,
    measured_scan,
    perimeter_walls,
    settings_for,
    settings_overrides,
    since,
)

FLOOR = (20.0, 10.0)  # [m]
FACE_Y = 6.0  # [m] the rack row's face
TOTE = (10.0, FACE_Y - 0.2, 0.6, 0.4)  # centre x, y, width, depth [m]
AISLE_Y = 3.0  # [m]
APPROACH = (1.0, 4.5)  # [m] from and to y, at x = 10 m
WATCH_S = 15.0  # [s] of phase 3
FACE_SEEN = (2.5, 17.5)  # [m] the face's x span measured: all of it but its ends


class Drive:
    """One unit's scans into the service: ``scan_at(x, y, yaw)`` moves it, scans, posts."""

    def __init__(self, world: World, lidar: Lidar, service: MapService, period: float) -> None:
        self.world, self.lidar, self.service, self.period = world, lidar, service, period
        self.stamp = 0.0

    def scan_at(self, x: float, y: float, yaw: float) -> Scan:
        self.stamp += self.period
        pose = Pose2D(float(x), float(y), float(yaw))
        self.world.set_unit_pose("u1", pose)
        scan = measured_scan(self.world, self.lidar, self.stamp, pose)
        self.service.ingest([scan])
        return scan


def run_case(policy: str, sensor: str, speed: float, resolution: float, extra: dict) -> dict:
    """The three phases for one policy and sensor; the figures of phase 3."""
    rack = Obstacle("rack", Kind.RACK, Box(10.0, FACE_Y + 0.5, 16.0, 1.0))
    tote = Obstacle("tote", Kind.TOTE, Box(*TOTE))
    layout = Layout(FLOOR[0], FLOOR[1], obstacles=(rack, *perimeter_walls(FLOOR)))
    config = LidarConfig(**SENSORS[sensor])
    lidar = Lidar(config, UNIT_RADIUS, np.random.default_rng(0))
    aisle = np.arange(3.0, 17.0 + 1e-9, 1.5 * config.period)
    with tempfile.TemporaryDirectory() as tmp, World(layout) as world:
        world.add_unit("u1", UNIT_RADIUS, 0.4, Pose2D(3.0, AISLE_Y, 0.0))
        service = MapService(settings_for(policy, Path(tmp), resolution, extra))
        try:
            drive = Drive(world, lidar, service, config.period)
            for x in aisle:  # 1. before: the floor in front of the face seen free
                drive.scan_at(x, AISLE_Y, 0.0)
            world.add(tote)
            for x in aisle[::-1]:  # 2. the tote set down, mapped
                drive.scan_at(x, AISLE_Y, np.pi)
            geometry = service.geometry
            # The tote's cells but the row against the face: the face's own returns land
            # there (a return at y = 6.0 m exactly rounds into either row).
            x0, y0, x1, y1 = tote.shape.bounds()
            footprint = cells_of_bounds(geometry, (x0, y0, x1, y1 - resolution)).slices
            tote_before = int((service.costmap_read().data[footprint] == LETHAL).sum())
            world.remove("tote")
            first = clear_at = None
            y, steps = APPROACH[0], int(round(WATCH_S / config.period))
            for _ in range(steps):  # 3. taken away; the unit drives toward the face
                scan = drive.scan_at(TOTE[0], y, np.pi / 2)
                y = min(y + speed * config.period, APPROACH[1])
                angles = scan.angle_min + scan.angle_increment * np.arange(scan.beam_count)
                reach = np.where(np.isfinite(scan.ranges), scan.ranges, 0.0)
                if (
                    first is None
                    and crossed(
                        TOTE[0], scan.pose.y, angles, reach, np.array([tote.shape.bounds()])
                    )[0]
                ):
                    first = scan.stamp
                lethal = service.costmap_read().data[footprint] == LETHAL
                if first is not None and clear_at is None and not lethal.any():
                    clear_at = scan.stamp
            costs = service.costmap_read().data
            face_row = geometry.world_to_cell(TOTE[0], FACE_Y + 1e-6)[1]
            c0 = geometry.world_to_cell(FACE_SEEN[0], FACE_Y)[0]
            c1 = geometry.world_to_cell(FACE_SEEN[1], FACE_Y)[0]
            face = costs[face_row - 1 : face_row + 1, c0:c1] == LETHAL
            face_kept = float(face.any(axis=0).mean())
        finally:
            service.close()
    return {
        "policy": policy,
        "sensor": sensor,
        "tote_before": tote_before,
        "clear_s": since(clear_at, first),
        "face_kept": round(face_kept, 3),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policies", default="decay,binary,sticky,dual")
    parser.add_argument("--sensors", default="clean,flawed")
    parser.add_argument("--speed", type=float, default=1.0, help="[m/s] of the approach")
    parser.add_argument("--resolution", type=float, default=0.1, help="[m] grid cell")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    extra = settings_overrides(args.set)
    rows = []
    for sensor in args.sensors.split(","):
        for policy in args.policies.split(","):
            row = run_case(policy, sensor, args.speed, args.resolution, extra)
            rows.append(row)
            clear = "never" if row["clear_s"] is None else f"{row['clear_s']:4.1f} s"
            print(
                f"{sensor:7} {policy:7} tote cells lethal before {row['tote_before']:3d}  "
                f"clear {clear:>7}  face kept {100 * row['face_kept']:5.1f} %",
                flush=True,
            )
    if args.json:
        print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
