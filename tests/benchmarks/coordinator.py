"""Lane coordinator benchmark: tick time for a fleet on a warehouse lane graph.

Run: ``python tests/benchmarks/coordinator.py [--units 100] [--ticks 3000] [--two-way]
[--json]``

The lane graph is ``LaneGraph.from_warehouse(warehouse_layout(width, height),
segment_m=...)``: junctions at every aisle crossing, long aisles split into waypoints
about ``segment_m`` apart so units can follow one another. By default every aisle is
one-way (``aisle_directions``: a counter-clockwise perimeter ring, inner rows and
columns alternating), the usual traffic plan of a robot floor; ``--two-way`` drops it,
and with random goals at this density two-way aisles jam (head-on convoys that local
deadlock breaking cannot untangle: see the printed waiting count). ``--units`` units start at
distinct random nodes; whenever one is idle it waits ``--dwell`` seconds and gets a new
random goal (a node nobody stands on or is heading to). Units drive at ``--speed``
[m/s] toward their status target, kinematically, and report positions every ``--dt``
seconds of simulated time. Every ``--block-every`` seconds one random lane is blocked
(and the previous one cleared) through a fake segment-query client and ``refresh``, so
units turn back and reroute.

Printed [ms]: ``tick`` (``LaneCoordinator.tick``: progress, grants, waits, deadlock
detection and breaking, for the whole fleet) median, p99 and max; ``request`` (a new
task: routing) median and p99; ``refresh`` (segment query + blocked-lane reroutes) median.
Also tasks completed, deadlocks broken, and units waiting at the end. ``--json`` prints
the figures as one JSON object on the last line. Measures only; tests assert behaviour.
The max tick includes Python's cyclic garbage collector (gen-2 passes of tens of ms);
the median and p99 do not feel it.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import networkx as nx
import numpy as np

from fleet.boxworld import warehouse_layout
from mapserver.client import SegmentOut
from mapserver.core.costvalues import LETHAL
from planner.coordinator import LaneCoordinator
from planner.decisions import Action, Cause
from planner.lane_graph import Lane, LaneGraph


class BlockedLanes:
    """A stand-in map client: the lanes in ``blocked`` read as blocked in their middle."""

    def __init__(self, graph: LaneGraph) -> None:
        self.blocked: set[Lane] = set()
        self._lane_of = {}
        for a, b in graph.lanes:
            pa, pb = graph.position(a), graph.position(b)
            self._lane_of[(*pa, *pb)] = self._lane_of[(*pb, *pa)] = (a, b)

    def query_segments(self, segments: list) -> list[SegmentOut]:
        out = []
        for x0, y0, x1, y1 in segments:
            if self._lane_of[(x0, y0, x1, y1)] in self.blocked:
                mid = ((x0 + x1) / 2, (y0 + y1) / 2)
                out.append(
                    SegmentOut(
                        max_cost=int(LETHAL), blocked=True, unknown_fraction=0.0, first_blocked=mid
                    )
                )
            else:
                out.append(
                    SegmentOut(max_cost=0, blocked=False, unknown_fraction=0.0, first_blocked=None)
                )
        return out


def aisle_directions(lane_x: tuple[float, ...], lane_y: tuple[float, ...]) -> list[tuple[str, str]]:
    """Every stretch one-way, a Manhattan traffic plan: the perimeter aisles a
    counter-clockwise ring, inner rows alternating east and west, inner columns north
    and south."""
    nx_, ny_ = len(lane_x), len(lane_y)
    pairs = []
    for iy in range(ny_):
        east = iy == 0 or (iy % 2 == 1 and iy != ny_ - 1)
        for ix in range(nx_ - 1):
            a, b = f"j{ix}_{iy}", f"j{ix + 1}_{iy}"
            pairs.append((a, b) if east else (b, a))
    for ix in range(nx_):
        north = ix == nx_ - 1 or (ix % 2 == 1 and ix != 0)
        for iy in range(ny_ - 1):
            a, b = f"j{ix}_{iy}", f"j{ix}_{iy + 1}"
            pairs.append((a, b) if north else (b, a))
    return pairs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=100)
    parser.add_argument("--ticks", type=int, default=3000, help="ticks timed (default 3000)")
    parser.add_argument("--width", type=float, default=200.0, help="warehouse width [m]")
    parser.add_argument("--height", type=float, default=100.0, help="warehouse depth [m]")
    parser.add_argument("--segment", type=float, default=5.0, help="segment_m [m]")
    parser.add_argument("--dt", type=float, default=0.2, help="tick period [s]")
    parser.add_argument("--speed", type=float, default=1.5, help="unit speed [m/s]")
    parser.add_argument("--dwell", type=float, default=2.0, help="idle time before a task [s]")
    parser.add_argument("--block-every", type=float, default=20.0, help="[s], 0: never")
    parser.add_argument(
        "--two-way", action="store_true", help="every aisle two-way (default: all one-way)"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print figures as JSON last")
    args = parser.parse_args()

    rng = np.random.default_rng(args.seed)
    warehouse = warehouse_layout(args.width, args.height, seed=args.seed)
    one_way = [] if args.two_way else aisle_directions(warehouse.lane_x, warehouse.lane_y)
    graph = LaneGraph.from_warehouse(warehouse, one_way=one_way, segment_m=args.segment)
    if not nx.is_strongly_connected(graph.graph):
        raise SystemExit("the lane graph is not strongly connected: some tasks have no route")
    client = BlockedLanes(graph)
    coord = LaneCoordinator(graph, client, speed=args.speed, clear_m=1.0, arrive_tol=0.1)
    nodes = list(graph.nodes)
    if args.units >= len(nodes):
        raise SystemExit(f"--units {args.units} needs fewer units than the {len(nodes)} nodes")
    now = 0.0
    positions: dict[str, tuple[float, float]] = {}
    idle_since: dict[str, float] = {}
    request_ms: list[float] = []

    def give_task(uid: str, start: str) -> bool:
        """A random free goal for ``uid``; False if every node is taken or targeted."""
        busy = {coord.status(u).goal for u in coord.unit_ids}
        free = [n for n in nodes if coord.holder(n) is None and n not in busy]
        if not free:
            return False
        goal = free[int(rng.integers(len(free)))]
        t0 = time.perf_counter()
        coord.request(uid, start, goal, int(rng.integers(3)), now)
        request_ms.append((time.perf_counter() - t0) * 1e3)
        return True

    for k, start in enumerate(rng.choice(nodes, size=args.units, replace=False).tolist()):
        uid = f"u{k + 1}"
        positions[uid] = graph.position(start)
        coord.request(uid, start, start, 0, now)  # appear, parked
        idle_since[uid] = -args.dwell

    tick_ms: list[float] = []
    refresh_ms: list[float] = []
    tasks = 0
    next_block = args.block_every if args.block_every > 0 else math.inf
    warmup = 50
    for step in range(warmup + args.ticks):
        now = round(now + args.dt, 9)
        for uid in coord.unit_ids:
            status = coord.status(uid)
            if status.state == "idle":
                idle_since.setdefault(uid, now)
                if now - idle_since[uid] >= args.dwell and give_task(uid, status.node):
                    del idle_since[uid]
                continue
            if status.target is None:
                continue
            (x, y), (tx, ty) = positions[uid], graph.position(status.target)
            gap = math.hypot(tx - x, ty - y)
            move = min(gap, args.speed * args.dt)
            if gap > 0:
                positions[uid] = (x + (tx - x) * move / gap, y + (ty - y) * move / gap)
        if now >= next_block:
            next_block += args.block_every
            client.blocked = {graph.lanes[int(rng.integers(len(graph.lanes)))]}
            t0 = time.perf_counter()
            coord.refresh(now)
            refresh_ms.append((time.perf_counter() - t0) * 1e3)
        t0 = time.perf_counter()
        decisions = coord.tick(now, positions)
        elapsed = (time.perf_counter() - t0) * 1e3
        if step >= warmup:
            tick_ms.append(elapsed)
            tasks += sum(d.action is Action.ARRIVED and d.cause is Cause.GOAL for d in decisions)

    waiting = [u for u in coord.unit_ids if coord.status(u).state in ("waiting", "stranded")]
    figures = {
        "units": args.units,
        "aisles": "two-way" if args.two_way else "one-way",
        "nodes": len(graph.nodes),
        "lanes": len(graph.lanes),
        "ticks_timed": len(tick_ms),
        "sim_seconds": round(now, 3),
        "tick_ms_median": float(np.median(tick_ms)),
        "tick_ms_p99": float(np.percentile(tick_ms, 99)),
        "tick_ms_max": float(np.max(tick_ms)),
        "request_ms_median": float(np.median(request_ms)) if request_ms else None,
        "request_ms_p99": float(np.percentile(request_ms, 99)) if request_ms else None,
        "refresh_ms_median": float(np.median(refresh_ms)) if refresh_ms else None,
        "tasks_completed": tasks,
        "deadlocks": coord.deadlocks,
        "decisions": len(coord.log),
        "waiting_at_end": len(waiting),
    }
    print(
        f"lane coordinator: {args.units} units on {len(graph.nodes)} nodes / "
        f"{len(graph.lanes)} lanes ({args.width:g} m x {args.height:g} m, "
        f"segment {args.segment} m, {'two-way' if args.two_way else 'one-way'} aisles)"
    )
    print(f"  tick    median {figures['tick_ms_median']:.3f} ms, p99 {figures['tick_ms_p99']:.3f} "
          f"ms, max {figures['tick_ms_max']:.3f} ms over {len(tick_ms)} ticks")  # fmt: skip
    if request_ms:
        print(f"  request median {figures['request_ms_median']:.3f} ms, "
              f"p99 {figures['request_ms_p99']:.3f} ms ({len(request_ms)} tasks)")  # fmt: skip
    if refresh_ms:
        print(
            f"  refresh median {figures['refresh_ms_median']:.3f} ms ({len(refresh_ms)} refreshes)"
        )
    print(f"  {tasks} tasks completed in {now:.0f} s simulated, {coord.deadlocks} deadlocks "
          f"broken, {len(waiting)} units waiting at the end")  # fmt: skip
    if args.json:
        print(json.dumps(figures))


if __name__ == "__main__":
    main()
