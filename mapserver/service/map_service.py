"""The map service: the shared map's state, its one writer and its readers (no HTTP).

State: the belief grid, the layered costmap and the journal, under one lock.

Writes. Scans are validated field by field by the caller (``Scan.from_dict``) and
submitted; one ingest thread takes them in arrival order, and everything that arrived
meanwhile is one group (group commit): the state checks (``scan_gate``: a unit's stamps
never go backwards, retries answered with their ack, the sensor on the map, no stamp
ahead of the map's clock, ``map_clock``) and one journal transaction (durable before
any reply). A second thread
fuses the journaled groups in the same order and then answers their submissions, so the
journal write of one group (an fsync, without the GIL) overlaps the fusion of the one
before (numba, without the GIL), and an ack's map version always includes its scan. A
rejected submission changes nothing. Each accepted submission's time in each of these
stages is kept for ``GET /metrics`` (``ingest_stages``).
The costmap follows the belief lazily and beside fusion (``costmap_follower``): the
boxes the scans touched are kept, and the costmap is brought up to the belief, over a
mirror of it, by the first read that needs it (so every read sees every acknowledged
scan), or by a thread of its own once ``reads.costmap_refresh_s`` [s] passed since the
last refresh (0: by the fusion thread before the acks): a fleet's scans of the same
places between two reads are composed and inflated once. The map's ``version`` is the
journal ``seq`` of the last scan fused, so it increases with every accepted scan and is
the same after a restart.

Reads take the follower's lock, never the map lock for long (only to copy what fusion
changed into the mirror): they gather what they need (a costmap of one version with its
version and stamp, the values at queried points) and compute outside it, so a slow
reader never stalls ingest.

Start-up first compiles (or loads from numba's cache) the fusion kernel of the map's
policy, so that no scan's answer waits for it (seconds on a cold cache).
Durability. Start-up then loads the newest snapshot and replays the journal after it: the
same belief bit for bit, and the costmap rebuilt at the map's stamp. Snapshots are taken
every ``snapshot_every_scans`` scans or ``snapshot_every_seconds`` [s] of wall time, and
no more often than keeps their saving within ``snapshot_max_share`` of the wall time
(``snapshot_schedule``).
Storage faults (docs/durability.md): an unusable snapshot falls back to an older one or
to a full replay; a damaged journal record is quarantined, logged and skipped.
Retention (``journal.retain_seconds``/``retain_bytes``, ``mapserver.store.retention``) runs
on the snapshot thread after each save; once it deleted the journal's first scans, only a
snapshot at or after the cut can start a rebuild.
"""

from __future__ import annotations

import json
import logging
import math
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mapserver.core.belief import BeliefGrid, FusionResult, load_fusion_kernels
from mapserver.core.errors import FleetmapError
from mapserver.core.occupancy import occupancy_percent
from mapserver.core.patch import Patch
from mapserver.core.queries import (
    CellSamples,
    SegmentReport,
    cell_columns,
    query_segments,
    sample_cells,
)
from mapserver.core.scan import Scan
from mapserver.core.sensor_model import fill_legacy_sensor_model
from mapserver.core.text import clip, quote
from mapserver.costmap.layered import LayeredCostmap
from mapserver.costmap.layers import InflationLayer, ObstacleLayer, StaticLayer
from mapserver.costmap.lower_bound import static_lower_bound
from mapserver.service.costmap_follower import CostmapFollower
from mapserver.service.ingest_stages import IngestStages
from mapserver.service.map_clock import MapClock
from mapserver.service.scan_gate import Ack, GroupCheck, IngestError, ScanGate, UnitLatest
from mapserver.service.settings import Settings
from mapserver.service.snapshot_schedule import SnapshotSchedule
from mapserver.store.datadir_lock import FileLocks, LockBusy
from mapserver.store.journal import Journal, JournalError, journal_path
from mapserver.store.journal_reading import read_records
from mapserver.store.retention import apply_retention
from mapserver.store.snapshot_state import load_snapshot_into

logger = logging.getLogger(__name__)

