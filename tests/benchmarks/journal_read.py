"""Journal read benchmark: how fast the journal's scans come back as ``Scan`` objects, as
the server's start-up replay and a run's ``replay.mcap`` read them.

Run: ``python -m tests.benchmarks.journal_read [--scans 20000] [--beams 360 1080]``

For each beam count, writes a journal of ``--scans`` scans (warehouse-like ranges 0.3-20 m
rounded to float32, 50 units, groups of 50 a transaction, ``synchronous=OFF``: the
writing is not measured) in a temporary folder, then reads it back twice in the same run:

- ``read_records``: what the server's replay reads (each record's ``fields``, ranges as
  the decoded array, validated by ``Scan.from_dict``);
- peer, the JSON object: each record's docs/http-api.md 2.1 object (``Record.scan``,
  ranges as a list with null for NaN) validated by ``Scan.from_dict``, as every read did
  before ``fields``.

Printed: records/s and microseconds a record for each, and their ratio. Measures only;
tests assert behaviour.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from mapserver.core.scan import Scan
from mapserver.store.journal import Journal
from mapserver.store.journal_reading import read_records

UNITS = 50  # scans of one group, one per unit


def write_journal(path: Path, scans: int, beams: int, seed: int = 0) -> None:
    """``scans`` scans of ``beams`` beams in groups of ``UNITS`` (one per unit)."""
    rng = np.random.default_rng(seed)
    angle_increment = 2 * math.pi / beams
    with Journal(path, synchronous="OFF") as journal:
        for group in range(math.ceil(scans / UNITS)):
            records = []
            for unit in range(min(UNITS, scans - group * UNITS)):
                ranges = np.clip(rng.normal(5.0, 3.0, beams), 0.3, 20.0).astype(np.float32)
                scan = Scan.from_dict({
                    "unit_id": f"u{unit}", "stamp": 1.0 + 0.1 * group, "frame": "map",
                    "pose": {"x": 10.0 + unit, "y": 20.0, "yaw": 0.1},
                    "angle_min": -math.pi, "angle_increment": angle_increment,
                    "range_min": 0.05, "range_max": 20.0, "ranges": ranges,
                })  # fmt: skip
                records.append(scan.journal_record())
            journal.append(records)


def time_reads(path: Path) -> dict[str, float]:
    """Seconds to read every scan of the journal at ``path`` each way, and the count."""
    with Journal(path) as journal:
        start = time.perf_counter()
        count = sum(1 for record in read_records(journal) if record.scan is not None)
        fields_s = time.perf_counter() - start
        start = time.perf_counter()
        for record in journal.records_after(0):
            Scan.from_dict(record.scan)
        json_object_s = time.perf_counter() - start
    return {"scans": count, "read_records_s": fields_s, "json_object_s": json_object_s}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=20_000, help="scans in the journal")
    parser.add_argument("--beams", type=int, nargs="+", default=[360, 1080], help="beams a scan")
    args = parser.parse_args()
    for beams in args.beams:
        with tempfile.TemporaryDirectory(prefix="journal-read-") as tmp:
            path = Path(tmp) / "journal.sqlite3"
            write_journal(path, args.scans, beams)
            t = time_reads(path)
        n = t["scans"]
        fields, peer = t["read_records_s"], t["json_object_s"]
        print(
            f"{n} scans x {beams} beams: read_records {n / fields:,.0f} scans/s "
            f"({fields / n * 1e6:.1f} us a scan); peer, the JSON object {n / peer:,.0f} "
            f"scans/s ({peer / n * 1e6:.1f} us): {peer / fields:.2f}x"
        )


if __name__ == "__main__":
    main()
