"""Bounded storage: retention of the journal behind its snapshots, the file's size under
retention, float32 rows and schema-3 journals, drop/salvage/replay from the oldest kept
snapshot, quarantine bounded and the indexed same-stamp lookup."""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from server_helpers import ServerProcess, scan_body, small_settings
from test_journal_faults import noisy_ranges, sql

from mapserver.core.scan import Scan
from mapserver.core.sensor_model import DEFAULT_POLICY
from mapserver.service.map_service import MapService, _check_map_settings, _map_settings
from mapserver.service.replay import ReplayError, replay_journal
from mapserver.store import journal as journal_module
from mapserver.store.journal import (
    SCHEMA_VERSION,
    Journal,
    JournalError,
    SnapshotInfo,
    journal_path,
    record_checksum,
)
from mapserver.store.retention import (
    ANCHORS,
    RetentionPolicy,
    apply_retention,
    plan_retention,
)
from scenarios.cli.main import main

SNAP = {"log_odds": np.zeros((2, 2), np.float32), "scans_fused": np.array(0)}


def body(i: int, unit: str = "u1", beams: int = 200) -> dict:
    """A scan that changes the map and whose ranges do not compress to nothing."""
    x = 2.0 + (i % 30) * 0.5
    return scan_body(stamp=float(i), unit=unit, x=x, y=5.0, ranges=noisy_ranges(i, beams))


def validated(i: int, unit: str = "u1") -> dict:
    """``body(i)`` as the server journals it (ranges rounded by ``Scan.from_dict``)."""
    return Scan.from_dict(body(i, unit)).journal_record()


def retaining(data: Path, policy: str = DEFAULT_POLICY.value, **journal) -> MapService:
    # a snapshot every 25 scans however quick the saves (no share rule): the cuts below
    # count on them
    settings = {
        "snapshot_every_scans": 25,
        "snapshot_max_share": 1.0,
        "retain_seconds": None,
        **journal,
    }
    return MapService(small_settings(data, journal=settings, policy=policy))


def belief_arrays(service_or_belief) -> dict[str, bytes]:
    """Every state array of the belief (the dual policy's history too), as bytes."""
    belief = getattr(service_or_belief, "belief", service_or_belief)
    return {name: array.tobytes() for name, array in belief.state_arrays().items()}


# ------------------------------------------------------------------------ planning
def infos(*pairs: tuple[int, float]) -> list[SnapshotInfo]:
    return [SnapshotInfo(seq, at, 100) for seq, at in pairs]


def test_the_cut_is_the_newest_snapshot_past_the_age_limit_and_anchors_are_thinned() -> None:
    snaps = infos(*[(100 * k, 1000.0 + 10 * k) for k in range(1, 21)])  # seq 100..2000
    policy = RetentionPolicy(retain_seconds=100.0, keep_snapshots=2)
    plan = plan_retention(snaps, 2000, 0, 10_000, now=1200.0, policy=policy)
    assert plan.cut == 1000  # saved at 1100 <= 1200 - 100; seq 1100 saved at 1110 is not
    kept = sorted({s.seq for s in snaps} - set(plan.drop_snapshots))
    # buckets of 100 / ANCHORS = 25 s: the first saved in [1125, 1150), [1150, 1175),
    # [1175, 1200), the anchor (bucket [1100, 1125)) and the newest two
    assert ANCHORS == 4 and kept == [1000, 1300, 1500, 1800, 1900, 2000]
    # none past retention: nothing deleted, the spread snapshots stay as future anchors
    young = plan_retention(snaps, 2000, 0, 10_000, now=1050.0, policy=policy)
    assert young.cut == 0 and 1900 not in young.drop_snapshots


