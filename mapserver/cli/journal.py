"""``fleetmap journal check|salvage|drop``: inspect and mend a stopped server's journal.

- ``check DATA_DIR [--json]``: read-only. Counts the intact records, checksum failures,
  unparsable records, unreadable seqs, quarantined rows and usable / unusable snapshots,
  the last seq and the seq through which retention deleted the scans; when that is not
  0 and no usable snapshot at or after it remains, the map cannot be rebuilt (damaged).
  Exit 0 when all is intact, 1 when something is damaged, 2 on usage errors (no journal
  there, a live server holds it).
- ``salvage DATA_DIR [--out NEW_DIR] [--json]``: copies every intact record, in seq order
  with its original seq, into a fresh journal in NEW_DIR (default ``DATA_DIR-salvaged``)
  with ``map-settings.json``; damaged records that still read go to NEW_DIR's quarantine,
  quarantined ones stay quarantined. Works on a truncated or partly corrupt file
  (``mapserver.store.journal_rows``). The usable snapshots are copied too, with retention's
  mark: a journal whose first scans retention deleted rebuilds from them. Exit 0 when
  nothing was lost or damaged, 1 otherwise.
- ``drop DATA_DIR --unit U --after STAMP``: moves the unit's scans with stamp > STAMP to
  quarantine ("dropped by admin"), sets the unit's stamp bound to its largest remaining
  stamp and deletes the snapshots that include a dropped scan; the older ones stay, so
  the next start-up rebuilds the map from the newest of them. Refuses (exit 1, nothing
  changed) when retention deleted the journal's first scans and no usable snapshot
  predates the first dropped scan.

Each takes a lock on the journal file (``mapserver.store.datadir_lock``: shared for check and
salvage, exclusive for drop) and refuses to run while a server holds the data dir.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sqlite3
import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from mapserver.core.belief import state_names
from mapserver.core.errors import FleetmapError
from mapserver.core.scan import Scan, ScanError
from mapserver.core.sensor_model import Policy
from mapserver.service.map_service import MAP_SETTINGS_FILE, read_map_settings
from mapserver.store.datadir_lock import FileLocks, LockBusy
from mapserver.store.journal import (
    Journal,
    JournalError,
    RawRow,
    RecordError,
    decode_row,
    journal_path,
)
from mapserver.store.journal_rows import RowReader, Unreadable, readable_copy, seq_ranges
from mapserver.store.snapshot_state import snapshot_problem

DROP_REASON = "dropped by admin"
IMPORT_BATCH = 512  # rows per transaction of a salvage


class UsageError(FleetmapError, Exception):
    """The command cannot run on what it was given (exit 2); the message says why."""


def add_journal_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``journal check``, ``journal salvage`` and ``journal drop``."""
    parser = subparsers.add_parser("journal", help="check, salvage or mend a server journal")
    sub = parser.add_subparsers(dest="journal_command", required=True)
    commands = (
        ("check", run_check, "read-only integrity check of a data dir's journal",
         "Exit 0: all intact; 1: something is damaged; 2: usage error."),
        ("salvage", run_salvage, "copy every intact record into a fresh journal",
         "Reads a damaged or truncated journal row by row; writes NEW_DIR."),
        ("drop", run_drop, "quarantine one unit's scans after a stamp",
         "Moves the unit's scans with stamp > STAMP to quarantine, resets the unit's "
         "stamp bound and deletes the snapshots that include them (the next start-up "
         "rebuilds from the newest older one)."),
    )  # fmt: skip
    parsers = {}
    for name, run, help_text, description in commands:
        parsers[name] = sub.add_parser(name, help=help_text, description=description)
        parsers[name].add_argument("data_dir", type=Path, help="the data dir (server stopped)")
        parsers[name].set_defaults(handler=_command(run))
    parsers["check"].add_argument("--json", action="store_true", help="findings as JSON")
    salvage = parsers["salvage"]
    salvage.add_argument("--out", type=Path, help="new data dir (default DATA_DIR-salvaged)")
    salvage.add_argument("--json", action="store_true", help="print the figures as JSON")
    drop = parsers["drop"]
    drop.add_argument("--unit", required=True, help="unit_id whose scans to drop")
    drop.add_argument("--after", type=_finite, required=True, help="[s] drop stamps > this")


