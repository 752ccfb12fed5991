"""Fleet simulator benchmark: sim steps and LiDAR rays per second against bare ray casting.

Run: ``python tests/benchmarks/sim.py [--steps N] [--threads T] [--server-seconds S]
[--server-units 50 100] [--skip-bare] [--json]``

The world is the default ``fleet.boxworld`` warehouse (100 m x 50 m, 107 walls, racks and
pallets) in PyBullet. Units stand spread along the horizontal lanes, each driving along
its lane at up to 1.5 m/s, with a 10 Hz LiDAR (range 20 m, range noise, dropouts and
spurious returns on, localisation noise on) and ``dt = 0.1`` s, so every unit scans at
every step.

1. For 10, 50 and 100 units with 360 and 1080 beams: ``--steps`` sim steps (``FleetSim``:
   motion, contacts, ray casting, flaws, scans; no server). Right after each step, in the
   same world, the same rays are cast bare: their ends are precomputed as lists
   (untimed) and only the ``rayTestBatch`` calls (same ``numThreads``) are timed, two
   ways, the faster counting: all rays in the map frame in chunks of at most 16383, and
   one call per unit with the rays in its body frame (``parentObjectUniqueId``: the calls
   the sim makes, and nothing else).
   Printed: sim steps/s, sim rays/s, bare rays/s (both ways), the sim's overhead over
   the faster bare casting [%], and the real-time factor (sim seconds per wall second)
   without a server.
2. With the map server: ``fleetmap serve`` with its default settings (2000 x 1000 cells at
   0.05 m, ``decay``, journal ``synchronous=FULL``) on 127.0.0.1 in a subprocess, and
   ``--server-units`` (50 and 100) units with 360 beams posting each step's scans as
   one batch (``ScanPoster``, binary scans) for ``--server-seconds`` of sim time, once
   waiting for each batch's acks and once with two batches in flight (a worker thread
   posts while the sim runs on). Printed: the real-time factor of each.

``--json`` prints every figure as one JSON object on the last line. Tests assert
behaviour; this script only measures.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import time

import httpx
import numpy as np
import pybullet as p

from fleet.boxworld import Warehouse, warehouse_layout
from fleet.layout import Layout
from fleet.lidar import LidarConfig
from fleet.localization import PoseNoise
from fleet.poster import ScanPoster
from fleet.sim import FleetSim, UnitSpec
from fleet.world import RAY_BATCH_MAX, World
from mapserver.client import MapClient
from mapserver.core.scan import Pose2D

DT = 0.1  # [s] one step, one scan per unit at 10 Hz
SPACING_M = 4.0  # [m] between neighbouring units on a lane


def unit_specs(warehouse: Warehouse, count: int, beams: int) -> list[UnitSpec]:
    """``count`` units spread over the horizontal lanes, ``SPACING_M`` apart, facing +x."""
    lidar = LidarConfig(beams=beams, range_noise=0.01, dropout_prob=0.01, spurious_prob=0.001)
    noise = PoseNoise(std_xy=0.02, std_yaw=0.005)
    lanes = warehouse.lane_y
    x0 = warehouse.lane_x[0]
    per_lane = math.ceil(count / len(lanes))
    if x0 + per_lane * SPACING_M > warehouse.width - 10:
        raise ValueError(f"{count} units do not fit on {len(lanes)} lanes")
    return [
        UnitSpec(
            f"u{k + 1}",
            Pose2D(x0 + (k // len(lanes)) * SPACING_M, lanes[k % len(lanes)], 0.0),
            lidar=lidar,
            pose_noise=noise,
        )
        for k in range(count)
    ]


def drive_along_lanes(sim: FleetSim, warehouse: Warehouse) -> None:
    x_end = warehouse.lane_x[-1]
    for unit in sim.units.values():
        sim.unit(unit.spec.unit_id).follow([(x_end, unit.spec.start.y)])


def world_rays(
    poses: list[Pose2D], config: LidarConfig, start: float
) -> tuple[list[list[float]], list[list[float]]]:
    """Every unit's beams' ray ends in the map frame (as ``fleet.lidar`` casts them); for
    one pose at the origin, a unit's rays in its body frame."""
    angles = np.array([q.yaw for q in poses])[:, None] + config.angles()[None, :]
    xy = np.array([[q.x, q.y] for q in poses])[:, None, :]
    direction = np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    z = np.full(angles.shape + (1,), config.height)
    ray_from = np.concatenate([xy + start * direction, z], axis=-1).reshape(-1, 3)
    ray_to = np.concatenate([xy + config.range_max * direction, z], axis=-1).reshape(-1, 3)
    return ray_from.tolist(), ray_to.tolist()