def test_future_anchors_stay_kept_so_the_scans_held_stop_at_the_bound() -> None:
    """A steady stream: a snapshot every 10 s (100 scans), retention 300 s, planned after
    each save. An anchor once kept is kept until the cut passes it, and the scans held
    never exceed (1 + 1 / ANCHORS) x the retention plus one snapshot interval."""
    policy = RetentionPolicy(retain_seconds=300.0, keep_snapshots=2)
    stored: list[SnapshotInfo] = []
    deleted_through, held_max, anchors = 0, 0, set()
    for k in range(1, 400):
        now, last_seq = 10.0 * k + 0.5, 100 * k
        stored.append(SnapshotInfo(last_seq, 10.0 * k, 100))
        plan = plan_retention(stored, last_seq, deleted_through, 0, now, policy)
        deleted_through = max(deleted_through, plan.cut)
        stored = [s for s in stored if s.seq not in plan.drop_snapshots]
        kept = {s.seq for s in stored}
        assert {a for a in anchors if a >= deleted_through} <= kept
        anchors = kept - {s.seq for s in stored[-2:]}  # not only the newest two
        if k > 60:  # past the first retention period
            held_max = max(held_max, last_seq - deleted_through)
    assert held_max <= 100 * (300 / 10) * (1 + 1 / ANCHORS) + 100


def test_the_size_limit_cuts_to_the_snapshot_that_keeps_it_and_no_limit_deletes_no_scan() -> None:
    snaps = infos((1000, 0.0), (2000, 0.0), (3000, 0.0), (4000, 0.0))
    by_size = RetentionPolicy(retain_bytes=2_000_400, keep_snapshots=1)
    # 4000 scans in 4,000,400 bytes with 400 of snapshots: 1000 bytes a scan, 2000 kept
    assert plan_retention(snaps, 4000, 0, 4_000_400, 0.0, by_size).cut == 2000
    assert plan_retention(snaps, 4000, 0, 1_000_000, 0.0, by_size).cut == 0
    cap_only = RetentionPolicy(quarantine_max_rows=5, keep_snapshots=2)
    plan = plan_retention(snaps, 4000, 0, 4_000_400, 0.0, cap_only)
    assert plan.cut == 0 and plan.drop_snapshots == (1000, 2000)


# ------------------------------------------------------------------- the journal
def test_retention_cuts_scans_snapshots_quarantine_and_units(tmp_path: Path) -> None:
    with Journal(tmp_path / "j.sqlite3") as journal:
        journal.append([validated(i, "gone") for i in range(10)])  # a one-shot unit
        journal.append([validated(i) for i in range(10, 50)])
        journal.quarantine(5, "test")
        for seq in (20, 40, 45):
            journal.save_snapshot(seq, float(seq), seq, SNAP, prune=False)
        journal.append([validated(i) for i in range(50, 60)])
        policy = RetentionPolicy(retain_seconds=60.0, keep_snapshots=1)
        assert apply_retention(journal, policy).scans == 0  # every snapshot is young
        report = apply_retention(journal, policy, now=time.time() + 61)
        assert report.deleted_through == 45 and report.scans == 44  # seq 5 was quarantined
        assert [seq for seq, _ in journal.scans_after(0)] == list(range(46, 61))
        assert journal.snapshot_seqs() == [45]
        assert journal.quarantined_rows() == [] and journal.quarantined == 0
        assert "gone" not in journal.unit_stamps() and journal.unit_stamps()["u1"] == 59.0


def test_the_file_stops_growing_once_retention_is_reached(tmp_path: Path) -> None:
    """Freed pages are reused: the page count is flat from the first cut on."""
    policy = RetentionPolicy(retain_bytes=400_000, keep_snapshots=1)
    pages: list[int] = []
    with Journal(tmp_path / "j.sqlite3") as journal:
        for k in range(40):
            journal.append([validated(100 * k + i) for i in range(100)])
            journal.save_snapshot(journal.last_seq(), float(k), k, SNAP, prune=False)
            apply_retention(journal, policy)
            pages.append(journal.page_stats()[0])
        count, free, size = journal.page_stats()
        assert journal.deleted_through() > 3000
        assert (count - free) * size <= 400_000 * (1 + 1 / ANCHORS) + 100 * 1200
    first_cut = next(k for k in range(40) if pages[k] == max(pages[: k + 1]) and k > 5)
    assert max(pages[first_cut + 5 :]) <= max(pages[: first_cut + 5])  # flat, not growing
    assert pages[-1] * size < 2 * 400_000  # and near the limit, not the history (~4 MB)


