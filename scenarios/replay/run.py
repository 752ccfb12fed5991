"""``fleetmap replay`` of a run: a run folder (with ``replay.mcap``) or the ``.mcap`` file
itself is rebuilt into a map like ``map build``; anything else goes to the server-journal
replay (``mapserver.cli.serve.run_replay``).

A run's replay holds every scan its own map server fused and that server's map settings
(``scenarios.replay.fused``): they are fused in the server's order with its settings, so
the map equals the server's bit for bit. A replay without them (a run against an outside
server, or an older file) falls back to its sampled LaserScans (``RunOptions.
record_scans_s``), fused with the policy of the run's ``metrics.json`` (``decay`` without
one) and the default sensor model: an approximation of the run's map, said on stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from mapserver.cli.serve import run_replay as run_journal_replay
from mapserver.cli.serve import write_replayed
from mapserver.core.belief import BeliefGrid
from mapserver.core.scan import Scan
from mapserver.core.sensor_model import Policy
from mapserver.service.replay import ReplayError, belief_for
from mapserver.store.journal import JOURNAL_FILENAME
from scenarios.replay.mcap import (
    REPLAY_FILENAME,
    ReplayFileError,
    read_fused_replay,
    read_geometry,
    read_scans,
)


def replay_file_of(source: Path) -> Path | None:
    """The run's replay file when ``source`` is a run folder or an ``.mcap`` file."""
    if source.is_dir() and (source / REPLAY_FILENAME).is_file():
        return source / REPLAY_FILENAME
    if source.is_file() and source.suffix == ".mcap":
        return source
    return None


SOURCES = (
    "give a server's --data-dir or its journal.sqlite3, or a run's --out folder or its replay.mcap"
)
"""What ``fleetmap replay`` reads, as the fix of an error about its source."""


def source_problem(source: Path) -> str | None:
    """Why ``source`` is nothing ``replay`` reads (missing, or a folder holding neither a
    journal nor a run's replay); None when it may be one."""
    if not source.exists():
        return f"{source}: no such file or folder ({SOURCES})"
    if source.is_dir() and not (source / JOURNAL_FILENAME).is_file():
        if not (source / REPLAY_FILENAME).is_file():
            return (
                f"{source}: holds neither a server's {JOURNAL_FILENAME} nor a run's "
                f"{REPLAY_FILENAME} ({SOURCES})"
            )
    return None


def run_replay(args: argparse.Namespace) -> int:
    """``fleetmap replay`` for runs and journals alike."""
    problem = source_problem(args.source)
    if problem is not None:
        print(f"fleetmap replay: error: {problem}", file=sys.stderr)
        return 2
    replay = replay_file_of(args.source)
    if replay is None:
        return run_journal_replay(args)
    try:
        fused = read_fused_replay(replay, until=args.until)
        if fused is not None:
            settings, scans = fused
            belief = belief_for(settings, replay)
        else:
            belief, scans = _approximation(replay, args.until)
    except (ReplayFileError, ReplayError, ValueError, KeyError, OSError) as exc:
        print(f"fleetmap replay: error: {exc}", file=sys.stderr)
        return 2
    return write_replayed(belief, scans, args)


def _approximation(replay: Path, until: float | None) -> tuple[BeliefGrid, list[Scan]]:
    """The belief grid and sampled LaserScans of a replay without fused scans."""
    print(
        f"fleetmap replay: {replay} holds no fused scans (a run against an outside server "
        "or an older replay): rebuilding from its sampled LaserScans, an approximation",
        file=sys.stderr,
    )
    geometry = read_geometry(replay)
    scans = read_scans(replay, until=until)
    metrics = replay.parent / "metrics.json"
    policy = json.loads(metrics.read_text())["policy"] if metrics.is_file() else "decay"
    return BeliefGrid(geometry, policy=Policy.parse(policy)), scans