def _finite(text: str) -> float:
    """argparse type: a finite number of seconds."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite stamp in seconds, got {text!r}")
    return value


def _command(run: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """``run`` with its UsageError and JournalError printed as ``fleetmap journal`` errors."""

    def handler(args: argparse.Namespace) -> int:
        try:
            return run(args)
        except UsageError as exc:
            print(f"fleetmap journal {args.journal_command}: error: {exc}", file=sys.stderr)
            return 2
        except JournalError as exc:
            print(f"fleetmap journal {args.journal_command}: error: {exc}", file=sys.stderr)
            return 1

    return handler


def _hold(data_dir: Path, shared: bool) -> FileLocks:
    """The lock on ``data_dir``'s journal file; UsageError when there is none or a live
    server (or, for ``shared=False``, any other journal command) holds it."""
    path = journal_path(data_dir)
    if not path.is_file():
        raise UsageError(
            f"{data_dir}: no journal there ({path.name} missing: give a server's --data-dir)"
        )
    try:
        return FileLocks([path], shared=shared, create=False)
    except LockBusy:
        raise UsageError(
            f"{data_dir} is in use by a live map server (or another journal command): stop it first"
        ) from None


# --------------------------------------------------------------------------- check
@dataclass
class CheckReport:
    """What ``journal check`` found (counts, and the damaged items by seq)."""

    journal: str
    records: int = 0
    checksum_failures: int = 0
    unparsable: int = 0
    unreadable: int = 0
    quarantined: int = 0
    snapshots_usable: int = 0
    snapshots_unusable: int = 0
    last_seq: int = 0
    deleted_through: int = 0
    problems: list[str] = field(default_factory=list)

    @property
    def intact(self) -> bool:
        return not self.problems


def run_check(args: argparse.Namespace) -> int:
    with _hold(args.data_dir, shared=True):
        report = check_journal(args.data_dir)
    if args.json:
        print(json.dumps({**asdict(report), "intact": report.intact}))
    else:
        print(
            f"{report.journal}: {report.records} intact records, last seq {report.last_seq}; "
            f"{report.checksum_failures} checksum failures, {report.unparsable} unparsable, "
            f"{report.unreadable} unreadable; {report.quarantined} quarantined; snapshots "
            f"{report.snapshots_usable} usable, {report.snapshots_unusable} unusable; "
            + (
                f"retention deleted seqs 1-{report.deleted_through}"
                if report.deleted_through
                else "nothing deleted by retention"
            )
        )
        for problem in report.problems:
            print(f"  damaged: {problem}")
        print("all intact" if report.intact else "damaged: see docs/durability.md")
    return 0 if report.intact else 1


def check_journal(data_dir: Path) -> CheckReport:
    """Read every record and snapshot of ``data_dir``'s journal, changing nothing."""
    path = journal_path(data_dir)
    report = CheckReport(str(path))
    with readable_copy(path) as readable:
        try:
            with RowReader(readable) as reader:
                report.deleted_through = reader.deleted_through()
                _check_rows(reader, report)
                report.quarantined = len(reader.quarantined())
        except sqlite3.DatabaseError as exc:
            report.problems.append(f"the journal's tables do not read: {exc}")
            return report
        _check_snapshots(readable, data_dir, report)
    return report