# -------------------------------------------------------- restart, replay, kill -9
@pytest.mark.parametrize("policy", ["decay", "dual"])
def test_restart_equals_a_replay_from_the_oldest_kept_snapshot(tmp_path: Path, policy) -> None:
    data = tmp_path / "data"
    # snapshots of 10-17 kB (zstd) + ~100 scans of ~870 B
    service = retaining(data, policy, retain_bytes=150_000)
    try:
        for i in range(400):
            service.ingest([Scan.from_dict(body(i, f"u{i % 3}"))])
        service.snapshot()
    finally:
        service.close()
    with Journal(journal_path(data), readonly=True) as journal:
        base, seqs = journal.deleted_through(), journal.snapshot_seqs()
    assert base > 100 and len(seqs) >= 2 and seqs[0] == base
    belief, scans, skipped = replay_journal(data)
    assert skipped == [] and belief.scans_fused == base
    for scan in scans:
        belief.fuse(scan)
    restarted = MapService(small_settings(data, journal={"retain_seconds": None}, policy=policy))
    try:
        assert restarted.belief.state_names == belief.state_names
        assert restarted.version == 400
        assert belief_arrays(restarted) == belief_arrays(belief)
    finally:
        restarted.close()
    with pytest.raises(ReplayError, match="before the oldest kept snapshot"):
        replay_journal(data, until=1.0)


def test_without_a_usable_snapshot_a_cut_journal_refuses_to_start(tmp_path: Path) -> None:
    data = tmp_path / "data"
    service = retaining(data, retain_bytes=60_000)
    try:
        for i in range(200):
            service.ingest([Scan.from_dict(body(i))])
    finally:
        service.close()
    sql(data, "UPDATE snapshots SET checksum = checksum + 1")
    with pytest.raises(JournalError, match=r"retention deleted scans 1-\d+.*full replay"):
        MapService(small_settings(data))
    with pytest.raises(ReplayError, match="only possible while nothing was deleted"):
        replay_journal(data)
    assert main(["journal", "check", str(data)]) == 1


def deleted_through(data: Path) -> int:
    """Retention's mark in a live server's journal (a read-only look)."""
    with Journal(journal_path(data), readonly=True) as journal:
        return journal.deleted_through()


def test_kill_9_during_retention_loses_no_acknowledged_scan_inside_retention(
    tmp_path: Path,
) -> None:
    """A real server cutting its journal every 10 scans, killed twice mid-run."""
    data, config = tmp_path / "data", tmp_path / "server.yaml"
    retain = 0.5  # [s]
    config.write_text(
        f"journal: {{snapshot_every_scans: 10, snapshot_max_share: 1.0, "
        f"retain_seconds: {retain}, retain_bytes: null}}\n"
    )
    sent: list[tuple[float, int, float]] = []  # (wall time sent, seq acknowledged, stamp)
    stamp = 0.0
    base = 0
    for run in range(2):
        server = ServerProcess(data, config=config, grid=(200, 100))
        try:
            # past the first cuts of this run (up to 20 s on a loaded machine), then on
            # for a varied while: killed at varied moments of deleting
            until, deadline = time.monotonic() + 0.3 * run, time.monotonic() + 20
            while (time.monotonic() < until or deleted_through(data) <= base) and (
                time.monotonic() < deadline
            ):
                stamp += 1.0
                t_sent = time.time()
                reply = httpx.post(server.url + "/v1/scans", json=body(int(stamp)), timeout=10)
                reply.raise_for_status()
                sent.append((t_sent, reply.json()["seq"], stamp))
        finally:
            killed_at = time.time()
            server.kill()
        with Journal(journal_path(data), readonly=True) as journal:
            held = {seq for seq, _ in journal.scans_after(0)}
            base = journal.deleted_through()
        inside = [seq for t, seq, _ in sent if t > killed_at - retain]
        assert inside and set(inside) <= held  # every acknowledged scan inside retention
        assert base > 0 and base < min(inside)  # retention did delete while it ran
    server = ServerProcess(data, config=config, grid=(200, 100))
    try:
        meta = httpx.get(server.url + "/v1/map/meta", timeout=10).json()
        assert meta["version"] == sent[-1][1]
    finally:
        server.stop()


# ------------------------------------------------------------- float32, schema 3
def float64_scans() -> list[dict]:
    """Scans whose first beam ends a hair before a cell edge (x = 5.0 m) in float64 and on
    it in float32: rounding the ranges changes the map."""
    return [
        scan_body(stamp=float(i), x=3.0, angle_min=0.0, ranges=[2.0 - 1e-12 * (1 + i)] * 200)
        for i in range(6)
    ]


