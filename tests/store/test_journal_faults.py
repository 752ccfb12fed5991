"""Storage faults of the map server's journal: checksums, quarantine, snapshot fallback,
the v2 migration, the data-dir lock and ``fleetmap journal check|salvage|drop``."""

from __future__ import annotations

import json
import logging
import sqlite3
from pathlib import Path

import httpx
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from prometheus_client import generate_latest
from server_helpers import ServerProcess, scan_body, small_settings

from mapserver.api.metrics import ServerMetrics
from mapserver.core.scan import Scan
from mapserver.service.map_service import LOCK_FILE, DataDirError, MapService
from mapserver.store import journal as journal_module
from mapserver.store.journal import (
    SCHEMA_VERSION,
    Journal,
    JournalError,
    RawRow,
    decode_row,
    encode_arrays,
    journal_path,
    record_checksum,
    snapshot_checksum,
)
from scenarios.cli.main import main

N_SCANS = 12


def bodies(n: int = N_SCANS, unit: str = "u1") -> list[dict]:
    """Scans that each change the map (the sensor moves along the grid)."""
    return [scan_body(stamp=float(i), unit=unit, x=3.0 + 0.5 * i, y=5.0) for i in range(n)]


def noisy_ranges(seed: int, beams: int = 200) -> list[float]:
    """Float32 ranges [m] that zlib cannot squeeze (rows of a realistic size)."""
    return np.random.default_rng(seed).uniform(1.0, 15.0, beams).astype(np.float32).tolist()


def serve_and_close(data: Path, scans: list[dict], snapshot_at: tuple[int, ...] = ()) -> None:
    """Ingest ``scans`` one by one into a MapService on ``data``, snapshotting after the
    given counts, and close it."""
    service = MapService(small_settings(data))
    try:
        for i, body in enumerate(scans, start=1):
            service.ingest([Scan.from_dict(body)])
            if i in snapshot_at:
                service.snapshot()
    finally:
        service.close()


