"""Tick posting benchmark: what a run's map server takes to answer a fleet's ticks, posted
one tick to a request against several (``fleet.poster.ScanPoster`` sends the ticks that
queued behind a request together), and where an answer's time goes.

Run: ``python -m tests.benchmarks.tick_posting [--units 20] [--beams 360] [--ticks 100]
[--group 4] [--rounds 2]``

Starts the server a run starts (``scenarios.run.embedded_server``, the run's settings), then
posts ``--rounds`` times, each way in turn, ``--ticks`` ticks of ``--units`` scans
(360 beams, ranges 1-9 m, one scan per unit a tick at 10 Hz of stamps) from one client,
waiting for each answer, as the poster does: one tick to a request (the peer, as
every run posted before), and ``--group`` ticks to a request. Printed: milliseconds a
tick and scans/s each way, their ratio; then the server's own account of the last round
(``fleetmap_ingest_stage_seconds`` per request: journal, fuse, answered). Measures only;
tests assert behaviour.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

from mapserver.client import MapClient
from mapserver.core.scan import Scan
from scenarios.run.embedded_server import EmbeddedServer
from scenarios.run.runner import SIM_SERVER
from tests.benchmarks.fleet_load import ingest_stage_means, ingest_stage_totals


def make_ticks(count: int, units: int, beams: int, first: int, seed: int = 0) -> list[list[Scan]]:
    """``count`` ticks from tick number ``first``: one scan of each unit, 0.1 s apart."""
    rng = np.random.default_rng(seed + first)
    ticks = []
    for k in range(first, first + count):
        tick = []
        for unit in range(units):
            ranges = (rng.random(beams) * 8.0 + 1.0).astype(np.float32)
            tick.append(Scan.from_dict({
                "unit_id": f"u{unit}", "stamp": 1.0 + 0.1 * k, "frame": "map",
                "pose": {"x": 10.0 + unit, "y": 10.0, "yaw": 0.0},
                "angle_min": -math.pi, "angle_increment": 2 * math.pi / beams,
                "range_min": 0.1, "range_max": 10.0, "ranges": ranges,
            }))  # fmt: skip
        ticks.append(tick)
    return ticks


def post(client: MapClient, ticks: list[list[Scan]], group: int) -> float:
    """Seconds to post ``ticks``, ``group`` to a request, each answer awaited."""
    start = time.perf_counter()
    for i in range(0, len(ticks), group):
        client.post_scans([scan for tick in ticks[i : i + group] for scan in tick])
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=20, help="scans a tick")
    parser.add_argument("--beams", type=int, default=360, help="beams a scan")
    parser.add_argument("--ticks", type=int, default=100, help="ticks posted each way a round")
    parser.add_argument("--group", type=int, default=4, help="ticks a request, against one")
    parser.add_argument("--rounds", type=int, default=2, help="rounds, each way in turn")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="tick-posting-") as tmp:
        with EmbeddedServer(Path(tmp) / "data", SIM_SERVER) as server:
            with httpx.Client(base_url=server.url, timeout=60) as http:
                client = MapClient(http, timeout=60)
                first = 0
                for round_ in range(1, args.rounds + 1):
                    seconds = {}
                    for group in (1, args.group):
                        ticks = make_ticks(args.ticks, args.units, args.beams, first)
                        first += args.ticks
                        before = ingest_stage_totals(server.url)
                        seconds[group] = post(client, ticks, group)
                        means = ingest_stage_means(before, ingest_stage_totals(server.url))
                        stages = ", ".join(
                            f"{stage} {means[stage]:.2f} ms"
                            for stage in ("journal", "fuse", "answered")
                        )
                        print(
                            f"round {round_}, {group} tick(s) of {args.units} x {args.beams} "
                            f"beams a request: {seconds[group] / args.ticks * 1e3:.2f} ms a tick "
                            f"({args.ticks * args.units / seconds[group]:,.0f} scans/s); "
                            f"the server, a request: {stages}",
                            flush=True,
                        )
                    ratio = seconds[1] / seconds[args.group]
                    print(f"round {round_}: {args.group} ticks a request {ratio:.2f}x one")


if __name__ == "__main__":
    main()
