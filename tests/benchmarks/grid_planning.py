"""Grid planning benchmark: A* and Dijkstra corner to corner on a 2000 x 2000 costmap.

Run: ``python -m tests.benchmarks.grid_planning [--json]``

The costmap is the inflation benchmark's warehouse (``tests/benchmarks/inflation.py``:
walls, rack rows, totes; 0.05 m cells) inflated with the Nav2 defaults. Printed: A* and
Dijkstra from (2.5, 2.5) to (97.5, 97.5) m (time [ms], nodes expanded, path length [m]);
and, in the same run, networkx ``astar_path`` on a 300 x 300 crop of the same costmap
(the same weights and octile heuristic) against ``GridPlanner`` on that crop, with the
speed ratio. A third line plans with ``GridPlanner(landmarks=6)``: the first plan
(cold: it builds the landmark tables, one Dijkstra each) and the best of three more
(warm: the same costmap), corner to corner and along the other diagonal.

The peer: libtcod's C pathfinder (``tcod.path.Pathfinder`` over a ``CustomGraph``, A*
with its octile heuristic at the free-cell cost, the ``bench`` extra) on the same
2000 x 2000 costmap, corner to corner, and the speed ratio. Its costs are integers: a
cell of cost c weighs 250 + 4 c (NavFn's 50 + 0.8 c, times 5), a straight step 408 and
a diagonal one 577 (577 / 408 = sqrt(2) + 3.6e-6), so its path cost, converted to metres,
is the planner's model up to that rounding of sqrt(2); impassable cells cost 0
(blocked), and each diagonal edge carries a condition array that holds it where both
cells beside it are passable, our corner rule. Both path costs are printed. Planning
only is timed: tcod's graph and Pathfinder are built before the clock starts, since
``GridPlanner`` keeps its buffers between plans too. ``--json`` prints the figures as
one JSON object last. Measures only.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import networkx as nx
import numpy as np

from mapserver.core.costvalues import LETHAL
from mapserver.core.geometry import GridGeometry
from mapserver.core.inflation import InflationParams, Inflator
from planner.grid_reference import networkx_grid
from planner.grid_search import GridPlanner, cell_weights
from tests.benchmarks.inflation import warehouse

RES = 0.05
LANDMARKS = 6  # ALT landmarks of the third line (planner/landmarks.py)


def costmap() -> np.ndarray:
    lethal = warehouse(seed=0)
    costs = Inflator(InflationParams(), RES).inflate(lethal)
    costs[lethal] = LETHAL
    return costs


def octile(a: tuple[int, int], b: tuple[int, int]) -> float:
    dr, dc = abs(a[0] - b[0]), abs(a[1] - b[1])
    return RES * (max(dr, dc) - min(dr, dc) + math.sqrt(2) * min(dr, dc))


def free_cell_near(costs: np.ndarray, k: int) -> tuple[int, int]:
    """The free cell (row, col) nearest to (k, k) along the diagonal."""
    for d in range(costs.shape[0]):
        for r, c in ((k + d, k + d), (k - d, k - d)):
            if 0 <= r < costs.shape[0] and 0 <= c < costs.shape[1] and costs[r, c] == 0:
                return r, c
    raise ValueError("no free cell on the diagonal")


TCOD_STRAIGHT, TCOD_DIAGONAL = 408, 577  # 577 / 408 ~ sqrt(2)


def tcod_planner(costs: np.ndarray, start: tuple[int, int], goal: tuple[int, int]):
    """A function planning start -> goal (row, col) with libtcod: (path cost [m], cells)."""
    import tcod.path

    passable = np.isfinite(cell_weights(True)[costs])
    cell_cost = np.where(passable, 250 + 4 * costs.astype(np.int32), 0).astype(np.int32)
    graph = tcod.path.CustomGraph(costs.shape)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if (dr, dc) == (0, 0):
                continue
            if dr and dc:  # held only where neither orthogonal cell is impassable
                beside = np.zeros_like(passable)
                rows = slice(max(0, -dr), costs.shape[0] - max(0, dr))
                cols = slice(max(0, -dc), costs.shape[1] - max(0, dc))
                beside[rows, cols] = (
                    np.roll(passable, -dr, 0)[rows, cols] & np.roll(passable, -dc, 1)[rows, cols]
                )
                graph.add_edge((dr, dc), TCOD_DIAGONAL, cost=cell_cost, condition=beside)
            else:
                graph.add_edge((dr, dc), TCOD_STRAIGHT, cost=cell_cost)
    graph.set_heuristic(cardinal=250 * TCOD_STRAIGHT, diagonal=250 * TCOD_DIAGONAL)

    def plan() -> tuple[float, np.ndarray]:
        finder = tcod.path.Pathfinder(graph)
        finder.add_root(start)
        path = finder.path_to(goal)
        cost = finder.distance[goal] * RES / (250 * TCOD_STRAIGHT)
        return float(cost), path

    return plan


def best_of(runs: int, fn) -> tuple[float, object]:
    best, result = math.inf, None
    for _ in range(runs):
        t0 = time.perf_counter()
        result = fn()
        best = min(best, (time.perf_counter() - t0) * 1e3)
    return best, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    costs = costmap()
    planner = GridPlanner(GridGeometry(2000, 2000, RES))
    planner.plan(costs, (2.5, 2.5), (3.0, 3.0))  # JIT and first-touch of the buffers
    figures: dict[str, float] = {}
    for algorithm in ("astar", "dijkstra"):
        ms, result = best_of(
            3, lambda a=algorithm: planner.plan(costs, (2.5, 2.5), (97.5, 97.5), a)
        )
        figures[f"{algorithm}_ms"] = ms
        figures[f"{algorithm}_expanded"] = result.expanded
        print(f"{algorithm:8s} 2000 x 2000 corner to corner: {ms:7.1f} ms, "
              f"{result.expanded} expanded, path {result.length:.1f} m")  # fmt: skip
    alt = GridPlanner(GridGeometry(2000, 2000, RES), landmarks=LANDMARKS)
    cold = alt.plan(costs, (2.5, 2.5), (97.5, 97.5))  # builds the landmark tables
    ms, result = best_of(3, lambda: alt.plan(costs, (2.5, 2.5), (97.5, 97.5)))
    other_ms, other = best_of(3, lambda: alt.plan(costs, (2.5, 97.5), (97.5, 2.5)))
    figures.update(alt_cold_ms=cold.planning_ms, alt_ms=ms, alt_expanded=result.expanded,
                   alt_other_diagonal_ms=other_ms)  # fmt: skip
    print(f"A* + {LANDMARKS} landmarks corner to corner: cold {cold.planning_ms:.1f} ms "
          f"(tables built), warm {ms:.1f} ms, {result.expanded} expanded, cost "
          f"{result.cost:.3f} m; other diagonal warm {other_ms:.1f} ms, {other.expanded} "
          f"expanded, cost {other.cost:.3f} m")  # fmt: skip
    corner_a = (int(2.5 / RES), int(2.5 / RES))
    corner_b = (int(97.5 / RES), int(97.5 / RES))
    tcod_plan = tcod_planner(costs, corner_a, corner_b)
    tcod_ms, (tcod_cost, _) = best_of(3, tcod_plan)
    ours_full = planner.plan(costs, (2.5, 2.5), (97.5, 97.5))
    figures.update(tcod_ms=tcod_ms, tcod_ratio=tcod_ms / figures["astar_ms"])
    print(f"tcod Pathfinder A* 2000 x 2000 corner to corner: {tcod_ms:.1f} ms (cost "
          f"{tcod_cost:.3f} m, ours {ours_full.cost:.3f} m): GridPlanner A* "
          f"{tcod_ms / figures['astar_ms']:.1f}x faster, with landmarks (warm) "
          f"{tcod_ms / figures['alt_ms']:.1f}x")  # fmt: skip
    crop = np.ascontiguousarray(costs[40:340, 40:340])
    small = GridPlanner(GridGeometry(300, 300, RES))
    s_cell, g_cell = free_cell_near(crop, 10), free_cell_near(crop, 290)
    start = ((s_cell[1] + 0.5) * RES, (s_cell[0] + 0.5) * RES)
    goal = ((g_cell[1] + 0.5) * RES, (g_cell[0] + 0.5) * RES)
    ours_ms, ours = best_of(5, lambda: small.plan(crop, start, goal))
    graph = networkx_grid(crop, RES)
    nx_ms, nx_path = best_of(1, lambda: nx.astar_path(graph, s_cell, g_cell, octile, "weight"))
    nx_cost = nx.path_weight(graph, nx_path, "weight")
    figures.update(crop_ms=ours_ms, networkx_crop_ms=nx_ms, speed_ratio=nx_ms / ours_ms)
    print(f"300 x 300 crop: GridPlanner {ours_ms:.2f} ms (cost {ours.cost:.3f}), networkx "
          f"astar_path {nx_ms:.0f} ms (cost {nx_cost:.3f}): {nx_ms / ours_ms:.0f}x")  # fmt: skip
    if args.json:
        print(json.dumps(figures))


if __name__ == "__main__":
    main()
