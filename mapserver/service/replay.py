"""Read a server's journal back: the empty belief grid its data dir was made with, and
its scans in journal order (optionally only those with stamp <= ``until``).

When retention deleted the journal's first scans, the replay starts from the oldest
kept snapshot that loads (at or after the cut) instead of an empty grid; a journal that
still starts at its first scan replays from seq 0 as before.

Read-only: a damaged record (its checksum fails, its body does not parse, or
``Scan.from_dict`` refuses it) is skipped and reported, as the server would quarantine
it, but the journal is not changed. Every intact record is replayed, as the server
does (the clock rule judged scans when they arrived, docs/map-time.md), but one whose
stamp is ahead of the wall clock even now, which the server quarantines too."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mapserver.core.belief import BeliefGrid
from mapserver.core.errors import FleetmapError
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Scan
from mapserver.core.sensor_model import DecayParams, Policy, SensorModel
from mapserver.service.map_clock import DEFAULT_MAX_LEAD_S
from mapserver.service.map_service import MAP_SETTINGS_FILE, read_map_settings
from mapserver.store.journal import (
    JOURNAL_FILENAME,
    Journal,
    JournalError,
    Snapshot,
    open_journal_for_replay,
)
from mapserver.store.journal_reading import ReadRecord, read_records
from mapserver.store.snapshot_state import GRID_ARRAYS, load_snapshot_into, snapshot_problem


class ReplayError(FleetmapError, ValueError):
    """The source is not a readable server journal."""


@dataclass(frozen=True)
class Skipped:
    """A journal record left out of a replay: its seq, unit and why."""

    seq: int
    unit_id: str
    reason: str


def replay_journal(
    source: Path, until: float | None = None
) -> tuple[BeliefGrid, list[Scan], list[Skipped]]:
    """(belief grid with the recorded map settings, empty or loaded from the oldest kept
    snapshot when retention deleted the first scans, the journal's intact scans after
    it, the damaged records skipped). ReplayError when no snapshot can start the replay
    or ``until`` [s] is before the oldest kept snapshot's stamp."""
    source = Path(source)
    data_dir = source if source.is_dir() else source.parent
    belief = belief_for(read_settings(data_dir), data_dir / MAP_SETTINGS_FILE)
    journal_file = source if source.is_file() else source / JOURNAL_FILENAME
    after = 0
    with opened_journal(journal_file) as journal:
        start = replay_start(journal, belief.geometry.shape, belief.state_names)
    if start is not None:
        if until is not None and until < start.stamp:
            raise ReplayError(
                f"{journal_file}: --until {until} is before the oldest kept snapshot (seq "
                f"{start.seq}, stamp {start.stamp}): retention deleted the scans before it; "
                f"use --until >= {start.stamp}"
            )
        load_snapshot_into(belief, start)
        after = start.seq
    scans, skipped = journal_scans(journal_file, until, after)
    return belief, [scan for _, scan in scans], skipped


def replay_start(
    journal: Journal, shape: tuple[int, int], names: tuple[str, ...] = GRID_ARRAYS
) -> Snapshot | None:
    """The snapshot a replay of ``journal`` starts from: None (an empty grid, seq 0) when
    the journal still holds its first scans, else the oldest kept snapshot at or after
    retention's cut that loads into a grid of ``shape``; JournalError when none does."""
    base = journal.deleted_through()
    if base == 0:
        return None
    problems = []
    for seq in journal.snapshot_seqs():
        if seq < base:
            continue
        try:
            snapshot = journal.load_snapshot(seq)
        except JournalError as exc:
            problems.append(str(exc))
            continue
        problem = snapshot_problem(snapshot, shape, names)
        if problem is None:
            return snapshot
        problems.append(f"snapshot at seq {seq}: {problem}")
    raise JournalError(
        f"retention deleted scans 1-{base} and no kept snapshot at or after seq {base} "
        f"loads ({'; '.join(problems) or 'none kept'}): a replay from seq 0 is only possible "
        "while nothing was deleted"
    )


def read_settings(data_dir: Path) -> dict[str, Any]:
    """The map settings a server recorded in ``data_dir`` (``MAP_SETTINGS_FILE``, read
    as ``mapserver.service.map_service.read_map_settings`` does: an old dir's missing no-return
    fields filled with the rule it was fused under); ReplayError when missing or not JSON."""
    path = Path(data_dir) / MAP_SETTINGS_FILE
    try:
        return read_map_settings(Path(data_dir))
    except (OSError, ValueError) as exc:
        raise ReplayError(f"{path}: not a map server's settings ({exc})") from None


def belief_for(recorded: dict[str, Any], source: object = "map settings") -> BeliefGrid:
    """An empty belief grid with recorded map settings (grid, sensor model, policy,
    decay, max clearing range [m], null: unlimited); ReplayError naming ``source`` when
    they are not a server's map settings."""
    try:
        return BeliefGrid(
            GridGeometry(**recorded["grid"]),
            SensorModel(**recorded["sensor_model"]),
            Policy.parse(recorded["policy"]),
            DecayParams(**recorded["decay"]),
            max_clearing_range=recorded["max_clearing_range"] or float("inf"),
        )
    except (ValueError, KeyError, TypeError) as exc:
        raise ReplayError(f"{source}: not a map server's settings ({exc!r})") from None


def journal_scans(
    journal_file: Path, until: float | None = None, after: int = 0
) -> tuple[list[tuple[int, Scan]], list[Skipped]]:
    """The journal's intact scans after seq ``after`` as (seq, scan) in seq order, the
    order the server fuses them (stamps <= ``until`` [s] when given), and the records
    skipped."""
    scans: list[tuple[int, Scan]] = []
    skipped: list[Skipped] = []
    for record in journal_records(journal_file, until, after):
        if record.scan is None:
            skipped.append(Skipped(record.seq, record.unit_id, record.problem))
        else:
            scans.append((record.seq, record.scan))
    return scans, skipped


def journal_records(
    journal_file: Path, until: float | None = None, after: int = 0
) -> Iterator[ReadRecord]:
    """The journal's records after seq ``after`` one by one as the server reads them
    (``read_records``); ReplayError when the journal itself cannot be read."""
    with opened_journal(journal_file) as journal:
        not_after = time.time() + DEFAULT_MAX_LEAD_S  # as the server's start-up does
        yield from read_records(journal, after=after, until=until, not_after=not_after)


@contextmanager
def opened_journal(journal_file: Path) -> Iterator[Journal]:
    """The journal at ``journal_file`` open read-only; ReplayError naming the file when it,
    or a read of it inside the ``with``, fails (a missing file, a damaged page)."""
    try:
        with open_journal_for_replay(journal_file) as journal:
            yield journal
    except (JournalError, OSError) as exc:
        raise ReplayError(f"{journal_file}: {exc}") from None
