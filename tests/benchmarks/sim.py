"""Fleet simulator benchmark: the two LiDAR casters (``grid``, numba; ``bullet``,
PyBullet's ``rayTestBatch``) in the same run, sim steps, rays per second and real-time
factors, with and without the map server, and the profile of a step.

Run: ``python -m tests.benchmarks.sim [--steps N] [--threads T] [--casters grid bullet]
[--server-seconds S] [--server-units 50 100] [--scenario PATH] [--scenario-seconds S]
[--zones Z [Z ...]] [--profile-steps N] [--skip-bare] [--json]``

0. Compile time of the ``grid`` caster's numba kernels, in a fresh process with an empty
   numba cache (compiled and cached), and again with that cache (loaded).
1. The world is the default ``fleet.boxworld`` warehouse (100 m x 50 m, 107 walls, racks
   and pallets). Units stand spread along the horizontal lanes, each driving along its
   lane at up to 1.5 m/s, with a 10 Hz LiDAR (range 20 m, range noise, dropouts and
   spurious returns on, localisation noise on) and ``dt = 0.1`` s, so every unit scans at
   every step. For 10, 50 and 100 units with 360 and 1080 beams and each caster:
   ``--steps`` sim steps (``FleetSim``: motion, contacts, ray casting, flaws, scans; no
   server). Right after each step, in the same world, the same rays are cast bare: for
   ``bullet`` only the ``rayTestBatch`` calls (ray ends precomputed as lists, untimed;
   the faster of all rays in the map frame in chunks of at most 16383, and one call per
   unit in its body frame as the sim makes them); for ``grid`` one
   ``FootprintIndex.cast_fans`` call for all units. Printed: sim steps/s, sim rays/s,
   bare rays/s, the sim's overhead over bare casting [%], and the real-time factor (sim
   seconds per wall second) without a server.
2. ``hundred_units`` (100 units x 360 beams at 5 Hz on a 200 m x 80 m floor; ``--scenario``
   another, e.g. ``scenarios/thousand_units.yaml``: 1,000 units on 400 m x 200 m), for
   ``--scenario-seconds`` of sim time with each caster: the whole run (``scenarios.run``:
   sim, planners, lane coordinator, its own embedded map server), and the sim alone on
   the same floor (each unit driving back and forth 8 m along its lane, no server).
   Printed: the real-time factor of each (wall time from the first step to the last).
   ``--zones``: the whole run once for each number of map servers sharing the floor
   (``map_server.zones``: strips with borders, docs/scaling.md).
3. With the map server: ``fleetmap serve`` with its default settings (2000 x 1000 cells
   at 0.05 m, ``decay``, journal ``synchronous=FULL``) on 127.0.0.1 in a subprocess, and
   ``--server-units`` (50 and 100) units of part 1 with 360 beams posting each step's
   scans as one batch (``ScanPoster``, binary scans) for ``--server-seconds`` of sim
   time, two batches in flight (a worker thread posts while the sim runs on), with each
   caster. Printed: the real-time factor of each.
4. The profile of a step: ``--profile-steps`` steps of part 2's sim alone under
   ``cProfile`` with each caster, the functions taking most time of their own, per step.

``--json`` prints every figure as one JSON object on the last line. Tests assert
behaviour; this script only measures.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import math
import os
import pstats
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np
import pybullet as p

from fleet.boxworld import Warehouse, warehouse_layout
from fleet.casters import CASTERS
from fleet.layout import Layout
from fleet.lidar import LidarConfig
from fleet.localization import PoseNoise
from fleet.poster import ScanPoster
from fleet.sim import FleetSim, UnitSpec
from fleet.world import RAY_BATCH_MAX, World
from mapserver.client import MapClient
from mapserver.core.scan import Pose2D
from scenarios.run.runner import run as run_scenario
from scenarios.spec.scenario import Scenario, load_scenario

DT = 0.1  # [s] one step, one scan per unit at 10 Hz
SPACING_M = 4.0  # [m] between neighbouring units on a lane
HUNDRED_UNITS = Path(__file__).resolve().parents[2] / "scenarios" / "hundred_units.yaml"
SHUTTLE_M = 8.0  # [m] part 2's units drive back and forth this far along their lanes
PROFILE_TOP = 12  # functions listed per profile

COMPILE_PROBE = """
import time
t0 = time.perf_counter()
import numpy as np
from fleet.footprint_index import FootprintIndex
t1 = time.perf_counter()
index = FootprintIndex(10.0, 10.0)
index.put_unit("u", 0.3, 0.0, 0.4)
index.move_unit("u", 5.0, 5.0, 0.0)
index.cast_fans(np.array([1.0, 1.0, 0.0]), np.ones(1), np.zeros(1), 0.2, 0.3, 20.0)
print(t1 - t0, time.perf_counter() - t1)
"""


def compile_seconds() -> dict[str, float]:
    """[s] import and first cast of the grid caster in a fresh process: with an empty
    numba cache (compiles) and then with the cache it wrote (loads)."""
    out = {}
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        for label in ("cold", "cached"):
            text = subprocess.run(
                [sys.executable, "-c", COMPILE_PROBE], env=env, check=True,
                capture_output=True, text=True,
            ).stdout.split()  # fmt: skip
            out[f"{label}_import_s"], out[f"{label}_first_cast_s"] = map(float, text[-2:])
    return out


def unit_specs(warehouse: Warehouse, count: int, beams: int, caster: str) -> list[UnitSpec]:
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
            caster=caster,
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


def bare_bullet(world: World, specs: list[UnitSpec], start: float, threads: int) -> float:
    """[s] the faster of the two ways of casting every unit's rays with ``rayTestBatch``."""
    config = specs[0].lidar
    poses = [world.unit_pose(spec.unit_id) for spec in specs]
    ray_from, ray_to = world_rays(poses, config, start)
    local_from, local_to = world_rays([Pose2D(0.0, 0.0, 0.0)], config, start)
    t0 = time.perf_counter()
    for i in range(0, len(ray_from), RAY_BATCH_MAX):
        p.rayTestBatch(
            ray_from[i : i + RAY_BATCH_MAX],
            ray_to[i : i + RAY_BATCH_MAX],
            numThreads=threads,
            physicsClientId=world.client_id,
        )
    t1 = time.perf_counter()
    for spec in specs:
        p.rayTestBatch(
            local_from,
            local_to,
            numThreads=threads,
            parentObjectUniqueId=world.body_id(spec.unit_id),
            parentLinkIndex=-1,
            physicsClientId=world.client_id,
        )
    return min(t1 - t0, time.perf_counter() - t1)


