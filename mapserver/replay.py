"""Read a server's journal back: the empty belief grid its data dir was made with, and
its scans in journal order (optionally only those with stamp <= ``until``)."""

from __future__ import annotations

import json
from pathlib import Path

from mapserver.belief import BeliefGrid
from mapserver.geometry import GridGeometry
from mapserver.journal import JOURNAL_FILENAME, JournalError, open_journal_for_replay
from mapserver.scan import Scan, ScanError
from mapserver.sensor_model import DecayParams, Policy, SensorModel
from mapserver.service import MAP_SETTINGS_FILE


class ReplayError(ValueError):
    """The source is not a readable server journal."""


def replay_journal(source: Path, until: float | None = None) -> tuple[BeliefGrid, list[Scan]]:
    """(empty belief grid with the recorded map settings, the journal's scans)."""
    source = Path(source)
    data_dir = source if source.is_dir() else source.parent
    settings_path = data_dir / MAP_SETTINGS_FILE
    try:
        recorded = json.loads(settings_path.read_text())
        belief = BeliefGrid(
            GridGeometry(**recorded["grid"]),
            SensorModel(**recorded["sensor_model"]),
            Policy.parse(recorded["policy"]),
            DecayParams(**recorded["decay"]),
            max_clearing_range=recorded["max_clearing_range"] or float("inf"),
        )
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ReplayError(f"{settings_path}: not a map server's settings ({exc})") from None
    journal_file = source if source.is_file() else source / JOURNAL_FILENAME
    try:
        with open_journal_for_replay(journal_file) as journal:
            scans = [Scan.from_dict(body) for _, body in journal.scans_after(0, until_stamp=until)]
    except (JournalError, ScanError, OSError) as exc:
        raise ReplayError(f"{journal_file}: {exc}") from None
    return belief, scans