MAP_SETTINGS_FILE = "map-settings.json"
LOCK_FILE = "server.lock"
MAX_GROUP = 512  # scans applied together at most


class DataDirError(FleetmapError, RuntimeError):
    """The data directory cannot be used (in use, or written with other map settings)."""


@dataclass(frozen=True)
class GridRead:
    """A grid copied at one version: data (H, W), the map's version and stamp [s]."""

    data: np.ndarray
    version: int
    stamp: float


@dataclass
class _Submission:
    scans: list[Scan]
    future: Future
    submitted: float = field(default_factory=time.monotonic)  # [s]


@dataclass
class _Journaled:
    """A group past the gate and the journal, for the fusion thread: the accepted
    submissions with their gate entries, the new scans in journal order, their acks."""

    accepted: list[tuple[_Submission, list[UnitLatest]]]
    new: list[Scan]
    acks: list[Ack]
    taken: float  # [s] monotonic: when the ingest thread took the group
    journaled: float  # [s] monotonic: when its journal transaction committed


def _units(scans: list[Scan]) -> str:
    """The unit of ``scans`` (of a batch, its distinct units), quoted bounded for a log
    line or a message."""
    units = sorted({scan.unit_id for scan in scans})
    return quote(units[0] if len(units) == 1 else units)


def take_waiting(
    waiting: queue.Queue | queue.SimpleQueue, scans_of: Callable[[Any], int]
) -> tuple[list, bool]:
    """The items of ``waiting`` (at least one, blocking for it; more while they hold
    fewer than MAX_GROUP scans, counted by ``scans_of``) and whether a None (stop) came
    after them."""
    first = waiting.get()
    if first is None:
        return [], True
    items, count = [first], scans_of(first)
    while count < MAX_GROUP:
        try:
            item = waiting.get_nowait()
        except queue.Empty:
            break
        if item is None:
            return items, True
        items.append(item)
        count += scans_of(item)
    return items, False


def _fail(submissions: list[_Submission], exc: Exception) -> None:
    """Answer every submission not answered yet with ``exc``."""
    for sub in submissions:
        if not sub.future.done():
            sub.future.set_exception(exc)