def bare_grid(world: World, specs: list[UnitSpec], start: float) -> float:
    """[s] casting every unit's rays in one ``FootprintIndex.cast_fans`` call."""
    config = specs[0].lidar
    poses = np.array([[q.x, q.y, q.yaw] for q in map(world.unit_pose, (s.unit_id for s in specs))])
    angles = config.angles()
    c, s = np.cos(angles), np.sin(angles)
    t0 = time.perf_counter()
    world.footprints.cast_fans(poses, c, s, config.height, start, config.range_max)
    return time.perf_counter() - t0


def measure(
    warehouse: Warehouse, units: int, beams: int, steps: int, threads: int, caster: str
) -> dict:
    specs = unit_specs(warehouse, units, beams, caster)
    with World(Layout.from_warehouse(warehouse), ray_threads=threads) as world:
        sim = FleetSim(world, specs, seed=1)
        drive_along_lanes(sim, warehouse)
        sim.step(DT)  # warm up
        start = next(iter(sim.units.values())).lidar.start
        sim_wall = bare = 0.0
        for _ in range(steps):  # interleaved, so a change of machine load hits both
            t0 = time.perf_counter()
            sim.step(DT)
            sim_wall += time.perf_counter() - t0
            if caster == "bullet":
                bare += bare_bullet(world, specs, start, threads)
            else:
                bare += bare_grid(world, specs, start)
    rays = units * beams * steps
    return {
        "caster": caster,
        "units": units,
        "beams": beams,
        "steps_per_s": steps / sim_wall,
        "sim_rays_per_s": rays / sim_wall,
        "bare_rays_per_s": rays / bare,
        "overhead_pct": 100.0 * (sim_wall / bare - 1.0),
        "realtime_factor": steps * DT / sim_wall,
    }


# ---------------------------------------------------------------------------- the scale run
def scale_scenario(path: Path, caster: str, seconds: float, zones: int | None = None) -> Scenario:
    """The scenario at ``path`` (``hundred_units`` by default) for ``seconds`` of sim time
    with ``caster``, its floor served by ``zones`` map servers (None: as the file says)."""
    overrides: dict[str, object] = {"duration": seconds, "units.lidar.caster": caster}
    if zones is not None:
        overrides["map_server.zones"] = zones
    return load_scenario(path, overrides)


