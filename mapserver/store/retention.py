"""Journal retention: delete the scans past retention that a kept snapshot covers.

Model: Kafka's ``retention.ms`` / ``retention.bytes`` (https://kafka.apache.org/documentation/#topicconfigs):
a record becomes deletable once it is older than ``retain_seconds`` or once the log is
larger than ``retain_bytes``, whichever comes first; null disables a limit, both null
keep everything. Like Kafka, which deletes whole segments, deletion is coarse: here the
unit is the stretch of scans between two snapshots.

Age is wall time of journaling, not scan stamps. Stamps may be simulated seconds from 0,
faster than real time, or a unit's wrong clock; what fills the disk is scans per wall
second. A snapshot records the wall time it was saved (``saved_at``): every scan it
covers (seq <= its seq) was journaled before then. So the scans up to the newest snapshot
saved at least ``retain_seconds`` ago are all past retention, and they are what is
deleted: a scan journaled within ``retain_seconds`` is never deleted. (A wall clock
stepped forward by NTP ages scans early by that step; the anchor rule below still keeps
the map rebuildable.)

Anchors. The snapshot at the cut (the *anchor*) is kept with the scans after it, so every
retained scan replays from a kept snapshot at or before it (``fleetmap replay``, start-up
when the newer snapshots are damaged). Snapshots between the anchor and the newest
``keep_snapshots`` are thinned to the future anchors: the oldest snapshot of each
*bucket*, ``retain_seconds / ANCHORS`` of wall time saved (``saved_at``), or, with a size
limit alone, ``1 / ANCHORS`` of the scans that fit in it (by seq). Buckets are fixed, so a
snapshot kept as a future anchor stays kept until the cut passes it, and the cut moves a
bucket at a time: the journal keeps at most ``(1 + 1 / ANCHORS)`` times the retention
plus one snapshot interval, and reaches that bound within one retention period (a
thinning that spaced anchors relative to the scans held at each run drifted: the anchors
it kept were spaced unevenly, and the scans held, the file's high-water mark, crept up
for as long as the soak benchmark ran). Snapshots older than the anchor are deleted.

Bytes. ``retain_bytes`` bounds the journal file's used pages (scans, their index,
quarantine and snapshots; the ``-wal`` file is bounded apart by ``journal_size_limit``).
Bytes per scan are estimated from the used pages less the snapshots, over the scans held.

Order of deletion, each step its own short transaction (``Journal.delete_scans_through``:
``BATCH`` seqs each), so appends wait for one batch at most and a crash between any two
steps leaves a journal that restarts: the anchor is checked to load first; scans up to
it go next, each batch raising ``deleted_through`` (start-up ignores snapshots older than
that); then the older snapshots, the quarantined rows at or before the cut and beyond
``quarantine_max_rows``, and the stamp bounds of units with no scan left.

Freed pages go to SQLite's freelist and are reused by later appends ("the freelist",
https://www.sqlite.org/fileformat2.html#the_freelist), so once retention cuts, the file
stops growing at what retention keeps plus one batch; it does not shrink (``VACUUM``
offline does that).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

from mapserver.store.journal import Journal, SnapshotError, SnapshotInfo

logger = logging.getLogger(__name__)

ANCHORS = 4  # snapshots kept spread through the retained scans, besides the newest
BATCH = 1000  # scans deleted per transaction


@dataclass(frozen=True)
class RetentionPolicy:
    """What the journal keeps.

    retain_seconds: [s] of wall time a scan is kept at least after it was journaled
        (None: no age limit).
    retain_bytes: [bytes] the journal file's used pages are cut back to (None: no size
        limit).
    keep_snapshots: the newest snapshots always kept (>= 1).
    quarantine_max_rows: quarantined rows kept at most, the newest (None: no cap).
    """

    retain_seconds: float | None = None
    retain_bytes: int | None = None
    keep_snapshots: int = 2
    quarantine_max_rows: int | None = None

    @property
    def enabled(self) -> bool:
        """Whether anything is ever deleted (a limit on scans or on quarantine)."""
        limits = (self.retain_seconds, self.retain_bytes, self.quarantine_max_rows)
        return any(limit is not None for limit in limits)


@dataclass(frozen=True)
class RetentionPlan:
    """``cut``: delete the scans with seq <= cut (0 or <= ``deleted_through``: none);
    ``drop_snapshots``: the seqs of the snapshots to delete."""

    cut: int
    drop_snapshots: tuple[int, ...]


@dataclass(frozen=True)
class RetentionReport:
    """What one ``apply_retention`` deleted: scans, snapshots, quarantined rows, unit
    stamp bounds, and the seq the journal now starts after."""

    scans: int = 0
    snapshots: int = 0
    quarantined: int = 0
    units: int = 0
    deleted_through: int = 0


def plan_retention(
    snapshots: list[SnapshotInfo],
    last_seq: int,
    deleted_through: int,
    used_bytes: int,
    now: float,
    policy: RetentionPolicy,
) -> RetentionPlan:
    """Which scans and snapshots to delete (pure: the module docstring's rules).

    snapshots: the stored snapshots, oldest first (only those with seq >=
        ``deleted_through`` can be anchors; older ones are dropped).
    last_seq: the journal's newest seq. used_bytes: the file's used pages [bytes].
    now: [s since the epoch] wall time.
    """
    usable = [s for s in snapshots if s.seq >= deleted_through]
    past: list[int] = []
    if policy.retain_seconds is not None:
        past += [s.seq for s in usable if s.saved_at <= now - policy.retain_seconds]
    fitting = None  # scans that fit in retain_bytes
    if policy.retain_bytes is not None:
        held = max(1, last_seq - deleted_through)
        snapshot_bytes = sum(s.nbytes for s in snapshots)
        per_scan = max(1.0, (used_bytes - snapshot_bytes) / held)
        fitting = max(0, int((policy.retain_bytes - snapshot_bytes) / per_scan))
        if used_bytes > policy.retain_bytes:
            past += [s.seq for s in usable if s.seq <= last_seq - fitting]
    cut = max(past, default=0)
    newest = {s.seq for s in usable[-policy.keep_snapshots :]}
    # the anchor: the snapshot replays start from (the new cut, else the one kept at the
    # last cut), kept whatever the buckets
    anchor = cut
    if cut <= deleted_through and deleted_through > 0 and usable:
        anchor = usable[0].seq
    anchor = anchor if anchor > 0 else -1
    kept, buckets = set(newest), set()
    for info in usable:
        if info.seq < cut or info.seq in newest:
            continue
        bucket = _bucket(info, policy, fitting)
        if info.seq == anchor or bucket not in buckets:
            kept.add(info.seq)
            buckets.add(bucket)
    if policy.retain_seconds is None and policy.retain_bytes is None:
        kept = newest  # no scan limit: as without retention, the newest snapshots only
    drop = tuple(s.seq for s in snapshots if s.seq not in kept)
    return RetentionPlan(cut if cut > deleted_through else 0, drop)


def _bucket(info: SnapshotInfo, policy: RetentionPolicy, fitting: int | None) -> int:
    """The fixed bucket of snapshot ``info`` among the future anchors (module docstring):
    by wall time saved under an age limit, else by seq (``fitting``: the scans that fit
    in the size limit)."""
    if policy.retain_seconds is not None:
        return math.floor(info.saved_at / (policy.retain_seconds / ANCHORS))
    return info.seq // max(1, (fitting or 0) // ANCHORS)


def apply_retention(
    journal: Journal, policy: RetentionPolicy, now: float | None = None
) -> RetentionReport:
    """Plan and carry out retention on ``journal`` (module docstring), off the ingest
    path: call it from the snapshot thread after a save. ``now``: [s since the epoch]
    wall time (default: the clock). A snapshot that does not load is never an anchor:
    it is logged and the cut moves to an older one (or none)."""
    if not policy.enabled:
        return RetentionReport(deleted_through=journal.deleted_through())
    now = time.time() if now is None else now
    bad: set[int] = set()
    while True:
        infos = [s for s in journal.snapshot_infos() if s.seq not in bad]
        pages, free, page_size = journal.page_stats()
        plan = plan_retention(
            infos,
            journal.last_seq(),
            journal.deleted_through(),
            (pages - free) * page_size,
            now,
            policy,
        )
        if plan.cut == 0:
            break
        try:
            journal.load_snapshot(plan.cut)
        except SnapshotError as exc:
            logger.error("retention: snapshot at seq %d cannot be an anchor: %s", plan.cut, exc)
            bad.add(plan.cut)
            continue
        break
    scans = journal.delete_scans_through(plan.cut, BATCH) if plan.cut else 0
    drop = [*plan.drop_snapshots, *(seq for seq in bad if seq < plan.cut)]
    journal.delete_snapshots(drop)
    through = journal.deleted_through()
    quarantined = journal.prune_quarantine(through, policy.quarantine_max_rows)
    units = journal.prune_units() if scans else 0
    report = RetentionReport(scans, len(drop), quarantined, units, through)
    if scans or drop or quarantined:
        logger.info(
            "retention: deleted %d scans (through seq %d), %d snapshots, %d quarantined "
            "rows, %d unit stamp bounds",
            scans,
            through,
            len(drop),
            quarantined,
            units,
        )
    return report