def measure(warehouse: Warehouse, units: int, beams: int, steps: int, threads: int) -> dict:
    specs = unit_specs(warehouse, units, beams)
    with World(Layout.from_warehouse(warehouse), ray_threads=threads) as world:
        sim = FleetSim(world, specs, seed=1)
        drive_along_lanes(sim, warehouse)
        sim.step(DT)  # warm up
        start = next(iter(sim.units.values())).lidar.start
        config = specs[0].lidar
        local_from, local_to = world_rays([Pose2D(0.0, 0.0, 0.0)], config, start)
        bodies = [world.body_id(spec.unit_id) for spec in specs]
        sim_wall = bare_map = bare_body = 0.0
        for _ in range(steps):  # interleaved, so a change of machine load hits all three
            t0 = time.perf_counter()
            sim.step(DT)
            sim_wall += time.perf_counter() - t0
            poses = [world.unit_pose(spec.unit_id) for spec in specs]
            ray_from, ray_to = world_rays(poses, config, start)
            t0 = time.perf_counter()
            for i in range(0, len(ray_from), RAY_BATCH_MAX):
                p.rayTestBatch(
                    ray_from[i : i + RAY_BATCH_MAX],
                    ray_to[i : i + RAY_BATCH_MAX],
                    numThreads=threads,
                    physicsClientId=world.client_id,
                )
            t1 = time.perf_counter()
            for body in bodies:
                p.rayTestBatch(
                    local_from,
                    local_to,
                    numThreads=threads,
                    parentObjectUniqueId=body,
                    parentLinkIndex=-1,
                    physicsClientId=world.client_id,
                )
            t2 = time.perf_counter()
            bare_map += t1 - t0
            bare_body += t2 - t1
    rays = units * beams * steps
    return {
        "units": units,
        "beams": beams,
        "steps_per_s": steps / sim_wall,
        "sim_rays_per_s": rays / sim_wall,
        "bare_map_frame_rays_per_s": rays / bare_map,
        "bare_body_frame_rays_per_s": rays / bare_body,
        "overhead_pct": 100.0 * (sim_wall / min(bare_map, bare_body) - 1.0),
        "realtime_factor": steps * DT / sim_wall,
    }


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def with_server(
    warehouse: Warehouse, sim_seconds: float, threads: int, in_flight: int, units: int = 50
) -> dict:
    """``units`` x 360 beams at 10 Hz posting to a real default map server."""
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    with tempfile.TemporaryDirectory() as data_dir:
        cmd = [sys.executable, "-m", "scenarios.cli.main", "serve", "--host", "127.0.0.1",
               "--port", str(port), "--data-dir", data_dir]  # fmt: skip
        env = {k: v for k, v in os.environ.items() if not k.startswith("FLEETMAP_")}
        server = subprocess.Popen(cmd, env=env, stderr=subprocess.DEVNULL)
        try:
            deadline = time.monotonic() + 120
            while True:
                try:
                    if httpx.get(url + "/healthz", timeout=1).status_code == 200:
                        break
                except httpx.HTTPError:
                    pass
                if time.monotonic() > deadline or server.poll() is not None:
                    raise RuntimeError("the map server did not start")
                time.sleep(0.2)
            specs = unit_specs(warehouse, units, 360)
            with (
                httpx.Client(base_url=url, timeout=60) as http,
                World(Layout.from_warehouse(warehouse), ray_threads=threads) as world,
            ):
                poster = ScanPoster(MapClient(http), in_flight=in_flight)
                sim = FleetSim(world, specs, seed=1, poster=poster)
                drive_along_lanes(sim, warehouse)
                sim.step(DT)  # warm up
                poster.flush()
                steps = round(sim_seconds / DT)
                started = time.perf_counter()
                for _ in range(steps):
                    sim.step(DT)
                poster.flush()
                wall = time.perf_counter() - started
                poster.close()
                version = MapClient(http).map_meta().version
        finally:
            server.terminate()
            server.wait(timeout=30)
    return {
        "units": units,
        "beams": 360,
        "in_flight": in_flight,
        "sim_seconds": steps * DT,
        "wall_seconds": wall,
        "realtime_factor": steps * DT / wall,
        "scans_posted": poster.posted,
        "map_version": version,
    }


def main(argv: list[str] | None = None) -> dict[str, object]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=30, help="timed sim steps per case")
    parser.add_argument("--threads", type=int, default=1, help="rayTestBatch numThreads")
    parser.add_argument("--server-seconds", type=float, default=20.0, help="sim seconds")
    parser.add_argument(
        "--server-units", type=int, nargs="+", default=[50, 100], help="units with the server"
    )
    parser.add_argument(
        "--skip-bare", action="store_true", help="only the runs with the server (part 2)"
    )
    parser.add_argument("--json", action="store_true", help="print a JSON object last")
    args = parser.parse_args(argv)
    warehouse = warehouse_layout()
    cases = []
    print(f"rayTestBatch numThreads={args.threads}, dt={DT} s, {args.steps} steps per case")
    print(f"{'units':>5} {'beams':>5} {'steps/s':>8} {'sim Mray/s':>10} "
          f"{'bare Mray/s (map, body)':>23} {'overhead':>8} {'x real time':>11}")  # fmt: skip
    for units in () if args.skip_bare else (10, 50, 100):
        for beams in (360, 1080):
            case = measure(warehouse, units, beams, args.steps, args.threads)
            cases.append(case)
            print(
                f"{units:5d} {beams:5d} {case['steps_per_s']:8.2f} "
                f"{case['sim_rays_per_s'] / 1e6:10.3f} "
                f"{case['bare_map_frame_rays_per_s'] / 1e6:15.3f} "
                f"{case['bare_body_frame_rays_per_s'] / 1e6:7.3f} "
                f"{case['overhead_pct']:7.1f}% {case['realtime_factor']:11.2f}"
            )
    served = []
    for units, in_flight in ((u, f) for u in args.server_units for f in (0, 2)):
        run = with_server(warehouse, args.server_seconds, args.threads, in_flight, units)
        served.append(run)
        how = "waiting for each batch" if in_flight == 0 else f"{in_flight} batches in flight"
        print(
            f"{units} units x 360 beams at 10 Hz with the map server ({how}): "
            f"{run['sim_seconds']:.1f} sim s in {run['wall_seconds']:.2f} s wall = "
            f"{run['realtime_factor']:.2f}x real time ({run['scans_posted']} scans posted, "
            f"map version {run['map_version']})"
        )
    result = {"threads": args.threads, "cases": cases, "with_server": served}
    if args.json:
        print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