def fused(data: Path, scans: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """(log-odds, last observed) of a fresh belief fused from ``scans`` in order."""
    belief = small_settings(data).belief_grid()
    for body in scans:
        belief.fuse(Scan.from_dict(body))
    return belief.raw_log_odds().copy(), belief.last_observed().copy()


def assert_same_belief(service: MapService, expected: tuple[np.ndarray, np.ndarray]) -> None:
    """Byte for byte equal belief arrays (NaN where never observed included)."""
    assert service.belief.raw_log_odds().tobytes() == expected[0].tobytes()
    assert service.belief.last_observed().tobytes() == expected[1].tobytes()


def assert_restart_rebuilds(data: Path, scans: list[dict]) -> MapService:
    """A MapService started on ``data`` holds the belief fused from ``scans``, byte for
    byte; returns it closed (its counters stay readable)."""
    service = MapService(small_settings(data))
    try:
        assert_same_belief(service, fused(data, scans))
        assert service.belief.scans_fused == len(scans)
    finally:
        service.close()
    return service


def sql(data: Path, statement: str, params: tuple = ()) -> list[tuple]:
    """Run one statement on the journal with plain sqlite3 (a fault from outside)."""
    conn = sqlite3.connect(journal_path(data))
    try:
        with conn:
            return conn.execute(statement, params).fetchall()
    finally:
        conn.close()


def flip_byte(data: Path, seq: int, column: str, offset: int) -> bytes:
    """Flip one bit in byte ``offset`` (modulo the value's length: ranges are stored
    compressed, a few bytes for a uniform scan) of scan ``seq``'s ``column``; returns the
    new bytes."""
    (value,) = sql(data, f"SELECT CAST({column} AS BLOB) FROM scans WHERE seq = ?", (seq,))[0]
    damaged = bytearray(value)
    damaged[offset % len(damaged)] ^= 0x10
    kind = "TEXT" if column in ("body", "unit_id") else "BLOB"
    sql(data, f"UPDATE scans SET {column} = CAST(? AS {kind}) WHERE seq = ?", (bytes(damaged), seq))
    return bytes(damaged)


def metric(service: MapService, name: str) -> float:
    text = generate_latest(ServerMetrics(service).registry).decode()
    (line,) = [row for row in text.splitlines() if row.startswith(name + " ")]
    return float(line.split()[1])


# ------------------------------------------------------------------ checksums
@settings(max_examples=200, deadline=None)
@given(st.data())
def test_any_flipped_byte_of_a_record_fails_its_checksum(data) -> None:
    body = json.dumps({k: v for k, v in scan_body().items() if k != "ranges"}).encode()
    ranges = np.linspace(0.5, 9.5, 40).astype("<f8").tobytes()
    fields = {"unit_id": b"u1", "body": body, "ranges": ranges}
    intact = RawRow(7, b"u1", 2.5, body, ranges, record_checksum(b"u1", 2.5, body, ranges))
    assert decode_row(intact).checksum_ok is True
    name = data.draw(st.sampled_from(sorted(fields)))
    offset = data.draw(st.integers(0, len(fields[name]) - 1))
    mask = data.draw(st.integers(1, 255))
    damaged = bytearray(fields[name])
    damaged[offset] ^= mask
    row = RawRow(**{**intact.__dict__, name: bytes(damaged)})
    record = decode_row(row)
    assert record.checksum_ok is False and record.scan is None
    assert record.problem.startswith("checksum mismatch")


def test_a_stamp_changed_in_place_fails_the_checksum(tmp_path: Path) -> None:
    with Journal(journal_path(tmp_path)) as journal:
        journal.append(bodies(3))
    sql(tmp_path, "UPDATE scans SET stamp = 1.5 WHERE seq = 2")
    with Journal(journal_path(tmp_path), readonly=True) as journal:
        assert [r.checksum_ok for r in journal.records_after(0)] == [True, False, True]


@pytest.mark.parametrize(("column", "offset"), [("body", 30), ("ranges", 801)])
def test_a_flipped_byte_is_reported_for_that_record_only(tmp_path, column, offset) -> None:
    with Journal(journal_path(tmp_path)) as journal:
        journal.append(bodies(5))
    flip_byte(tmp_path, 3, column, offset)
    with Journal(journal_path(tmp_path), readonly=True) as journal:
        records = list(journal.records_after(0))
        assert [r.seq for r in records] == [1, 2, 3, 4, 5]
        assert [r.problem is None for r in records] == [True, True, False, True, True]
        assert records[2].unit_id == "u1" and "checksum mismatch" in records[2].problem
        with pytest.raises(JournalError, match=r"seq 3 \(unit 'u1'\): checksum mismatch"):
            list(journal.scans_after(0))


# ------------------------------------------------------------------ migration
def make_v2_journal(path: Path, scans: list[dict], snapshot: dict[str, np.ndarray]) -> None:
    """A journal exactly as schema version 2 wrote it: no checksums, no quarantine."""
    conn = sqlite3.connect(path)
    for statement in journal_module._SCHEMA.split(";"):
        if statement.strip():
            conn.execute(statement)
    for body in scans:
        header = json.dumps({k: v for k, v in body.items() if k != "ranges"}, separators=(",", ":"))
        ranges = np.asarray(body["ranges"], dtype="<f8").tobytes()
        conn.execute(
            "INSERT INTO scans (unit_id, stamp, body, ranges) VALUES (?, ?, ?, ?)",
            (body["unit_id"], body["stamp"], header, ranges),
        )
        conn.execute("INSERT OR REPLACE INTO units VALUES (?, ?)", (body["unit_id"], body["stamp"]))
    conn.execute("INSERT INTO snapshots VALUES (?, ?, ?, ?)", (2, 1.0, 2, encode_arrays(snapshot)))
    conn.execute(f"PRAGMA application_id = {journal_module.APPLICATION_ID}")
    conn.execute("PRAGMA user_version = 2")
    conn.commit()
    conn.close()


def test_a_v2_journal_reads_unchecked_and_migrates_keeping_every_record(tmp_path) -> None:
    path = tmp_path / "journal.sqlite3"
    scans = bodies(6)
    snap = {"log_odds": np.full((2, 3), 0.5, np.float32), "scans_fused": np.array(2)}
    make_v2_journal(path, scans, snap)
    with Journal(path, readonly=True) as old:
        assert old.schema_version == 2 and old.quarantined == 0
        records = list(old.records_after(0))
        assert [r.checksum_ok for r in records] == [None] * 6
        assert [r.scan for r in records] == scans
    with Journal(path) as journal:  # the writable open migrates
        records = list(journal.records_after(0))
        assert [r.checksum_ok for r in records] == [True] * 6
        assert [r.scan for r in records] == scans
        assert journal.load_snapshot(2).arrays["log_odds"].tolist() == snap["log_odds"].tolist()
        assert journal.unit_stamps() == {"u1": 5.0}
        assert journal.append(bodies(7)[6:]) == [7]
    assert sql(tmp_path, "PRAGMA user_version") == [(SCHEMA_VERSION,)]
    assert sql(tmp_path, "SELECT count(*) FROM snapshots WHERE checksum IS NULL") == [(0,)]
    flip_byte(tmp_path, 4, "ranges", 8)  # after the migration a flip is detected
    with Journal(path, readonly=True) as journal:
        assert [r.seq for r in journal.records_after(0) if r.checksum_ok is False] == [4]


# --------------------------------------------------------- quarantine at start-up
def corrupt_body_json(data: Path, seq: int) -> str:
    """Replace the body by text that is not JSON, with a matching checksum."""
    return _replace_body(data, seq, b'{"unit_id": "u1", "stamp": ')


def refused_body(data: Path, seq: int) -> str:
    """Replace the body by JSON the server refuses (no pose), with a matching checksum."""
    body = {k: v for k, v in scan_body(stamp=float(seq - 1)).items() if k not in ("ranges", "pose")}
    return _replace_body(data, seq, json.dumps(body).encode())


def _replace_body(data: Path, seq: int, body: bytes) -> bytes:
    unit, stamp, ranges, fmt = sql(
        data, "SELECT unit_id, stamp, ranges, format FROM scans WHERE seq = ?", (seq,)
    )[0]
    checksum = record_checksum(unit.encode(), stamp, body, ranges, fmt)
    sql(
        data,
        "UPDATE scans SET body = CAST(? AS TEXT), checksum = ? WHERE seq = ?",
        (body, checksum, seq),
    )
    return body


DAMAGES = {
    "flipped byte in ranges": (lambda d, s: flip_byte(d, s, "ranges", 803), "checksum mismatch"),
    "flipped byte in body": (lambda d, s: flip_byte(d, s, "body", 12), "checksum mismatch"),
    "body not JSON": (corrupt_body_json, "body does not parse"),
    "refused by Scan.from_dict": (refused_body, "pose"),
}


@pytest.mark.parametrize("damage", sorted(DAMAGES))
def test_restart_quarantines_exactly_the_damaged_record(tmp_path, caplog, damage) -> None:
    data = tmp_path / "data"
    scans = bodies()
    serve_and_close(data, scans)
    damage_fn, reason = DAMAGES[damage]
    original = damage_fn(data, 5)
    with caplog.at_level(logging.ERROR, logger="mapserver.service.map_service"):
        service = MapService(small_settings(data))
    try:
        assert service.journal.quarantined == 1
        assert metric(service, "fleetmap_journal_quarantined") == 1.0
        assert_same_belief(service, fused(data, scans[:4] + scans[5:]))
        assert service.version == N_SCANS
        assert [seq for seq, _ in service.journal.scans_after(0)] == [1, 2, 3, 4, *range(6, 13)]
    finally:
        service.close()
    (logged,) = [r.getMessage() for r in caplog.records if "quarantined" in r.getMessage()]
    assert "seq 5" in logged and "'u1'" in logged and reason in logged
    ((seq, kept, why),) = sql(data, "SELECT seq, body || '', reason FROM quarantine")
    column = "ranges" if "ranges" in damage else "body"
    stored = sql(data, f"SELECT {column} FROM quarantine")[0][0]
    assert seq == 5 and reason in why
    assert (stored if isinstance(stored, bytes) else stored.encode()) == original
    again = assert_restart_rebuilds(data, scans[:4] + scans[5:])  # nothing new is found
    assert again.journal.quarantined == 1


def test_replay_skips_a_damaged_record_and_changes_nothing(tmp_path, capsys) -> None:
    data = tmp_path / "data"
    scans = bodies()
    serve_and_close(data, scans)
    flip_byte(data, 3, "ranges", 100)
    assert main(["replay", str(data), "--out", str(tmp_path / "map"), "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out.splitlines()[-1])["scans"] == N_SCANS - 1
    assert "seq 3" in err and "checksum mismatch" in err
    assert sql(data, "SELECT count(*) FROM scans") == [(N_SCANS,)]
    assert sql(data, "SELECT count(*) FROM quarantine") == [(0,)]


# ------------------------------------------------------------------- snapshots
def _flip_snapshot(data: Path, seq: int) -> None:
    (blob,) = sql(data, "SELECT arrays FROM snapshots WHERE seq = ?", (seq,))[0]
    damaged = bytearray(blob)
    damaged[len(blob) // 2] ^= 0x01
    sql(data, "UPDATE snapshots SET arrays = ? WHERE seq = ?", (bytes(damaged), seq))


def _store_snapshot(data: Path, seq: int, blob: bytes) -> None:
    stamp, version = sql(data, "SELECT stamp, version FROM snapshots WHERE seq = ?", (seq,))[0]
    checksum = snapshot_checksum(seq, stamp, version, blob)
    sql(data, "UPDATE snapshots SET arrays = ?, checksum = ? WHERE seq = ?", (blob, checksum, seq))


SNAPSHOT_DAMAGES = {
    "checksum mismatch": _flip_snapshot,
    "undecodable": lambda d, s: _store_snapshot(d, s, b"PK\x03\x04 not an npz at all"),
    "wrong shape": lambda d, s: _store_snapshot(
        d,
        s,
        encode_arrays(
            {
                "log_odds": np.zeros((5, 5), np.float32),
                "last_observed": np.zeros((5, 5)),
                "scans_fused": np.array(1),
            }
        ),
    ),
}


@pytest.mark.parametrize("damage", sorted(SNAPSHOT_DAMAGES))
def test_a_bad_newest_snapshot_falls_back_to_the_older_one(tmp_path, caplog, damage) -> None:
    data = tmp_path / "data"
    scans = bodies()
    serve_and_close(data, scans, snapshot_at=(4, 8))
    SNAPSHOT_DAMAGES[damage](data, 8)
    with caplog.at_level(logging.ERROR, logger="mapserver.service.map_service"):
        assert assert_restart_rebuilds(data, scans).version == N_SCANS
    messages = " ".join(r.getMessage() for r in caplog.records)
    assert "snapshot at seq 8 is unusable" in messages
    assert "whole journal" not in messages


def test_with_every_snapshot_bad_start_up_replays_the_whole_journal(tmp_path, caplog) -> None:
    data = tmp_path / "data"
    scans = bodies()
    serve_and_close(data, scans, snapshot_at=(4, 8))
    _flip_snapshot(data, 4)
    SNAPSHOT_DAMAGES["wrong shape"](data, 8)
    with caplog.at_level(logging.ERROR, logger="mapserver.service.map_service"):
        assert_restart_rebuilds(data, scans)
    assert "replaying the whole journal" in caplog.text


def test_a_failed_snapshot_save_is_counted(tmp_path, monkeypatch) -> None:
    service = MapService(small_settings(tmp_path / "data"))
    try:
        body = scan_body()
        service.ingest([Scan.from_dict(body)])

        def disk_full(*args, **kwargs):
            raise sqlite3.OperationalError("database or disk is full")

        monkeypatch.setattr(service.journal, "save_snapshot", disk_full)
        service.snapshot()
        service.snapshot()
        assert service.snapshot_failures == 2
        assert metric(service, "fleetmap_snapshot_failures") == 2.0
    finally:
        service.close()


# ------------------------------------------------------------------------ lock
def test_deleting_server_lock_does_not_let_a_second_server_in(tmp_path) -> None:
    data = tmp_path / "data"
    first = MapService(small_settings(data))
    try:
        (data / LOCK_FILE).unlink()
        with pytest.raises(DataDirError, match=r"in use by another map server.*journal"):
            MapService(small_settings(data))
        assert main(["journal", "check", str(data)]) == 2
    finally:
        first.close()
    MapService(small_settings(data)).close()  # released on close


# ----------------------------------------------------------------------- check
def test_check_exit_codes_and_json(tmp_path, capsys) -> None:
    data = tmp_path / "data"
    serve_and_close(data, bodies(), snapshot_at=(6,))
    assert main(["journal", "check", str(data), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["records"] == N_SCANS and report["last_seq"] == N_SCANS
    assert report["snapshots_usable"] == 1 and report["intact"] is True
    flip_byte(data, 2, "ranges", 40)
    corrupt_body_json(data, 9)
    _flip_snapshot(data, 6)
    assert main(["journal", "check", str(data), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert (report["records"], report["checksum_failures"], report["unparsable"]) == (10, 1, 1)
    assert (report["snapshots_usable"], report["snapshots_unusable"]) == (0, 1)
    assert sql(data, "SELECT count(*) FROM quarantine") == [(0,)]  # read-only
    assert main(["journal", "check", str(tmp_path / "nowhere")]) == 2
    assert "no journal there" in capsys.readouterr().err


# --------------------------------------------------------------------- salvage
def test_salvage_recovers_the_intact_prefix_of_a_truncated_journal(tmp_path, capsys) -> None:
    data = tmp_path / "data"
    scans = [
        scan_body(stamp=float(i), x=3.0 + 0.05 * i, ranges=noisy_ranges(i)) for i in range(120)
    ]
    serve_and_close(data, scans)
    path = journal_path(data)
    size = path.stat().st_size
    with open(path, "r+b") as f:
        f.truncate(int(size * 0.6))
    with pytest.raises(JournalError, match="damaged.*journal salvage"):
        Journal(path)
    out = tmp_path / "saved"
    assert main(["journal", "salvage", str(data), "--out", str(out), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    ((first, last),) = report["recovered_ranges"]
    assert first == 1 and 10 < last < 120 and report["recovered"] == last
    assert report["lost_ranges"] == [[last + 1, 120]]
    with Journal(journal_path(out)) as saved:
        assert [(seq, body) for seq, body in saved.scans_after(0)] == list(
            zip(range(1, last + 1), scans[:last], strict=True)
        )
        assert saved.unit_stamps() == {"u1": 119.0}  # the source's bound, lost scans included
    assert (out / "map-settings.json").read_text() == (data / "map-settings.json").read_text()
    assert main(["journal", "check", str(out)]) == 0
    assert_restart_rebuilds(out, scans[:last])


def test_salvage_quarantines_damaged_records_and_keeps_seqs(tmp_path, capsys) -> None:
    data = tmp_path / "data"
    scans = bodies()
    serve_and_close(data, scans)
    flip_byte(data, 7, "body", 3)
    assert main(["journal", "salvage", str(data)]) == 1
    assert "seqs 1-6, 8-12" in capsys.readouterr().out
    out = tmp_path / "data-salvaged"
    assert sql(out, "SELECT seq, reason LIKE 'salvage: checksum mismatch%' FROM quarantine") == [
        (7, 1)
    ]
    assert main(["journal", "salvage", str(data), "--out", str(out)]) == 2  # never overwrites


# ------------------------------------------------------------------------ drop
def test_drop_quarantines_a_units_later_scans_and_rebuilds_without_them(tmp_path, capsys) -> None:
    data = tmp_path / "data"
    scans = [b for pair in zip(bodies(8, "u1"), bodies(8, "u2"), strict=True) for b in pair]
    serve_and_close(data, scans, snapshot_at=(10,))
    assert main(["journal", "drop", str(data), "--unit", "u1", "--after", "4.5"]) == 0
    out = capsys.readouterr().out
    assert "dropped 3 scans of unit 'u1' (seqs 11, 13, 15" in out and "bound is now 4.0" in out
    assert sql(data, "SELECT seq, reason FROM quarantine") == [
        (11, "dropped by admin"),
        (13, "dropped by admin"),
        (15, "dropped by admin"),
    ]
    assert sql(data, "SELECT seq FROM snapshots") == [(10,)]  # older than seq 11: kept
    kept = [b for b in scans if not (b["unit_id"] == "u1" and b["stamp"] > 4.5)]
    service = MapService(small_settings(data))
    try:
        assert_same_belief(service, fused(data, kept))
        again = scan_body(stamp=5.0, unit="u1")  # the bound went back: no 409
        assert service.ingest([Scan.from_dict(again)])[0].seq == 17
        assert main(["journal", "drop", str(data), "--unit", "u1", "--after", "0"]) == 2
    finally:
        service.close()
    assert main(["journal", "drop", str(data), "--unit", "u9", "--after", "0"]) == 0
    assert "nothing to drop" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exited:
        main(["journal", "drop", str(data), "--unit", "u1", "--after", "nan"])
    assert exited.value.code == 2
    assert "--after: expected a finite stamp in seconds, got 'nan'" in capsys.readouterr().err


# ------------------------------------------------------------- a real server
def test_a_real_server_restarts_past_a_damaged_record_and_reports_it(tmp_path) -> None:
    data = tmp_path / "data"
    server = ServerProcess(data, grid=(200, 100))
    try:
        for body in bodies():
            httpx.post(server.url + "/v1/scans", json=body, timeout=10).raise_for_status()
    finally:
        server.stop()
    flip_byte(data, 6, "ranges", 16)
    server = ServerProcess(data, grid=(200, 100))
    try:
        metrics = httpx.get(server.url + "/metrics", timeout=10).text
        assert "fleetmap_journal_quarantined 1.0" in metrics
        assert "fleetmap_snapshot_failures 0.0" in metrics
        assert httpx.get(server.url + "/v1/map/meta", timeout=10).json()["version"] == N_SCANS
    finally:
        server.stop()


def test_serve_on_a_damaged_journal_is_a_clear_error(tmp_path, capsys) -> None:
    data = tmp_path / "data"
    serve_and_close(data, bodies())
    journal_path(data).write_bytes(journal_path(data).read_bytes()[:6000])
    config = tmp_path / "server.yaml"
    config.write_text("grid: {width: 200, height: 100, resolution: 0.1}\n")
    assert main(["serve", "--config", str(config), "--data-dir", str(data)]) == 2
    assert "journal salvage" in capsys.readouterr().err
