"""Recordings benchmark: reading scans from a ROS 2 bag (MCAP), a ROS 1 bag and a CARMEN
log, reading and fusing them, and OctoMap inserting the same scans in the same run.

Run: ``python -m tests.benchmarks.recordings [--scans N] [--log PATH] [--json]``

The bags are written first (``tests/recording_helpers``: a 360-beam laser 10 Hz in an
8 m x 6 m room, /tf odom -> base_link at 20 Hz, map -> odom at 2 Hz, /tf_static mount).
``--log`` is a CARMEN log (default: the Intel Research Lab log in ``../shared/realdata``
when it exists, else a synthetic 181-beam FLASER log of ``--scans`` lines). For each:

- read: scans/s of iterating the recording (parse, poses, ``Scan`` validation);
- read + fuse: scans/s of ``fuse_all`` streaming the recording into a grid sized from
  the data (0.05 m, decay policy), the kernel loaded beforehand;
- fuse only: fleetmap's fusion of the scans in memory;
- OctoMap: pyoctomap (``pip install -e .[bench]``) inserting the same scans, as
  ``tests/benchmarks/fusion.py`` does, when installed.

Tests assert behaviour; this script only measures.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from mapserver.core.belief import BeliefGrid
from mapserver.core.scan import Scan
from mapserver.store.offline import fuse_all
from mapserver.store.recordings import Recording, open_recording
from mapserver.store.recordings.grid_fit import fit_grid
from tests.recording_helpers import BagSpec, Motion, carmen_lines, write_bag, write_carmen

INTEL = Path(__file__).resolve().parents[3] / "shared" / "realdata" / "intel-corrected.log.gz"
RESOLUTION = 0.05  # [m] fleetmap's grid and OctoMap's voxels
SLOW = Motion(velocity=(0.05, 0.02, 0.3))  # stays in the room for minutes


def octomap_rate(scans: list[Scan]) -> float | None:
    """OctoMap's scans/s inserting ``scans`` at fleetmap's resolution (None when
    pyoctomap is not installed)."""
    try:
        from tests.benchmarks.fusion import insert, octree, point_cloud
    except ImportError:
        return None
    from mapserver.core.sensor_model import SensorModel

    clearing = BeliefGrid(fit_grid(scans[:1], RESOLUTION)).no_return_clearing  # fleetmap's
    clouds = [point_cloud(scan, clearing(scan.range_max)) for scan in scans]
    return insert(octree(SensorModel(), RESOLUTION), scans, clouds).scans_per_s


def measure(name: str, recording: Recording) -> dict:
    start = time.perf_counter()
    scans = list(recording)
    read_s = time.perf_counter() - start
    geometry = fit_grid(scans, RESOLUTION)
    fuse_all(BeliefGrid(geometry), scans[:1])  # load the kernels
    start = time.perf_counter()
    streamed = fuse_all(BeliefGrid(geometry), recording)
    read_fuse_s = time.perf_counter() - start
    fused = fuse_all(BeliefGrid(geometry), scans)
    return {
        "recording": name,
        "scans": len(scans),
        "beams": scans[0].beam_count,
        "read_scans_per_s": len(scans) / read_s,
        "read_fuse_scans_per_s": streamed.scans / read_fuse_s,
        "fuse_scans_per_s": fused.scans_per_s,
        "octomap_scans_per_s": octomap_rate(scans),
    }


def run(scan_count: int, log: Path | None) -> list[dict]:
    results = []
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder)
        for storage, name in (("mcap", "bag-mcap"), ("ros1", "bag.bag")):
            spec = BagSpec(storage=storage, scans=scan_count, motion=SLOW)
            path = write_bag(root / name, spec)
            results.append(
                measure(f"ROS {'1' if storage == 'ros1' else '2 MCAP'} bag", open_recording(path))
            )
        if log is None:
            log = write_carmen(root / "synthetic.log", carmen_lines("FLASER", scan_count, SLOW))
        results.append(measure(f"CARMEN log {log.name}", open_recording(log)))
    return results


def report(results: list[dict]) -> None:
    for r in results:
        peer = r["octomap_scans_per_s"]
        octomap = "not installed" if peer is None else f"{peer:,.0f} scans/s"
        print(
            f"{r['recording']}: {r['scans']} scans x {r['beams']} beams: read "
            f"{r['read_scans_per_s']:,.0f} scans/s, read + fuse {r['read_fuse_scans_per_s']:,.0f}"
            f" scans/s, fuse only {r['fuse_scans_per_s']:,.0f} scans/s; OctoMap {octomap}"
        )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=1000, help="scans per synthetic recording")
    parser.add_argument("--log", type=Path, help="a CARMEN log (default: the Intel log)")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    args = parser.parse_args(argv)
    log = args.log or (INTEL if INTEL.exists() else None)
    results = run(args.scans, log)
    print(json.dumps(results, indent=1)) if args.json else report(results)


if __name__ == "__main__":
    main()