def shuttle_sim(scenario: Scenario) -> tuple[World, FleetSim]:
    """The scenario's floor and units, no server: each unit drives back and forth
    ``SHUTTLE_M`` along its lane toward the middle of the floor (they start at junctions,
    a block apart: none meet)."""
    layout = scenario.build_layout()
    world = World(layout)
    sim = FleetSim(world, scenario.unit_specs(), seed=scenario.seed)
    for unit in sim.units.values():
        x, y = unit.spec.start.x, unit.spec.start.y
        reach = SHUTTLE_M if x < layout.width / 2 else -SHUTTLE_M
        sim.unit(unit.spec.unit_id).follow([(x + reach * (k % 2 == 0), y) for k in range(99)])
    return world, sim


def scenario_alone(scenario: Scenario) -> dict:
    """Real-time factor of ``shuttle_sim`` for the scenario's duration."""
    world, sim = shuttle_sim(scenario)
    with world:
        sim.step(scenario.dt)  # warm up
        steps = round(scenario.duration / scenario.dt)
        t0 = time.perf_counter()
        for _ in range(steps):
            sim.step(scenario.dt)
        wall = time.perf_counter() - t0
    return {"sim_seconds": steps * scenario.dt, "wall_seconds": wall,
            "realtime_factor": steps * scenario.dt / wall}  # fmt: skip


def scenario_run(scenario: Scenario) -> dict:
    """Real-time factor of the whole run (its own map server), first step to last."""
    marks: list[tuple[float, float]] = []
    run_scenario(scenario, progress=lambda now, _: marks.append((now, time.perf_counter())))
    (sim0, wall0), (sim1, wall1) = marks[0], marks[-1]
    return {"sim_seconds": sim1 - sim0, "wall_seconds": wall1 - wall0,
            "realtime_factor": (sim1 - sim0) / (wall1 - wall0)}  # fmt: skip


def index_upkeep(scenario: Scenario, repeat: int = 50) -> dict:
    """[us] keeping the grid caster's index in step, on the scenario's floor after a
    step: one body's row written (``move_unit``), the units' cell lists rebuilt (each
    step's cost) and the obstacles' (each obstacle change's); medians of ``repeat``."""
    world, sim = shuttle_sim(scenario)
    with world:
        sim.step(scenario.dt)
        index = world.footprints
        pose = world.unit_pose("u1")
        out = {"obstacles": len(world.obstacles), "units": len(sim.units)}
        for name, work in (
            ("row_write_us", lambda: index.move_unit("u1", pose.x, pose.y, pose.yaw)),
            ("unit_cells_us", lambda: index.rebuild_cells(obstacles=False)),
            ("obstacle_cells_us", lambda: index.rebuild_cells(units=False)),
        ):
            times = []
            for _ in range(repeat):
                t0 = time.perf_counter()
                work()
                times.append(time.perf_counter() - t0)
            out[name] = float(np.median(times)) * 1e6
    return out


def profile_steps(scenario: Scenario, steps: int) -> dict:
    """The functions with the most time of their own over ``steps`` steps of
    ``shuttle_sim``: (name, ms per step, % of the step)."""
    world, sim = shuttle_sim(scenario)
    with world:
        for _ in range(3):
            sim.step(scenario.dt)  # warm up: every unit has scanned
        profiler = cProfile.Profile()
        t0 = time.perf_counter()
        profiler.enable()
        for _ in range(steps):
            sim.step(scenario.dt)
        profiler.disable()
        wall = time.perf_counter() - t0
    stats = pstats.Stats(profiler, stream=io.StringIO())
    total = sum(row[2] for row in stats.stats.values())
    rows = sorted(stats.stats.items(), key=lambda item: -item[1][2])[:PROFILE_TOP]
    top = [
        (f"{Path(f).name}:{line}({name})", own / steps * 1e3, 100 * own / total)
        for (f, line, name), (_, _, own, _, _) in rows
    ]
    return {"steps": steps, "ms_per_step": wall / steps * 1e3, "top": top}