def make_v3_journal(path: Path, scans: list[dict]) -> None:
    """A journal as schema version 3 wrote it: float64 ranges, no format, no index."""
    conn = sqlite3.connect(path)
    for script in (journal_module._SCHEMA, journal_module._SCHEMA_V3):
        for statement in script.split(";"):
            if statement.strip():
                conn.execute(statement)
    for scan in scans:
        header = json.dumps({k: v for k, v in scan.items() if k != "ranges"}, separators=(",", ":"))
        ranges = np.asarray(scan["ranges"], dtype="<f8").tobytes()
        checksum = record_checksum(scan["unit_id"].encode(), scan["stamp"], header.encode(), ranges)
        conn.execute(
            "INSERT INTO scans (unit_id, stamp, body, ranges, checksum) VALUES (?, ?, ?, ?, ?)",
            (scan["unit_id"], scan["stamp"], header, ranges, checksum),
        )
        conn.execute("INSERT OR REPLACE INTO units VALUES (?, ?)", (scan["unit_id"], scan["stamp"]))
    conn.execute(f"PRAGMA application_id = {journal_module.APPLICATION_ID}")
    conn.execute("PRAGMA user_version = 3")
    conn.commit()
    conn.close()


def test_a_schema_3_journal_migrates_and_replays_its_float64_map(tmp_path: Path) -> None:
    data = tmp_path / "data"
    data.mkdir()
    scans = float64_scans()
    old = small_settings(data).belief_grid()
    rounded = small_settings(data).belief_grid()
    for scan in scans:
        old.fuse(Scan.from_dict(scan, float32_ranges=False))
        rounded.fuse(Scan.from_dict(scan))
    assert belief_arrays(old) != belief_arrays(rounded)  # so the test can tell
    make_v3_journal(journal_path(data), scans)
    _check_map_settings(data, _map_settings(small_settings(data)))  # as the old server did
    with Journal(journal_path(data), readonly=True) as journal:
        assert journal.schema_version == 3  # read as it is, not migrated
    belief, replayed, _ = replay_journal(data)
    for scan in replayed:
        belief.fuse(scan)
    assert belief_arrays(belief) == belief_arrays(old)
    service = MapService(small_settings(data))
    try:
        assert belief_arrays(service) == belief_arrays(old)
        service.ingest([Scan.from_dict(body(6))])  # new rows: float32, format 1
    finally:
        service.close()
    assert sql(data, "PRAGMA user_version") == [(SCHEMA_VERSION,)]
    assert sql(data, "SELECT format, count(*) FROM scans GROUP BY format") == [(None, 6), (1, 1)]
    assert main(["journal", "check", str(data)]) == 0


def test_live_fusion_fuses_the_float32_values_the_journal_stores(tmp_path: Path) -> None:
    data = tmp_path / "data"
    scans = float64_scans()
    service = MapService(small_settings(data))
    try:
        for scan in scans:
            service.ingest([Scan.from_dict(scan)])
        live = belief_arrays(service)
    finally:
        service.close()
    restarted = MapService(small_settings(data))
    try:
        assert belief_arrays(restarted) == live
        stored = restarted.journal.find_scan("u1", 3.0)[1]["ranges"][0]
        assert stored == 2.0 == float(np.float32(scans[3]["ranges"][0]))
    finally:
        restarted.close()


# --------------------------------------------------------------- drop and salvage
def cut_data_dir(tmp_path: Path, scans: int = 300) -> Path:
    data = tmp_path / "data"
    service = retaining(data, retain_bytes=150_000)
    try:
        for i in range(scans):
            service.ingest([Scan.from_dict(body(i, f"u{i % 3}"))])
    finally:
        service.close()
    return data