def _check_rows(reader: RowReader, report: CheckReport) -> None:
    report.last_seq = reader.last_seq_claimed() or 0
    unreadable: list[int] = []
    for row in reader.rows():
        if isinstance(row, Unreadable):
            unreadable.append(row.seq)
            continue
        report.last_seq = max(report.last_seq, row.seq)
        problem = _row_problem(row)
        if problem is None:
            report.records += 1
        elif problem.startswith("checksum mismatch"):
            report.checksum_failures += 1
            report.problems.append(f"seq {row.seq}: {problem}")
        else:
            report.unparsable += 1
            report.problems.append(f"seq {row.seq}: {problem}")
    report.unreadable = len(unreadable)
    for first, last in seq_ranges(unreadable):
        report.problems.append(f"seqs {first}-{last}: unreadable")


def _row_problem(row: RawRow) -> str | None:
    """Why a row would be quarantined at start-up (a checksum mismatch first), or None."""
    record = decode_row(row)
    try:
        fields = record.fields()
        Scan.from_dict(fields, max_beams=max(1, len(fields["ranges"])))
    except (RecordError, ScanError) as exc:
        return str(exc)
    return None


def _check_snapshots(path: Path, data_dir: Path, report: CheckReport) -> None:
    try:
        recorded = read_map_settings(data_dir)
        grid = recorded["grid"]
        shape = (int(grid["height"]), int(grid["width"]))
        names = state_names(Policy.parse(recorded.get("policy", Policy.DECAY.value)))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        report.problems.append(f"{MAP_SETTINGS_FILE} does not read: {exc}")
        shape = None
    try:
        journal = Journal(path, readonly=True)
    except JournalError as exc:
        report.problems.append(f"the journal does not open: {exc}")
        return
    with journal:
        try:
            seqs = journal.snapshot_seqs()
        except JournalError as exc:
            report.problems.append(f"the snapshots do not read: {exc}")
            return
        starts = 0  # usable snapshots a rebuild can start from (seq >= deleted_through)
        for seq in seqs:
            try:
                snapshot = journal.load_snapshot(seq)
                problem = None if shape is None else snapshot_problem(snapshot, shape, names)
            except JournalError as exc:
                problem = str(exc)
            if problem is None:
                report.snapshots_usable += 1
                starts += seq >= report.deleted_through
            else:
                report.snapshots_unusable += 1
                report.problems.append(f"snapshot at seq {seq}: {problem}")
        if report.deleted_through and not starts:
            report.problems.append(
                f"retention deleted seqs 1-{report.deleted_through} and no usable snapshot "
                "at or after it remains: the map cannot be rebuilt from this journal"
            )


# ------------------------------------------------------------------------- salvage
@dataclass
class SalvageReport:
    """What ``journal salvage`` copied: intact seqs, damaged (quarantined) and lost."""

    out: str
    recovered: int = 0
    recovered_ranges: list[tuple[int, int]] = field(default_factory=list)
    quarantined: list[int] = field(default_factory=list)
    lost_ranges: list[tuple[int, int]] = field(default_factory=list)
    snapshots: list[int] = field(default_factory=list)


def run_salvage(args: argparse.Namespace) -> int:
    source = args.data_dir
    out = args.out or source.with_name(source.name + "-salvaged")
    if out.resolve() == source.resolve():
        raise UsageError(f"--out must be another directory than {source}")
    if journal_path(out).exists():
        raise UsageError(f"{out} already holds a journal: choose a new --out")
    with _hold(source, shared=True):
        report = salvage_journal(source, out)
    if args.json:
        print(json.dumps(asdict(report)))
    else:
        print(
            f"recovered {report.recovered} intact records into {report.out} "
            f"(seqs {_ranges_text(report.recovered_ranges) or 'none'})"
        )
        if report.quarantined:
            print(
                f"damaged, kept in quarantine: seqs {_ranges_text(seq_ranges(report.quarantined))}"
            )
        print(f"lost (unreadable): seqs {_ranges_text(report.lost_ranges) or 'none'}")
        print(f"snapshots copied: seqs {_ranges_text(seq_ranges(report.snapshots)) or 'none'}")
    return 0 if not (report.quarantined or report.lost_ranges) else 1


