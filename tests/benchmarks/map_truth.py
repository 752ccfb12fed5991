"""Map-against-truth benchmark: one map read's comparison on ``hundred_units``' floor, the
tolerance grown with shifted ORs (``scenarios.score.map_truth``) against scipy's
``binary_dilation`` (how it was grown before).

Run: ``python tests/benchmarks/map_truth.py [--scenario YAML] [--repeats N] [--json]``

The truth is the scenario's world (PyBullet) rasterised and inflated on its map grid
(``fleet.ground_truth.GroundTruth``, 2,000 x 800 cells for ``hundred_units``); the
"shared" costmap is the truth with a few hundred cells flipped (seeded), so phantom and
forgotten cells exist. Printed, each the best of ``--repeats`` [ms]: growing the truth's
blocked cells by the one-cell tolerance both ways (checked identical), and a whole
``measure`` (both masks grown, the three numbers) with each; the ratios. The map-truth
observer runs one ``measure`` per map read (every 0.5 s of sim time by default), on the
runner's thread. Tests assert behaviour; this script only measures.
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
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from unittest import mock  # noqa: E402

import numpy as np  # noqa: E402
from scipy import ndimage  # noqa: E402

from fleet.ground_truth import GroundTruth  # noqa: E402
from fleet.world import World  # noqa: E402
from mapserver.core.costvalues import INSCRIBED, LETHAL  # noqa: E402
from scenarios.score import map_truth  # noqa: E402
from scenarios.spec.scenario import load_scenario  # noqa: E402

ROOT = HERE.parents[1]
FLIPPED = 500  # cells of the truth flipped to make the "shared" map


def scipy_near(mask: np.ndarray, cells: int) -> np.ndarray:
    """The tolerance as it was grown before: a square binary dilation."""
    if cells <= 0:
        return mask
    return ndimage.binary_dilation(mask, structure=np.ones((2 * cells + 1,) * 2, dtype=bool))


def best_ms(fn: Callable[[], object], repeats: int) -> float:
    """[ms] the fastest of ``repeats`` calls."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default=str(ROOT / "scenarios" / "hundred_units.yaml"))
    parser.add_argument("--repeats", type=int, default=10, help="best of N (default 10)")
    parser.add_argument("--json", action="store_true", help="the figures as one JSON line")
    args = parser.parse_args()

    scenario = load_scenario(args.scenario)
    geometry = scenario.geometry()
    with World(scenario.build_layout()) as world:
        truth = GroundTruth(world, geometry, scenario.inflation()).costmap()
    rng = np.random.default_rng(0)
    shared = truth.copy()
    rows = rng.integers(0, truth.shape[0], FLIPPED)
    cols = rng.integers(0, truth.shape[1], FLIPPED)
    shared[rows, cols] = np.where(shared[rows, cols] >= INSCRIBED, 0, LETHAL)
    reachable = np.ones(truth.shape, dtype=bool)
    blocked = truth >= INSCRIBED
    assert np.array_equal(map_truth._near(blocked, 1), scipy_near(blocked, 1))

    grow_ours = best_ms(lambda: map_truth._near(blocked, 1), args.repeats)
    grow_scipy = best_ms(lambda: scipy_near(blocked, 1), args.repeats)
    read_ours = best_ms(lambda: map_truth.measure(0.0, shared, truth, reachable), args.repeats)
    with mock.patch.object(map_truth, "_near", scipy_near):
        before = map_truth.measure(0.0, shared, truth, reachable)
        read_scipy = best_ms(lambda: map_truth.measure(0.0, shared, truth, reachable), args.repeats)
    assert before == map_truth.measure(0.0, shared, truth, reachable)
    figures = {
        "grid": list(truth.shape),
        "grow_ms": round(grow_ours, 2),
        "grow_scipy_ms": round(grow_scipy, 2),
        "grow_speedup": round(grow_scipy / grow_ours, 1),
        "measure_ms": round(read_ours, 2),
        "measure_scipy_ms": round(read_scipy, 2),
        "measure_speedup": round(read_scipy / read_ours, 1),
    }
    print(f"grid {truth.shape[1]} x {truth.shape[0]} cells, best of {args.repeats}")
    print(
        f"grow by the tolerance: {grow_ours:.2f} ms, scipy binary_dilation "
        f"{grow_scipy:.2f} ms ({figures['grow_speedup']}x)"
    )
    print(
        f"measure (one map read): {read_ours:.2f} ms, with scipy {read_scipy:.2f} ms "
        f"({figures['measure_speedup']}x)"
    )
    if args.json:
        print(json.dumps(figures))


if __name__ == "__main__":
    main()
