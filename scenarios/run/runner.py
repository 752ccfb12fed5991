"""Run one scenario end to end and score it against ground truth.

``run`` starts a map server of its own on a free loopback port (or uses ``server_url``),
resets a ``scenarios.run.episode.Episode`` on it, steps it to the scenario's end and returns
the scored ``RunRecord``. The episode module says what each step does.

With ``map_server.zones`` above 1 it starts one server per zone instead, side by side
(``Scenario.zone_layout``: strips of the floor with borders), and the episode reads and
posts through a ``ZonedMapClient``; the record's fused scans are then the zones' journals
merged as one server of the whole floor would have fused them (``read_zoned_fused``).
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import asdict
from pathlib import Path

import httpx

from mapserver.client import MapClient
from mapserver.client.zoned import ZonedMapClient
from mapserver.client.zones import ZoneLayout
from mapserver.core.geometry import GridGeometry
from scenarios.replay.fused import read_fused, read_zoned_fused
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
    servers: list[EmbeddedServer] = []
    layout = setup.zone_layout()
    try:
        urls = [server_url] if server_url is not None else []
        if server_url is None:
            data_dir = Path(tmp.name) / "data" if data_dir is None else Path(data_dir)
            servers = start_servers(setup, layout, data_dir)
            urls = [server.url for server in servers]
        try:
            for k, url in enumerate(urls if servers and announce is not None else ()):
                zone = f" (zone {k} of {len(urls)})" if len(urls) > 1 else ""
                announce(f"map server for this run{zone}: {url}/ (the live viewer)")
            with ExitStack() as stack:
                clients = [
                    MapClient(stack.enter_context(httpx.Client(base_url=url, timeout=60)),
                              token=token, timeout=60)
                    for url in urls
                ]  # fmt: skip
                client = clients[0]
                if len(clients) > 1:
                    client = stack.enter_context(ZonedMapClient(layout, clients))
                extra = [*observers, *([ProgressReport(progress)] if progress else [])]
                with Episode(setup, client, options, extra) as episode:
                    episode.reset()
                    while not episode.done:
                        episode.step()
                    record = episode.finish()
        finally:
            for server in servers:
                server.stop()
        if len(servers) == 1:  # read while the replay is written; the folder goes with it
            record.fused = read_fused(servers[0].data_dir, tmp)
        elif servers:
            dirs = [server.data_dir for server in servers]
            units = [spec.unit_id for spec in setup.unit_specs()]  # the order they post in
            record.fused = read_zoned_fused(dirs, layout.site, units, tmp)
        else:
            tmp.cleanup()
        return record
    except BaseException:
        tmp.cleanup()
        raise


def start_servers(setup: Scenario, layout: ZoneLayout, data_dir: Path) -> list[EmbeddedServer]:
    """The run's own map servers, ready: one on ``data_dir`` for a single zone, else one
    per zone on ``data_dir/zone-<k>`` with that zone's grid, started side by side."""
    settings = {**setup.server_overrides(), **SIM_SERVER}
    if layout.zones == 1:
        return [EmbeddedServer(data_dir, settings)]
    servers: list[EmbeddedServer] = []
    try:
        for k in range(layout.zones):
            grid = asdict(layout.geometry(k))  # the server's grid settings: the same names
            zone_dir = data_dir / f"zone-{k}"
            servers.append(EmbeddedServer(zone_dir, {**settings, "grid": grid}, wait=False))
        for server in servers:
            server.wait_ready()
    except BaseException:
        for server in servers:
            server.kill()
        raise
    return servers


def grid_geometry(width_m: float, height_m: float, resolution: float) -> GridGeometry:
    """The map grid covering a ``width_m`` x ``height_m`` [m] floor at ``resolution``."""
    return GridGeometry(
        int(math.ceil(width_m / resolution - 1e-9)),
        int(math.ceil(height_m / resolution - 1e-9)),
        resolution,
    )
