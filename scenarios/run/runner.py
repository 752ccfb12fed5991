"""Run one scenario end to end and score it against ground truth.

``run`` starts a map server of its own on a free loopback port (or uses ``server_url``),
resets a ``scenarios.run.episode.Episode`` on it, steps it to the scenario's end and returns
the scored ``RunRecord``. The episode module says what each step does.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

import httpx

from mapserver.client import MapClient
from mapserver.core.geometry import GridGeometry
from scenarios.replay.fused import read_fused
from scenarios.run.embedded_server import EmbeddedServer
from scenarios.run.episode import Episode, RunOptions
from scenarios.run.observers import Observer, ProgressReport
from scenarios.run.record import RunRecord
from scenarios.spec.scenario import Scenario

__all__ = ["Progress", "RunOptions", "grid_geometry", "run"]

Progress = Callable[[float, float], None]

SIM_SERVER = {"ingest": {"unit_beams_per_s": None, "unit_scans_per_s": None}}
"""What a run's own server changes from the defaults: no per-unit ingest budget, which
is counted in wall seconds, while a simulation faster than real time posts each unit's
scans that many times faster (its one client is the simulation, on loopback)."""


def run(
    setup: Scenario,
    server_url: str | None = None,
    options: RunOptions | None = None,
    progress: Progress | None = None,
    token: str | None = None,
    announce: Callable[[str], None] | None = None,
    data_dir: Path | None = None,
    observers: Sequence[Observer] = (),
) -> RunRecord:
    """Run scenario ``setup`` against ``server_url`` (None: an embedded server of its own,
    on ``data_dir``, a temporary one when None; ``token``: the bearer token for a server
    that needs one); ``progress(now, duration)`` [s] after every step; ``observers``:
    more observers of the episode (a benchmark's). With an embedded server the record
    holds what it fused (``RunRecord.fused``, read once it stopped)."""
    tmp = tempfile.TemporaryDirectory(prefix="fleetmap-run-")  # kept by record.fused
    server = None
    try:
        if server_url is None:
            data_dir = Path(tmp.name) / "data" if data_dir is None else Path(data_dir)
            server = EmbeddedServer(data_dir, {**setup.server_overrides(), **SIM_SERVER})
            server_url = server.url
            if announce is not None:
                announce(f"map server for this run: {server_url}/ (the live viewer)")
        try:
            with httpx.Client(base_url=server_url, timeout=60) as http:
                client = MapClient(http, token=token, timeout=60)
                extra = [*observers, *([ProgressReport(progress)] if progress else [])]
                with Episode(setup, client, options, extra) as episode:
                    episode.reset()
                    while not episode.done:
                        episode.step()
                    record = episode.finish()
        finally:
            if server is not None:
                server.stop()
        if server is None:
            tmp.cleanup()
        else:  # read while the replay is written; the temporary folder goes with it
            record.fused = read_fused(server.data_dir, tmp)
        return record
    except BaseException:
        tmp.cleanup()
        raise


def grid_geometry(width_m: float, height_m: float, resolution: float) -> GridGeometry:
    """The map grid covering a ``width_m`` x ``height_m`` [m] floor at ``resolution``."""
    return GridGeometry(
        int(math.ceil(width_m / resolution - 1e-9)),
        int(math.ceil(height_m / resolution - 1e-9)),
        resolution,
    )