# ---------------------------------------------------------------------------- the server
def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def with_server(
    warehouse: Warehouse, sim_seconds: float, threads: int, in_flight: int, units: int,
    caster: str,
) -> dict:  # fmt: skip
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
            specs = unit_specs(warehouse, units, 360, caster)
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
        "caster": caster,
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
    parser.add_argument(
        "--casters", nargs="+", choices=CASTERS, default=list(CASTERS), help="casters to run"
    )
    parser.add_argument("--server-seconds", type=float, default=20.0, help="sim seconds")
    parser.add_argument(
        "--server-units", type=int, nargs="*", default=[50, 100], help="units with the server"
    )
    parser.add_argument(
        "--scenario-seconds", type=float, default=30.0,
        help="sim seconds of --scenario per caster (0: skip)",
    )  # fmt: skip
    parser.add_argument(
        "--profile-steps", type=int, default=20, help="profiled steps per caster (0: skip)"
    )
    parser.add_argument(
        "--scenario", type=Path, default=HUNDRED_UNITS,
        help="the scale run of parts 2 and 4 (default: scenarios/hundred_units.yaml)",
    )  # fmt: skip
    parser.add_argument(
        "--zones", type=int, nargs="+", default=[None],
        help="part 2's whole run with each of these numbers of map servers (map_server.zones;"
        " default: as the scenario says)",
    )  # fmt: skip
    parser.add_argument("--skip-bare", action="store_true", help="skip part 1")
    parser.add_argument("--json", action="store_true", help="print a JSON object last")
    args = parser.parse_args(argv)
    name = args.scenario.stem
    warehouse = warehouse_layout()
    result: dict[str, object] = {"threads": args.threads, "scenario": name}
    if "grid" in args.casters:
        compiled = result["grid_compile"] = compile_seconds()
        print(
            f"grid caster, fresh process: import {compiled['cold_import_s']:.2f} s, first cast "
            f"{compiled['cold_first_cast_s']:.2f} s with an empty numba cache (compiles); "
            f"import {compiled['cached_import_s']:.2f} s, first cast "
            f"{compiled['cached_first_cast_s']:.2f} s with it cached"
        )
    cases = result["cases"] = []
    print(f"rayTestBatch numThreads={args.threads}, dt={DT} s, {args.steps} steps per case")
    print(f"{'caster':>6} {'units':>5} {'beams':>5} {'steps/s':>8} {'sim Mray/s':>10} "
          f"{'bare Mray/s':>11} {'overhead':>8} {'x real time':>11}")  # fmt: skip
    for units in () if args.skip_bare else (10, 50, 100):
        for beams in (360, 1080):
            for caster in args.casters:
                case = measure(warehouse, units, beams, args.steps, args.threads, caster)
                cases.append(case)
                print(
                    f"{caster:>6} {units:5d} {beams:5d} {case['steps_per_s']:8.2f} "
                    f"{case['sim_rays_per_s'] / 1e6:10.3f} {case['bare_rays_per_s'] / 1e6:11.3f} "
                    f"{case['overhead_pct']:7.1f}% {case['realtime_factor']:11.2f}"
                )
    if "grid" in args.casters:
        upkeep = index_upkeep(scale_scenario(args.scenario, "grid", 60.0))
        result["grid_index_upkeep"] = upkeep
        print(
            f"grid index on {name} ({upkeep['obstacles']} obstacles, {upkeep['units']} "
            f"units): a row written {upkeep['row_write_us']:.1f} us, the units' cells rebuilt "
            f"{upkeep['unit_cells_us']:.1f} us (once a step), the obstacles' "
            f"{upkeep['obstacle_cells_us']:.1f} us (once per obstacle change)"
        )
    scenario = result["scale_runs"] = []
    for caster in args.casters if args.scenario_seconds > 0 else ():
        runs = [("sim alone", scenario_alone, None)] + [
            (f"whole run{f', {z} zones' if args.zones != [None] else ''}", scenario_run, z)
            for z in args.zones
        ]
        for how, measured, zones in runs:
            setup = scale_scenario(args.scenario, caster, args.scenario_seconds, zones)
            row = {"caster": caster, "how": how, "zones": setup.map_server.zones, **measured(setup)}
            scenario.append(row)
            print(
                f"{name}, {caster}, {how}: {row['sim_seconds']:.1f} sim s in "
                f"{row['wall_seconds']:.2f} s wall = {row['realtime_factor']:.2f}x real time"
            )
    served = result["with_server"] = []
    for units in args.server_units:
        for caster in args.casters:
            run = with_server(warehouse, args.server_seconds, args.threads, 2, units, caster)
            served.append(run)
            print(
                f"{caster}: {units} units x 360 beams at 10 Hz with the map server (2 batches "
                f"in flight): {run['sim_seconds']:.1f} sim s in {run['wall_seconds']:.2f} s "
                f"wall = {run['realtime_factor']:.2f}x real time ({run['scans_posted']} scans "
                f"posted, map version {run['map_version']})"
            )
    profiles = result["profiles"] = {}
    for caster in args.casters if args.profile_steps > 0 else ():
        prof = profiles[caster] = profile_steps(
            scale_scenario(args.scenario, caster, 60.0), args.profile_steps
        )
        print(f"profile, {name} sim alone, {caster}: {prof['ms_per_step']:.1f} ms a step "
              f"under cProfile; own time per step:")  # fmt: skip
        for function, ms, pct in prof["top"]:
            print(f"  {ms:8.2f} ms {pct:5.1f}%  {function}")
    if args.json:
        print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
