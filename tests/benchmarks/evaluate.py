"""Evaluate benchmark: ``fleetmap evaluate``'s pass over a real recording, timed, with
fleetmap's fusion speed beside OctoMap's on the same scans in the same run.

Run: ``python -m tests.benchmarks.evaluate [RECORDING] [--resolution R] [--read-every S]
[--no-octomap]``

RECORDING defaults to the Intel Research Lab log, ``../shared/realdata/
intel-corrected.log.gz`` from the repository's root (its README there gives source and
terms); any recording ``open_recording`` reads will do. The grid is sized from the data
(a first pass, timed apart). Then one pass fuses every scan under ``decay``, ``binary``
and ``sticky`` and into OctoMap (``pyoctomap``, the ``bench`` extra; its classic update,
``scenarios/evaluate/octomap_peer.py``) in lockstep, each fusion timed alone, and measures
each map (docs/evaluate.md).

Printed: the verdict table, the first pass's and the evaluation pass's wall time, and
fusion speed [scans/s] per map with fleetmap's over OctoMap's. Measures only; tests
assert behaviour.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from mapserver.core.sensor_model import DecayParams, Policy, SensorModel
from mapserver.store.recordings import RecordingError, open_recording
from mapserver.store.recordings.grid_fit import fit_grid
from scenarios.evaluate.maps import FleetmapMap, MapUnderTest
from scenarios.evaluate.octomap_peer import PEER_NAME, OctoMapPeer
from scenarios.evaluate.report import markdown_table, summary
from scenarios.evaluate.run import evaluate

ROOT = Path(__file__).resolve().parents[2]
INTEL = ROOT.parent / "shared" / "realdata" / "intel-corrected.log.gz"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recording", type=Path, nargs="?", default=INTEL)
    parser.add_argument("--resolution", type=float, default=0.05, help="[m/cell]")
    parser.add_argument("--read-every", type=float, default=1.0, help="[s] between ghost reads")
    parser.add_argument("--no-octomap", action="store_true", help="fleetmap's policies only")
    args = parser.parse_args(argv)
    try:
        recording = open_recording(args.recording)
        start = time.perf_counter()
        geometry = fit_grid(recording, args.resolution)
    except RecordingError as exc:
        print(f"evaluate benchmark: {exc}", file=sys.stderr)
        return 2
    fit_s = time.perf_counter() - start
    model, decay = SensorModel(), DecayParams()
    maps: list[MapUnderTest] = [FleetmapMap(geometry, model, p, decay) for p in Policy]
    if not args.no_octomap:
        maps.append(OctoMapPeer(geometry, model))
    start = time.perf_counter()
    evaluation = evaluate(recording, geometry, maps, read_every=args.read_every)
    pass_s = time.perf_counter() - start
    print(summary(evaluation, str(args.recording)))
    print()
    print(markdown_table(evaluation.verdicts))
    print(f"wall time: grid sized in {fit_s:.1f} s (first pass), evaluated in {pass_s:.1f} s")
    speeds = {v.name: v.scans_per_s for v in evaluation.verdicts}
    line = ", ".join(f"{name} {speed:,.0f}" for name, speed in speeds.items())
    print(f"fusion [scans/s, fusion alone]: {line}")
    if PEER_NAME in speeds:
        ratios = ", ".join(f"{p.value} {speeds[p.value] / speeds[PEER_NAME]:.1f}x" for p in Policy)
        print(f"fleetmap over OctoMap on the same scans: {ratios}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