class MapService:
    """The shared map of one data directory. ``close()`` stops it."""

    def __init__(self, settings: Settings) -> None:
        # before anything is opened: a kernel that cannot compile leaves nothing to close
        self.kernel_load_seconds = load_fusion_kernels([settings.policy])
        """[s] compiling (or loading from numba's cache) the fusion kernel of the map's
        policy at start-up, so the first scan is not the one to wait for it."""
        logger.info(
            "fusion kernel of policy %s ready in %.2f s",
            settings.policy.value,
            self.kernel_load_seconds,
        )
        self.settings = settings
        self.geometry = settings.geometry()
        self.data_dir = Path(settings.data_dir)
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self._lock_handle = _lock_data_dir(self.data_dir)
        _check_map_settings(self.data_dir, _map_settings(settings))
        self.journal = Journal(
            journal_path(self.data_dir),
            synchronous=settings.journal.synchronous,
            keep_snapshots=settings.journal.keep_snapshots,
        )
        self.snapshot_failures = 0  # snapshot saves that failed (metrics)
        self.retention = settings.journal.retention()
        self.belief = settings.belief_grid(self.geometry)
        self.version = 0
        self.clock = MapClock(
            settings.clock.max_lead_s, settings.clock.sim_ttl_s, settings.clock.max_sim_rate
        )
        self._restore()
        self.clock.resume(self.belief.stamp)
        static = settings.static_map()
        layers = [StaticLayer(static)] if static is not None else []
        inflation = InflationLayer(settings.build_inflation(), self.geometry)
        self.planning_bounds = (
            None
            if static is None
            else static_lower_bound(static, settings.build_inflation(), self.geometry)
        )  # costs the live costmap never goes below: for planners' cached heuristics
        self._lock = threading.Lock()
        self.follower = CostmapFollower(
            self.belief,
            settings.belief_grid(self.geometry),
            lambda mirror: [*layers, ObstacleLayer(mirror), inflation],
            self._lock,
            settings.reads.costmap_refresh_s,
            history=settings.journal.history,
            version=self.version,
        )
        self.gate = ScanGate(
            self.geometry,
            self.clock,
            self.journal.unit_stamps(),
            self.journal.find_scan,
            settings.limits.max_beams,
        )
        self._eager_costmap = settings.reads.costmap_refresh_s == 0
        self._queue: queue.Queue[_Submission | None] = queue.Queue()
        self._since_snapshot = 0
        self._last_snapshot_time = time.monotonic()
        j = settings.journal
        self._snapshots = SnapshotSchedule(
            j.snapshot_every_scans, j.snapshot_every_seconds, j.snapshot_max_share
        )
        self.snapshot_save_seconds = 0.0
        """[s] how long the last snapshot took to save, with its retention."""
        self._snapshotter: threading.Thread | None = None
        self.fusion_seconds = 0.0  # [s] total, for metrics
        self.stages = IngestStages()  # where submissions' time goes, for metrics
        self._closed = False
        self._fuse_queue: queue.Queue[_Journaled | None] = queue.Queue()
        self._worker = threading.Thread(target=self._ingest_loop, name="map-ingest", daemon=True)
        self._fuser = threading.Thread(target=self._fuse_loop, name="map-fuse", daemon=True)
        self._worker.start()
        self._fuser.start()

    # ---------------------------------------------------------------- lifecycle
    def _restore(self) -> None:
        """Newest usable snapshot + the journal after it. A damaged record (checksum,
        body, or a scan ``Scan.from_dict`` refuses) is quarantined and skipped. Every
        intact record is fused (the clock rule judged it when it arrived) but one whose
        stamp is ahead of the wall clock even now (journaled before the rule), which is
        quarantined and its unit's stamp bound reset. On an error that stops start-up
        the journal and the lock are released."""
        try:
            after = self._load_newest_snapshot()
            max_beams = self.settings.limits.max_beams
            not_after = time.time() + self.settings.clock.max_lead_s
            records = read_records(self.journal, after, max_beams=max_beams, not_after=not_after)
            for record in records:
                if record.scan is None:
                    self._quarantine(record.seq, record.unit_id, record.problem)
                    if record.ahead:  # the real unit may post at its own time again
                        self.journal.reset_unit_stamp(record.unit_id)
                    continue
                try:
                    self.belief.fuse(record.scan)
                except Exception as exc:  # changes nothing (see ``_fuse_apart``)
                    reason = clip(f"fusion failed: {type(exc).__name__}: {exc}")
                    self._quarantine(record.seq, record.unit_id, reason)
                    continue
                self.version = record.seq
        except BaseException:
            self.journal.close()
            self._lock_handle.close()
            raise

    def _load_newest_snapshot(self) -> int:
        """Load the newest usable snapshot into the belief; returns its seq (0: none, a
        full replay). An unusable one is logged and the next older one tried; one older
        than retention's cut (``deleted_through``) cannot be used. When retention deleted
        the first scans and no snapshot is usable, raises JournalError (no full replay)."""
        base = self.journal.deleted_through()
        seqs = [seq for seq in self.journal.snapshot_seqs() if seq >= base]
        for seq in reversed(seqs):
            try:
                load_snapshot_into(self.belief, self.journal.load_snapshot(seq))
            except (JournalError, ValueError) as exc:
                logger.error("snapshot at seq %d is unusable, trying an older one: %s", seq, exc)
                continue
            self.version = seq
            return seq
        if base > 0:
            raise JournalError(
                f"{self.journal.path}: no usable snapshot at or after seq {base} (kept: "
                f"{seqs or 'none'}), and retention deleted scans 1-{base}, so the map "
                "cannot be rebuilt by a full replay: `fleetmap journal check DATA_DIR` says "
                "what is damaged; start a new data dir (keep this one to inspect)"
            )
        if seqs:
            logger.error("no usable snapshot (seqs %s): replaying the whole journal", seqs)
        return 0

    def _quarantine(self, seq: int, unit_id: str, reason: str) -> None:
        """Move journal record ``seq`` to quarantine (never replayed again) and log it
        (a failure to move it is logged too: start-up then meets the record again)."""
        try:
            self.journal.quarantine(seq, reason)
        except Exception:
            logger.exception("journal seq %d (unit %s) could not be quarantined: %s",
                             seq, quote(unit_id), reason)  # fmt: skip
            return
        logger.error("journal seq %d (unit %s) quarantined: %s", seq, quote(unit_id), reason)

    def close(self) -> None:
        """Stop the ingest thread (after what is queued), close the journal, unlock."""
        if self._closed:
            return
        self._closed = True
        self._queue.put(None)
        self._worker.join()
        self._fuser.join()
        self.follower.close()
        if self._snapshotter is not None:
            self._snapshotter.join()
        self.journal.close()
        self._lock_handle.close()

    # -------------------------------------------------------------------- writes
    def submit(self, scans: list[Scan]) -> Future:
        """Queue validated scans (all or none); the future gives ``list[Ack]`` or raises
        IngestError. Only the scans' validated fields are journaled."""
        future: Future = Future()
        if self._closed:
            future.set_exception(IngestError(503, "the map server is shutting down"))
            return future
        self._queue.put(_Submission(scans, future))
        return future

    def ingest(self, scans: list[Scan]) -> list[Ack]:
        """Submit and wait (for callers without an event loop)."""
        return self.submit(scans).result()

    def _ingest_loop(self) -> None:
        """Stage 1 (thread ``map-ingest``): take what arrived as one group, check it and
        journal it, and hand it to the fusion thread; on close, tell that thread to stop."""
        try:
            while True:
                group, stop = self._next_group()
                if group:
                    try:
                        journaled = self._admit_and_journal(group, time.monotonic())
                    except Exception as exc:  # a bug: answer 500, never leave callers waiting
                        logger.exception("ingest failed")
                        _fail(group, exc)
                    else:
                        for part in journaled:
                            self._fuse_queue.put(part)
                if stop:
                    return
        finally:
            self._fuse_queue.put(None)

    def _next_group(self) -> tuple[list[_Submission], bool]:
        """The submissions waiting (at least one, at most MAX_GROUP scans) and whether
        close() asked to stop after them."""
        return take_waiting(self._queue, lambda sub: len(sub.scans))

    def _admit_and_journal(self, group: list[_Submission], taken: float) -> list[_Journaled]:
        """State checks per submission (``scan_gate``) and one journal transaction; the
        gate then holds the group's acks, so the next group is checked against it while
        this one fuses. Returns what the fusion thread fuses and answers, in order.
        taken: [s] monotonic, when the group was taken from the queue (``stages``).

        When the group's journal write fails, nothing of it was journaled and the gate
        forgets it; a group of several submissions is then checked and journaled again
        submission by submission (``_one_by_one``), so only the submissions whose own
        write fails are answered 503 and the others as if those had not been there. A
        refusal (409, 422) is answered only once the group is journaled, since a
        submission refused beside one that then failed may be accepted without it."""
        check = self.gate.open_group()
        outcomes = [(sub, check.admit(sub.scans)) for sub in group]
        try:
            acks = self._append(check.new)
        except Exception as exc:  # disk full, I/O error, a bug: nothing was journaled
            check.abandon()
            if len(group) > 1:
                return self._one_by_one(group, taken)
            self._journal_failed(group[0], exc)
            return []
        check.commit(acks)
        accepted: list[tuple[_Submission, list[UnitLatest]]] = []
        for sub, outcome in outcomes:
            if isinstance(outcome, IngestError):
                sub.future.set_exception(outcome)
            else:
                accepted.append((sub, outcome))
        return [_Journaled(accepted, check.new, acks, taken, time.monotonic())]

    def _one_by_one(self, group: list[_Submission], taken: float) -> list[_Journaled]:
        """``group`` checked and journaled a submission at a time, in order, each in a
        gate check of its own: a submission whose write fails is answered 503 and leaves
        no trace; the others go on (one journal transaction, one fsync, each)."""
        parts: list[_Journaled] = []
        for sub in group:
            check = self.gate.open_group()
            outcome = check.admit(sub.scans)
            if isinstance(outcome, IngestError):
                check.abandon()
                sub.future.set_exception(outcome)
                continue
            try:
                acks = self._append(check.new)
            except Exception as exc:
                check.abandon()
                self._journal_failed(sub, exc)
                continue
            check.commit(acks)
            parts.append(_Journaled([(sub, outcome)], check.new, acks, taken, time.monotonic()))
        return parts

    def _append(self, scans: list[Scan]) -> list[Ack]:
        """Journal ``scans`` in one transaction (durable when it returns); their acks,
        each with the map version that includes them all (the last seq)."""
        if not scans:
            return []
        seqs = self.journal.append([scan.journal_record() for scan in scans])
        return [Ack(seq, seqs[-1]) for seq in seqs]

    def _journal_failed(self, sub: _Submission, exc: Exception) -> None:
        """Answer ``sub`` 503 (nothing of it was journaled) and log its units and why
        (one template: the log's rate limit, ``lograte``, bounds a flood of them)."""
        reason = clip(f"{type(exc).__name__}: {exc}")
        logger.error("journal write failed for unit %s (%d scans): %s",
                     _units(sub.scans), len(sub.scans), reason)  # fmt: skip
        sub.future.set_exception(IngestError(503, f"journal write failed: {clip(str(exc))}"))

    def _fuse_loop(self) -> None:
        """Stage 2 (thread ``map-fuse``): fuse the journaled groups waiting, in order, as
        one kernel call (``_next_fusion``), then answer their submissions, so an ack's
        map version always includes its scan."""
        while True:
            batch, stop = self._next_fusion()
            if batch:
                try:
                    self._fuse(batch, time.monotonic())
                    self._snapshot_if_due()
                except Exception as exc:  # a bug: answer 500, never leave callers waiting
                    logger.exception("fusion failed")
                    _fail([sub for journaled in batch for sub, _ in journaled.accepted], exc)
            if stop:
                return

    def _next_fusion(self) -> tuple[list[_Journaled], bool]:
        """The journaled groups waiting (at least one, at most about MAX_GROUP scans) and
        whether the ingest thread has stopped after them."""
        return take_waiting(self._fuse_queue, lambda journaled: len(journaled.new))

    def _fuse(self, batch: list[_Journaled], taken: float) -> None:
        """Fuse the journaled groups' new scans in one kernel call (the costmap follows
        lazily) and answer them. When that fails, each group is fused submission by
        submission (``_fuse_apart``) and only the submissions that fail are answered with
        the error. taken: [s] monotonic, when this thread took the groups; their stage
        times are recorded (``stages``) before any of them is answered."""
        failed: list[dict[int, IngestError]] = [{} for _ in batch]  # per group: slot -> answer
        new = [scan for journaled in batch for scan in journaled.new]
        if new:
            with self._lock:
                t0 = time.perf_counter()
                try:
                    results = self.belief.fuse_many(new)
                except Exception:
                    logger.exception("fusing a group of %d scans failed: fusing them apart",
                                     len(new))  # fmt: skip
                    results = []
                    for k, journaled in enumerate(batch):
                        fused, failed[k] = self._fuse_apart(journaled)
                        results += fused
                self.version = max(j.acks[-1].map_version for j in batch if j.acks)
                self.follower.fused([r.box for r in results], self.version)
                self.fusion_seconds += time.perf_counter() - t0
                self._since_snapshot += len(new)
            if self._eager_costmap:  # refreshed before the acks (reads.costmap_refresh_s 0)
                self.follower.refresh()
        answered = time.monotonic()
        for journaled in batch:
            self.stages.record_group(
                [sub.submitted for sub, _ in journaled.accepted],
                journaled.taken,
                journaled.journaled,
                taken,
                answered,
                len(journaled.new),
            )
        for journaled, group_failed in zip(batch, failed, strict=True):
            for sub, entries in journaled.accepted:
                error = next(
                    (group_failed[e.slot] for e in entries if e.slot in group_failed), None
                )
                if error is not None:
                    sub.future.set_exception(error)
                else:
                    sub.future.set_result(GroupCheck.answers(entries, journaled.acks))

    def _fuse_apart(
        self, journaled: _Journaled
    ) -> tuple[list[FusionResult], dict[int, IngestError]]:
        """Fuse a group's new scans a submission at a time, in journal order (the lock
        held). A submission whose scans cannot be fused changes nothing (``fuse_many``
        builds its arguments before its kernel, which raises nothing), so it fails
        whole: its journal records are quarantined (never replayed) and logged, and the
        slots of its scans map to its answer, a 500. Returns the fused scans' results and
        those answers."""
        results: list[FusionResult] = []
        failed: dict[int, IngestError] = {}
        done = 0  # slots before this are fused or failed
        for _, entries in journaled.accepted:
            slots = [e.slot for e in entries if e.slot is not None and e.slot >= done]
            if not slots:
                continue
            own = range(done, max(slots) + 1)
            done = own.stop
            scans = journaled.new[own.start : own.stop]
            try:
                results += self.belief.fuse_many(scans)
            except Exception as exc:
                reason = clip(f"fusion failed: {type(exc).__name__}: {exc}")
                seqs = [journaled.acks[slot].seq for slot in own]
                for seq, scan in zip(seqs, scans, strict=True):
                    self._quarantine(seq, scan.unit_id, reason)
                error = IngestError(
                    500,
                    f"scan: the map could not fuse the scans of unit {_units(scans)} (a "
                    f"server fault, logged); set aside as journal seqs {seqs}, not in the "
                    f"map: {reason}",
                )
                failed.update(dict.fromkeys(own, error))
        return results, failed

    def _snapshot_if_due(self) -> None:
        """Start a snapshot on a background thread when one is due, at most one at a
        time: it copies the belief's mirror (``follower``), not the live belief, so
        fusion goes on meanwhile."""
        due = self._snapshots.due(
            self._since_snapshot,
            time.monotonic() - self._last_snapshot_time,
            self.snapshot_save_seconds,
        )
        if due and not (self._snapshotter and self._snapshotter.is_alive()):
            self._snapshot_started()
            saver = threading.Thread(
                target=lambda: self._save_snapshot(*self._take_snapshot()),
                name="map-snapshot",
                daemon=True,
            )
            saver.start()  # before it is published: snapshot() may join it at once
            self._snapshotter = saver

    def snapshot(self) -> int:
        """Save a snapshot of the belief now (waiting for it); returns its seq."""
        if self._snapshotter is not None:
            self._snapshotter.join()
        self._snapshot_started()
        taken = self._take_snapshot()
        self._save_snapshot(*taken)
        return taken[0]

    def _snapshot_started(self) -> None:
        """Restart the snapshot schedule's counts (``SnapshotSchedule``)."""
        with self._lock:
            self._since_snapshot = 0
        self._last_snapshot_time = time.monotonic()

    def _take_snapshot(self) -> tuple[int, float, dict[str, np.ndarray]]:
        """The belief's state at the latest scan fused: (its version, stamp [s], arrays
        with ``scans_fused``), copied from the mirror."""
        with self.follower.mirror_current() as now:
            arrays = {**now.belief.state_arrays(), "scans_fused": np.array(now.belief.scans_fused)}
            return now.version, now.belief.stamp, arrays

    def _save_snapshot(self, seq: int, stamp: float, arrays: dict[str, np.ndarray]) -> None:
        """Save a snapshot, then apply retention (off the ingest path: this runs on the
        snapshot thread, and retention deletes in short transactions)."""
        retention = self.retention.enabled
        started = time.monotonic()
        try:
            self.journal.save_snapshot(seq, stamp, seq, arrays, prune=not retention)
        except Exception:  # the journal still holds every scan: start-up replays more
            self.snapshot_failures += 1
            logger.exception("snapshot at seq %d failed", seq)
            return
        finally:
            self.snapshot_save_seconds = time.monotonic() - started
        if retention:
            try:
                apply_retention(self.journal, self.retention)
            except Exception:  # nothing acknowledged is lost: the next save retries
                logger.exception("journal retention after the snapshot at seq %d failed", seq)
            self.snapshot_save_seconds = time.monotonic() - started

    # --------------------------------------------------------------------- reads
    @property
    def stamp(self) -> float:
        """The map's "now" [s]: the latest scan stamp (None-like -inf before any scan)."""
        return self.belief.stamp

    def meta(self) -> dict[str, Any]:
        """docs/http-api.md 2.2 map metadata."""
        g, s = self.geometry, self.settings
        with self._lock:
            version, stamp = self.version, self.belief.stamp
        return {
            "resolution": g.resolution,
            "width": g.width,
            "height": g.height,
            "origin": {"x": g.origin_x, "y": g.origin_y, "yaw": 0.0},
            "frame": "map",
            "stamp": stamp if math.isfinite(stamp) else None,
            "version": version,
            "policy": s.policy.value,
            "sensor_model": s.sensor_model.model_dump(),
            "decay": s.decay.model_dump(),
            "inflation": s.inflation.model_dump(),
            "thresholds": {
                "occupied": s.sensor_model.occupied_threshold,
                "free": s.sensor_model.free_threshold,
            },
        }

    @property
    def costmap(self) -> LayeredCostmap:
        """The layered costmap (``follower``; it may lag the belief until a read)."""
        return self.follower.costmap

    def costmap_read(self, at: float | None = None) -> GridRead:
        """The costmap at ``at`` [s] (default: the map's stamp), copied at one version."""
        with self.follower.costmap_current() as now:
            if at is None or at == now.costmap.stamp:
                return GridRead(now.costmap.costs.copy(), now.version, now.costmap.stamp)
            layers = self._frozen_layers(self._belief_copy(now.belief))
            version = now.version
        return GridRead(self._build(layers, at), version, at)

    def occupancy_read(self, at: float | None = None) -> GridRead:
        """OccupancyGrid int8 values (-1 unknown, 0..100) at ``at`` [s]."""
        with self.follower.mirror_current() as now:
            belief = self._belief_copy(now.belief)
            version = now.version
        when = belief.stamp if at is None else at
        return GridRead(occupancy_percent(belief.probability_at(when)), version, when)

    def age_read(self, at: float | None = None) -> GridRead:
        """Evidence age [s] per cell (float32) at ``at`` [s] (default: the map's stamp):
        ``at - last_observed``, NaN where never observed, negative for evidence newer
        than ``at``."""
        with self.follower.mirror_current() as now, np.errstate(over="ignore"):
            ages = now.belief.age_at(at).astype(np.float32)  # beyond float32: +-inf
            version, stamp = now.version, now.belief.stamp
        return GridRead(ages, version, stamp if at is None else at)

    def updates_since(self, version: int) -> tuple[int, float, list[Patch] | None]:
        """(current version, its stamp [s], patches since ``version`` or None when a full
        read is due)."""
        with self.follower.costmap_current() as now:
            return now.version, now.costmap.stamp, now.costmap.patches_since(version)

    def cell_columns(self, points: Any, at: float | None = None) -> dict[str, list]:
        """docs/http-api.md 2.4 reports of ``points`` [(x, y) m, a list or an (N, 2) array] at
        ``at`` [s] (default: the map's stamp), as columns (``queries.cell_columns``)."""
        return cell_columns(*self._cell_samples(points, at))

    def _cell_samples(self, points: Any, at: float | None) -> tuple[CellSamples, float]:
        """The points' values and the stamp [s] they are read at. The lock is held only to
        gather them (or, at another stamp, to copy the belief): costmaps at other stamps
        are built outside it."""
        with self.follower.costmap_current() as now:
            when = now.belief.stamp if at is None else at
            current = at is None or at == now.costmap.stamp
            if current:
                samples = sample_cells(now.belief, now.costmap.costs, points, when)
            else:
                belief = self._belief_copy(now.belief)
                layers = self._frozen_layers(belief)
        if not current:
            samples = sample_cells(belief, self._build(layers, at), points, when)
        return samples, when

    def segments(self, segments: list[list[float]]) -> list[SegmentReport]:
        """docs/http-api.md 2.5 reports on the current costmap, copied under the lock."""
        with self.follower.costmap_current() as now:
            costs = now.costmap.costs.copy()
        return query_segments(self.geometry, costs, segments)

    def journal_bytes(self) -> int:
        return self.journal.size_bytes()

    def _belief_copy(self, source: BeliefGrid) -> BeliefGrid:
        """A copy of ``source`` (the follower's mirror, its lock held)."""
        copy = self.settings.belief_grid(self.geometry)
        copy.copy_state_from(source)
        return copy

    def _frozen_layers(self, belief: BeliefGrid) -> list:
        """Fresh layers over ``belief`` (a copy), for reads at another stamp."""
        return [
            ObstacleLayer(belief) if isinstance(layer, ObstacleLayer) else layer.fresh()
            for layer in self.costmap.layers
        ]

    def _build(self, layers: list, at: float) -> np.ndarray:
        """A from-scratch costmap of ``layers`` at ``at`` [s]."""
        return LayeredCostmap(self.geometry, layers, history=1, stamp=at).costs