def test_drop_keeps_older_snapshots_and_refuses_when_it_cannot_rebuild(tmp_path, capsys) -> None:
    data = cut_data_dir(tmp_path)
    with Journal(journal_path(data), readonly=True) as journal:
        base, seqs, last = journal.deleted_through(), journal.snapshot_seqs(), journal.last_seq()
    assert base > 0 and seqs[0] == base
    # u1's scans from just after the oldest kept snapshot: that one stays, the others go
    after = float(base)  # stamps equal seq - 1 here
    assert main(["journal", "drop", str(data), "--unit", "u1", "--after", str(after)]) == 0
    assert sql(data, "SELECT seq FROM snapshots") == [(base,)]
    assert "kept 1 older ones" in capsys.readouterr().out
    dropped = len(sql(data, "SELECT seq FROM quarantine"))
    assert dropped > 10
    service = MapService(small_settings(data))
    try:  # rebuilt from seq `base` without u1's dropped scans
        assert service.version == last and service.belief.scans_fused == last - dropped
    finally:
        service.close()
    # the oldest kept snapshot damaged: u2's drop would leave nothing to rebuild from
    sql(data, "UPDATE snapshots SET checksum = checksum + 1 WHERE seq = ?", (base,))
    before = sql(data, "SELECT count(*) FROM quarantine")
    assert main(["journal", "drop", str(data), "--unit", "u2", "--after", str(base - 5.0)]) == 1
    err = capsys.readouterr().err
    assert f"retention deleted scans 1-{base}" in err and "no usable snapshot older" in err
    assert sql(data, "SELECT count(*) FROM quarantine") == before


def test_salvage_copies_the_snapshots_so_a_cut_journal_still_rebuilds(tmp_path, capsys) -> None:
    data = cut_data_dir(tmp_path)
    original = MapService(small_settings(data))
    expected = belief_arrays(original)
    original.close()
    out = tmp_path / "saved"
    assert main(["journal", "salvage", str(data), "--out", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    kept = [seq for (seq,) in sql(data, "SELECT seq FROM snapshots ORDER BY seq")]
    assert report["snapshots"] == kept and len(kept) >= 2
    assert main(["journal", "check", str(out)]) == 0
    salvaged = MapService(small_settings(out))
    try:
        assert belief_arrays(salvaged) == expected
    finally:
        salvaged.close()


# -------------------------------------------------------- quarantine and the index
def test_quarantine_is_capped_to_its_newest_rows(tmp_path: Path) -> None:
    with Journal(tmp_path / "j.sqlite3") as journal:
        journal.append([validated(i) for i in range(30)])
        for seq in range(1, 21):
            journal.quarantine(seq, "test")
        apply_retention(journal, RetentionPolicy(quarantine_max_rows=5))
        assert [row[0] for row in journal.quarantined_rows()] == [16, 17, 18, 19, 20]
        assert journal.quarantined == 5
        assert journal.last_seq() == 30 and journal.deleted_through() == 0  # no scan deleted


def test_find_scan_uses_the_index_and_finds_what_a_table_scan_finds(tmp_path: Path) -> None:
    with Journal(tmp_path / "j.sqlite3") as journal:
        journal.append([validated(i % 7, f"u{i % 5}") for i in range(60)])
        plan = journal._read(
            "EXPLAIN QUERY PLAN SELECT seq FROM scans WHERE unit_id = ? AND stamp = ? "
            "ORDER BY seq DESC LIMIT 1",
            ("u1", 3.0),
        )
        assert "scans_unit_stamp" in " ".join(str(row) for row in plan)
        for unit in ("u0", "u1", "u4", "nobody"):
            for stamp in (0.0, 3.0, 6.0, 9.0):
                found = journal.find_scan(unit, stamp)
                brute = [
                    (seq, scan)
                    for seq, scan in journal.scans_after(0)
                    if scan["unit_id"] == unit and scan["stamp"] == stamp
                ]
                assert found == (brute[-1] if brute else None)


def test_retention_on_another_thread_does_not_stop_appends(tmp_path: Path) -> None:
    """Deletion runs in short transactions: appends go on while it works."""
    with Journal(tmp_path / "j.sqlite3") as journal:
        journal.append([validated(i) for i in range(3000)])
        journal.save_snapshot(3000, 1.0, 1, SNAP, prune=False)
        worker = threading.Thread(
            target=apply_retention,
            args=(journal, RetentionPolicy(retain_seconds=0.0, keep_snapshots=1)),
        )
        worker.start()
        appended = 0
        while worker.is_alive():
            journal.append([validated(5000 + appended)])
            appended += 1
        worker.join()
        assert journal.deleted_through() == 3000
        assert [s for s, _ in journal.scans_after(0)] == list(range(3001, 3001 + appended))
