"""``fleetmap serve`` (the map server under uvicorn) and ``fleetmap replay`` (a map from
a server's journal, written like ``map build``)."""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
from pathlib import Path
from typing import Any

from mapserver.cli.listen import ListenError, listen
from mapserver.core.belief import BeliefGrid
from mapserver.core.scan import Scan
from mapserver.service.settings import Settings, SettingsError, load_settings


def add_serve_parsers(subparsers: argparse._SubParsersAction) -> None:
    """Register ``serve`` and ``replay``."""
    serve = subparsers.add_parser(
        "serve",
        help="run the map server",
        description="Run the map server. Settings: --config YAML, FLEETMAP_* variables, "
        "then these flags, each overriding the one before.",
    )
    serve.add_argument("--host", help="address to bind (default 127.0.0.1)")
    serve.add_argument("--port", type=int, help="port (default 8700; 0 picks a free one)")
    serve.add_argument("--data-dir", type=Path, help="journal and snapshots (./fleetmap-data)")
    serve.add_argument("--map", type=Path, dest="map_yaml", help="ROS map YAML: grid + static")
    serve.add_argument("--config", type=Path, help="YAML settings file")
    serve.set_defaults(handler=run_serve)

    replay = subparsers.add_parser(
        "replay",
        help="rebuild a map from a server journal or a run's replay",
        description="Replay a server's journal (its data dir or journal file) or a run's "
        "replay.mcap (its folder or the file: every scan its server fused, with its map "
        "settings) and write map.yaml, map.pgm and logodds.npy as 'fleetmap map build' does.",
    )
    replay.add_argument(
        "source", type=Path, help="server data dir, journal.sqlite3, or a run's folder/replay.mcap"
    )
    replay.add_argument("--until", type=float, help="[s] replay scans with stamp <= this")
    replay.add_argument(
        "--out",
        type=Path,
        help=f"output folder (default: SOURCE/{REPLAY_OUT}, or beside SOURCE when it is a file)",
    )
    replay.add_argument("--json", action="store_true", help="print the figures as JSON last")
    replay.set_defaults(handler=run_replay)


def run_serve(args: argparse.Namespace) -> int:
    import uvicorn

    from mapserver.api.app import create_app
    from mapserver.service.map_process import MapProcessError, open_map_service
    from mapserver.service.map_service import DataDirError
    from mapserver.store.journal import JournalError

    overrides = {
        "host": args.host,
        "port": args.port,
        "data_dir": args.data_dir,
        "map_yaml": args.map_yaml,
    }
    try:
        settings = load_settings(args.config, overrides)
        listener = listen(settings.host, settings.port)
    except SettingsError as exc:
        for line in exc.lines():
            print(f"fleetmap serve: error: {line}", file=sys.stderr)
        return 2
    except ListenError as exc:
        print(f"fleetmap serve: error: {exc}", file=sys.stderr)
        return 2
    try:
        service = open_map_service(settings, on_lost=_stop_serving)
        app = create_app(settings, service)
    except (DataDirError, JournalError, MapProcessError) as exc:
        listener.close()
        print(f"fleetmap serve: error: {exc}", file=sys.stderr)
        return 2
    # The ingest thread fuses in numba with the GIL released; a short switch interval lets
    # it take the GIL back promptly from the busy event loop (Python's default is 5 ms).
    sys.setswitchinterval(0.0005)

    class AnnouncedServer(uvicorn.Server):
        """uvicorn's server, saying where it listens once it does (the port it got)."""

        async def startup(self, sockets: Any = None) -> None:
            await super().startup(sockets)
            if self.started and not self.should_exit:
                port = self.servers[0].sockets[0].getsockname()[1]
                print(listening_line(settings, port), file=sys.stderr, flush=True)

    AnnouncedServer(uvicorn_config(app, settings)).run(sockets=[listener])
    return 0


def _stop_serving() -> None:
    """The map process is gone: stop as on SIGTERM (answer what is in flight, exit)."""
    os.kill(os.getpid(), signal.SIGTERM)


def listening_line(settings: Settings, port: int) -> str:
    """The one line ``serve`` prints once it listens: its address (the viewer's URL), the
    API docs, and whether tokens are on (how many) or the server is open, loopback only."""
    host = f"[{settings.host}]" if ":" in settings.host else settings.host
    url = f"http://{host}:{port}/"
    if settings.open_access:
        tokens = "tokens: off - open to every client, loopback only"
    else:
        tokens = f"tokens: on ({len(settings.tokens)})"
    return f"fleetmap serve: listening on {url} (viewer; API docs at {url}docs); {tokens}"


def uvicorn_config(app: Any, settings: Settings) -> Any:
    """uvicorn's config for ``app`` with the ``server`` section's bounds (timeouts [s],
    connections), logging at WARNING through a RateLimitFilter on every handler, without
    the tracebacks of requests cancelled at shutdown (``cancel_log``)."""
    import uvicorn

    from mapserver.api.http_protocol import with_head_timeout
    from mapserver.service import cancel_log, lograte

    server = settings.server
    config = uvicorn.Config(
        app,
        host=settings.host,
        port=settings.port,
        log_level="warning",
        http=with_head_timeout(server.header_timeout_s, server.max_connections),
        timeout_keep_alive=server.keep_alive_s,  # type: ignore[arg-type]  # float works
        limit_concurrency=server.max_connections,
        timeout_graceful_shutdown=server.shutdown_timeout_s,  # type: ignore[arg-type]
    )
    # uvicorn configured its loggers above; the app's (mapserver.*, planner.*) reach root.
    if not logging.getLogger().handlers:
        handler = logging.StreamHandler()
        handler.setFormatter(logging.Formatter("%(levelname)s:%(name)s: %(message)s"))
        logging.getLogger().addHandler(handler)
    lograte.install(server.log_burst, server.log_interval_s, ("", "uvicorn", "uvicorn.access"))
    cancel_log.install()  # requests cancelled at the shutdown deadline: one line, no tracebacks
    return config


def run_replay(args: argparse.Namespace) -> int:
    from mapserver.service.replay import ReplayError, replay_journal

    try:
        belief, scans, skipped = replay_journal(args.source, until=args.until)
    except ReplayError as exc:
        print(f"fleetmap replay: error: {exc}", file=sys.stderr)
        return 2
    for record in skipped:
        print(
            f"fleetmap replay: skipped damaged record seq {record.seq} "
            f"(unit {record.unit_id!r}): {record.reason}",
            file=sys.stderr,
        )
    return write_replayed(belief, scans, args)


REPLAY_OUT = "replay-map"
"""The folder ``replay`` writes into without ``--out``, beside what it replays."""


def default_replay_out(source: Path) -> Path:
    """Where ``replay SOURCE`` writes without ``--out``: ``REPLAY_OUT`` in the folder
    ``source`` is (a data dir, a run's folder) or holds (a journal, a replay.mcap), never
    the current folder."""
    return (source if source.is_dir() else source.parent) / REPLAY_OUT


def write_replayed(belief: BeliefGrid, scans: list[Scan], args: argparse.Namespace) -> int:
    """Fuse replayed ``scans`` into ``belief``, write the map files to ``args.out`` and
    report (``args.json``: the figures as JSON); the tail of every ``fleetmap replay``."""
    from mapserver.store.offline import fuse_all, write_map_outputs

    stats = fuse_all(belief, scans)
    yaml_path = write_map_outputs(belief, args.out or default_replay_out(args.source))
    if args.json:
        print(json.dumps(stats.as_dict()))
    else:
        print(f"replayed {stats.scans} scans of {args.source}; wrote {yaml_path}")
    return 0