def salvage_journal(source: Path, out: Path) -> SalvageReport:
    """Copy ``source``'s readable records into a new journal in ``out`` (module doc)."""
    out.mkdir(parents=True, exist_ok=True)
    settings = source / MAP_SETTINGS_FILE
    if settings.is_file():
        shutil.copyfile(settings, out / MAP_SETTINGS_FILE)
    report = SalvageReport(str(out))
    recovered: list[int] = []
    lost: list[int] = []
    with readable_copy(journal_path(source)) as readable:
        try:
            reader = RowReader(readable)
        except sqlite3.DatabaseError as exc:
            raise JournalError(
                f"{source}: nothing salvageable, the schema does not read: {exc}"
            ) from None
        with reader, Journal(journal_path(out)) as journal:
            batch: list[RawRow] = []
            reasons: dict[int, str] = {}
            for row, reason in reader.quarantined():
                batch.append(row)
                reasons[row.seq] = reason
            for row in reader.rows():
                if isinstance(row, Unreadable):
                    lost.append(row.seq)
                    continue
                batch.append(row)
                problem = _row_problem(row)
                if problem is None:
                    recovered.append(row.seq)
                else:
                    reasons[row.seq] = f"salvage: {problem}"
                    report.quarantined.append(row.seq)
                if len(batch) >= IMPORT_BATCH:
                    journal.import_rows(batch, reasons)
                    batch = []
            journal.import_rows(batch, reasons)
            stamps = reader.unit_stamps()
            if stamps:
                journal.raise_unit_stamps(stamps)
            deleted = reader.deleted_through()
            if deleted:
                journal.set_deleted_through(deleted)
            report.snapshots = _copy_snapshots(readable, journal, deleted)
    report.recovered = len(recovered)
    report.recovered_ranges = seq_ranges(recovered)
    report.lost_ranges = seq_ranges(lost)
    return report


def _copy_snapshots(source: Path, journal: Journal, deleted_through: int) -> list[int]:
    """Copy the snapshots of ``source`` that load (checksum and arrays) and a replay can
    start from (seq >= ``deleted_through``) into ``journal``; returns their seqs."""
    copied: list[int] = []
    try:
        old = Journal(source, readonly=True)
    except JournalError:
        return copied  # the header or schema does not read: no snapshot either
    with old:
        try:
            infos = old.snapshot_infos()
        except JournalError:
            return copied
        for info in infos:
            if info.seq < deleted_through:
                continue
            try:
                journal.import_snapshot(old.load_snapshot(info.seq), info.saved_at)
            except JournalError:
                continue  # unusable: not copied (the new journal's check stays clean)
            copied.append(info.seq)
    return copied


def _ranges_text(ranges: list[tuple[int, int]]) -> str:
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in ranges)


# ---------------------------------------------------------------------------- drop
def run_drop(args: argparse.Namespace) -> int:
    with _hold(args.data_dir, shared=False), Journal(journal_path(args.data_dir)) as journal:
        snapshots = len(journal.snapshot_seqs())
        dropped = journal.drop_unit_after(args.unit, args.after, DROP_REASON)
        bound: Any = journal.unit_stamps().get(args.unit, "none")
        kept = journal.snapshot_seqs()
    if not dropped:
        print(f"nothing to drop: unit {args.unit!r} has no scan with stamp > {args.after}")
        return 0
    seqs = _ranges_text(seq_ranges([seq for seq, _ in dropped]))
    stamps = [stamp for _, stamp in dropped]
    print(
        f"dropped {len(dropped)} scans of unit {args.unit!r} (seqs {seqs}, stamps "
        f"{min(stamps)}..{max(stamps)}) to quarantine; its stamp bound is now {bound}; "
        f"deleted {snapshots - len(kept)} snapshots, kept {len(kept)} older ones: the next "
        "start-up rebuilds the map from "
        + (f"the snapshot at seq {kept[-1]}" if kept else "the journal's first scan")
    )
    return 0