def _map_settings(settings: Settings) -> dict[str, Any]:
    """What a journal's scans mean: replaying them under other values gives another map."""
    g = settings.geometry()
    return {
        "grid": {
            "width": g.width,
            "height": g.height,
            "resolution": g.resolution,
            "origin_x": g.origin_x,
            "origin_y": g.origin_y,
        },
        "sensor_model": settings.sensor_model.model_dump(),
        "policy": settings.policy.value,
        "decay": settings.decay.model_dump(),
        "max_clearing_range": settings.max_clearing_range,
    }


def _check_map_settings(data_dir: Path, current: dict[str, Any]) -> None:
    """Record the map settings in a new data dir; refuse a dir written with others."""
    path = data_dir / MAP_SETTINGS_FILE
    if not path.exists():
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(current, indent=2))
        tmp.replace(path)
        return
    recorded = read_map_settings(data_dir)
    if recorded != current:
        diff = sorted(k for k in current if recorded.get(k) != current[k])
        raise DataDirError(
            f"data_dir {data_dir} holds a journal made with other map settings "
            f"({', '.join(diff)} differ; see {path}): use another data_dir or those settings"
        )


def read_map_settings(data_dir: Path) -> dict[str, Any]:
    """The map settings recorded in a data dir (for ``fleetmap replay``).

    A data dir written before a sensor-model field existed records no value for it: the
    value its journal was fused under is filled in (``fill_legacy_sensor_model``: e.g.
    before no-return beams had their own evidence, docs/no-return.md, they were as strong
    as returns, ``p_miss``, out to range_max), so such a dir opens under those settings,
    not the new defaults.
    """
    recorded = json.loads((Path(data_dir) / MAP_SETTINGS_FILE).read_text())
    model = recorded.get("sensor_model")
    if isinstance(model, dict):
        fill_legacy_sensor_model(model)
    return recorded


def _lock_data_dir(data_dir: Path) -> FileLocks:
    """An exclusive lock on the data dir for this process's lifetime (one writer): on
    ``server.lock`` and on the journal file itself, so deleting ``server.lock`` does not
    let a second server in (``mapserver.store.datadir_lock``)."""
    try:
        return FileLocks([data_dir / LOCK_FILE, journal_path(data_dir)])
    except LockBusy as exc:
        raise DataDirError(
            f"data_dir {data_dir} is in use by another map server or a `fleetmap journal` "
            f"command ({exc.path.name} is locked)"
        ) from None
