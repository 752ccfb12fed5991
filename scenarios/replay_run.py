"""``fleetmap replay`` of a run: a run folder (with ``replay.mcap``) or the ``.mcap`` file
itself is rebuilt into a map like ``map build``; anything else goes to the server-journal
replay (``mapserver.cli_serve.run_replay``).

A run's replay holds the scans it recorded (sampled, see ``RunOptions.record_scans_s``)
and its grid; the map is fused with the policy of the run's ``metrics.json`` (``decay``
without one) and the default sensor model, so it approximates, not equals, the run's
shared map.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from mapserver.belief import BeliefGrid
from mapserver.cli_serve import run_replay as run_journal_replay
from mapserver.cli_serve import write_replayed
from mapserver.sensor_model import Policy
from scenarios.replay_mcap import REPLAY_FILENAME, ReplayFileError, read_geometry, read_scans


def replay_file_of(source: Path) -> Path | None:
    """The run's replay file when ``source`` is a run folder or an ``.mcap`` file."""
    if source.is_dir() and (source / REPLAY_FILENAME).is_file():
        return source / REPLAY_FILENAME
    if source.is_file() and source.suffix == ".mcap":
        return source
    return None


def run_replay(args: argparse.Namespace) -> int:
    """``fleetmap replay`` for runs and journals alike."""
    replay = replay_file_of(args.source)
    if replay is None:
        return run_journal_replay(args)
    try:
        geometry = read_geometry(replay)
        scans = read_scans(replay, until=args.until)
        metrics = replay.parent / "metrics.json"
        policy = json.loads(metrics.read_text())["policy"] if metrics.is_file() else "decay"
    except (ReplayFileError, ValueError, KeyError, OSError) as exc:
        print(f"fleetmap replay: error: {exc}", file=sys.stderr)
        return 2
    return write_replayed(BeliefGrid(geometry, policy=Policy.parse(policy)), scans, args)
