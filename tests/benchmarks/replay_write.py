"""Replay writing benchmark: a run's fused scans into ``replay.mcap``'s ``/fleetmap/scans``
channel, their messages made in process against in a child process
(``scenarios.replay.fused_worker``) while the writer packs and compresses.

Run: ``python -m tests.benchmarks.replay_write [--scans 60000] [--beams 360] [--rounds 2]``

Writes a journal of ``--scans`` scans (``tests.benchmarks.journal_read.write_journal``:
warehouse-like ranges, 50 units) in a temporary folder, then, ``--rounds`` times, each
way in turn: reads it back as the replay's messages and writes them to an MCAP file
(JSON messages, zstd chunks: as ``write_replay`` does), once with the messages made in
process (the peer, as every replay was written before the child) and once in the child.
The two files must be the same bytes. Printed: seconds and scans/s of each way, and
their ratio; and the messages alone, without the writer. Measures only; tests assert
behaviour.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import Writer

from scenarios.replay.fused import FUSED_SCHEMA_NAME, FUSED_TOPIC, FusedScans
from scenarios.replay.fused_worker import fused_items
from tests.benchmarks.journal_read import write_journal

IN_PROCESS = 1 << 62  # a ``worker_from`` no journal reaches
IN_CHILD = 0


def write_fused(fused: FusedScans, out: Path, worker_from: int) -> tuple[float, int]:
    """Seconds to write the fused channel of ``fused`` to ``out``, and its messages."""
    start = time.perf_counter()
    count = 0
    with open(out, "wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="fleetmap-benchmark")
        schema = writer.register_schema(FUSED_SCHEMA_NAME, SchemaEncoding.JSONSchema, b"{}")
        channel = writer.register_channel(FUSED_TOPIC, MessageEncoding.JSON, schema)
        for ns, message in fused_items(fused, worker_from=worker_from):
            writer.add_message(channel, log_time=ns, data=message, publish_time=ns)
            count += 1
        writer.finish()
    return time.perf_counter() - start, count


def read_only(fused: FusedScans, worker_from: int) -> float:
    """Seconds to take every message, writing nothing."""
    start = time.perf_counter()
    for _ in fused_items(fused, worker_from=worker_from):
        pass
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=60_000, help="scans in the journal")
    parser.add_argument("--beams", type=int, default=360, help="beams a scan")
    parser.add_argument("--rounds", type=int, default=2, help="times each way is timed")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="replay-write-") as tmp:
        folder = Path(tmp)
        write_journal(folder / "journal.sqlite3", args.scans, args.beams)
        fused = FusedScans({}, folder / "journal.sqlite3")
        for round_ in range(1, args.rounds + 1):
            peer_s, n = write_fused(fused, folder / "peer.mcap", IN_PROCESS)
            child_s, m = write_fused(fused, folder / "child.mcap", IN_CHILD)
            same = (folder / "peer.mcap").read_bytes() == (folder / "child.mcap").read_bytes()
            print(
                f"round {round_}, {n} scans x {args.beams} beams written: messages in a child "
                f"{child_s:.2f} s ({m / child_s:,.0f} scans/s); peer, in process {peer_s:.2f} s "
                f"({n / peer_s:,.0f} scans/s): {peer_s / child_s:.2f}x; files the same: {same}",
                flush=True,
            )
        peer_s, child_s = read_only(fused, IN_PROCESS), read_only(fused, IN_CHILD)
        print(
            f"messages alone, nothing written: in a child {child_s:.2f} s, "
            f"in process {peer_s:.2f} s"
        )


if __name__ == "__main__":
    main()
