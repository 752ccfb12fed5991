"""The durable scan journal: order, round trips, snapshots, reopening and crash safety."""

from __future__ import annotations

import math
import signal
import sqlite3
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mapserver.core.scan import Scan
from mapserver.store.journal import (
    SCHEMA_VERSION,
    Journal,
    JournalError,
    RecordError,
    journal_path,
    open_journal_for_replay,
)

F32_A = float(np.float32(1.2345678901234567))  # ranges are float32 values (Scan.from_dict)
F32_B = float(np.float32(0.1 + 0.2))


def scan(unit_id: str = "u1", stamp: float = 0.0, n: int = 4) -> dict:
    """A docs/http-api.md 2.1 scan object with a return, a no-return and an invalid beam."""
    return {
        "unit_id": unit_id,
        "stamp": stamp,
        "frame": "map",
        "pose": {"x": 1.0 + stamp, "y": 2.0, "yaw": 0.1},
        "pose_std": {"xy": 0.02, "yaw": 0.01},
        "angle_min": -math.pi,
        "angle_increment": 0.01745,
        "range_min": 0.05,
        "range_max": 20.0,
        "ranges": [F32_A, math.inf, None, F32_B][:n],
    }


@pytest.fixture
def journal(tmp_path: Path):
    with Journal(tmp_path / "journal.sqlite3") as j:
        yield j


def test_appended_scans_read_back_equal(journal: Journal) -> None:
    scans = [scan("u1", 1.0), scan("u2", 1.5), scan("u1", 2.0)]
    seqs = journal.append(scans)
    assert [s for s, _ in journal.scans_after(0)] == seqs
    assert [body for _, body in journal.scans_after(0)] == scans


def test_float32_and_no_return_ranges_round_trip_exactly(journal: Journal) -> None:
    journal.append([scan()])
    (_, body) = next(journal.scans_after(0))
    assert body["ranges"][0] == F32_A
    assert body["ranges"][1] == math.inf
    assert body["ranges"][2] is None
    assert body["ranges"][3] == F32_B


def test_a_range_that_is_not_float32_is_refused_not_rounded(journal: Journal) -> None:
    body = scan()
    body["ranges"] = [F32_A, 1.2345678901234567]
    with pytest.raises(ValueError, match=r"ranges\[1\] = .* is not a float32 value"):
        journal.append([body])
    assert journal.last_seq() == 0


def test_seqs_are_consecutive_and_increase_across_batches(journal: Journal) -> None:
    first = journal.append([scan(stamp=1.0), scan(stamp=2.0)])
    second = journal.append([scan(stamp=3.0)])
    third = journal.append([scan(stamp=4.0), scan(stamp=5.0), scan(stamp=6.0)])
    assert first + second + third == [1, 2, 3, 4, 5, 6]
    assert journal.last_seq() == 6
    assert journal.count() == 6


def test_empty_journal_and_empty_append(journal: Journal) -> None:
    assert journal.append([]) == []
    assert journal.last_seq() == 0
    assert journal.count() == 0
    assert list(journal.scans_after(0)) == []
    assert journal.unit_stamps() == {}
    assert journal.latest_snapshot() is None


def test_scans_after_starts_after_the_given_seq(journal: Journal) -> None:
    journal.append([scan(stamp=float(i)) for i in range(10)])
    assert [s for s, _ in journal.scans_after(7)] == [8, 9, 10]
    assert list(journal.scans_after(10)) == []


def test_scans_after_pages_through_everything_in_order(journal: Journal) -> None:
    journal.append([scan(stamp=float(i)) for i in range(25)])
    seqs = [s for s, _ in journal.scans_after(3, page_size=4)]
    assert seqs == list(range(4, 26))


def test_until_stamp_skips_later_stamps_but_keeps_later_seqs(journal: Journal) -> None:
    # two units interleave: a later seq may carry an earlier stamp
    journal.append([scan("a", 1.0), scan("b", 5.0), scan("a", 2.0), scan("b", 6.0)])
    journal.append([scan("a", 3.0)])
    got = [(s, body["stamp"]) for s, body in journal.scans_after(0, until_stamp=3.0, page_size=1)]
    assert got == [(1, 1.0), (3, 2.0), (5, 3.0)]
    assert list(journal.scans_after(0, until_stamp=0.5)) == []


def test_unit_stamps_hold_each_units_largest_stamp(journal: Journal) -> None:
    journal.append([scan("u1", 1.0), scan("u2", 7.0), scan("u1", 4.0)])
    journal.append([scan("u1", 4.0), scan("u3", -2.5)])
    assert journal.unit_stamps() == {"u1": 4.0, "u2": 7.0, "u3": -2.5}


def test_a_bad_scan_in_a_batch_journals_nothing(journal: Journal) -> None:
    journal.append([scan(stamp=1.0)])
    with pytest.raises(ValueError, match=r"scans\[1\]\.stamp.*nan"):
        journal.append([scan("u9", 2.0), scan(stamp=math.nan)])
    with pytest.raises(ValueError, match=r"scans\[0\]\.unit_id.*''"):
        journal.append([scan(unit_id="")])
    assert journal.last_seq() == 1
    assert journal.unit_stamps() == {"u1": 1.0}


def arrays(fill: float) -> dict[str, np.ndarray]:
    log_odds = np.full((3, 5), fill, dtype=np.float32)
    last = np.full((3, 5), np.nan, dtype=np.float64)
    last[1, 2] = fill
    return {"log_odds": log_odds, "last_observed": last}


def test_snapshot_round_trips_arrays_exactly(journal: Journal) -> None:
    journal.append([scan(stamp=1.0), scan(stamp=2.0)])
    journal.save_snapshot(2, 2.0, 17, arrays(0.75))
    snap = journal.latest_snapshot()
    assert snap is not None
    assert (snap.seq, snap.stamp, snap.version) == (2, 2.0, 17)
    expected = arrays(0.75)
    assert set(snap.arrays) == set(expected)
    for name, array in expected.items():
        assert snap.arrays[name].dtype == array.dtype
        np.testing.assert_array_equal(snap.arrays[name], array)


def test_only_the_newest_snapshots_are_kept(tmp_path: Path) -> None:
    with Journal(tmp_path / "j.sqlite3", keep_snapshots=2) as journal:
        journal.append([scan(stamp=float(i)) for i in range(5)])
        for seq in (1, 2, 3, 5):
            journal.save_snapshot(seq, float(seq), seq * 10, arrays(seq))
        assert journal.snapshot_seqs() == [3, 5]
        snap = journal.latest_snapshot()
        assert snap is not None and snap.seq == 5 and snap.version == 50


def test_snapshot_at_the_same_seq_replaces_the_older_one(journal: Journal) -> None:
    journal.append([scan()])
    journal.save_snapshot(1, 0.0, 3, arrays(1.0))
    journal.save_snapshot(1, 0.0, 4, arrays(2.0))
    assert journal.snapshot_seqs() == [1]
    snap = journal.latest_snapshot()
    assert snap is not None and snap.version == 4
    assert snap.arrays["log_odds"][0, 0] == 2.0


def test_snapshot_beyond_the_journal_is_refused(journal: Journal) -> None:
    journal.append([scan()])
    with pytest.raises(ValueError, match="seq must not be beyond.*1.*got 2"):
        journal.save_snapshot(2, 0.0, 1, arrays(1.0))
    assert journal.latest_snapshot() is None


def test_reopening_keeps_scans_units_and_snapshots(tmp_path: Path) -> None:
    path = tmp_path / "data" / "journal.sqlite3"
    scans = [scan("u1", 1.0), scan("u2", 2.0)]
    with Journal(path) as journal:
        journal.append(scans)
        journal.save_snapshot(2, 2.0, 9, arrays(0.5))
    with Journal(path) as journal:
        assert [body for _, body in journal.scans_after(0)] == scans
        assert journal.unit_stamps() == {"u1": 1.0, "u2": 2.0}
        snap = journal.latest_snapshot()
        assert snap is not None and snap.seq == 2
        assert journal.append([scan("u1", 3.0)]) == [3]


def test_replay_helper_opens_read_only_from_file_or_data_dir(tmp_path: Path) -> None:
    with Journal(journal_path(tmp_path)) as journal:
        journal.append([scan(stamp=1.0)])
    for where in (tmp_path, journal_path(tmp_path)):
        with open_journal_for_replay(where) as replay:
            assert replay.last_seq() == 1
            with pytest.raises(JournalError, match="read-only"):
                replay.append([scan(stamp=2.0)])
    with pytest.raises(JournalError, match="neither a journal file nor a data directory"):
        open_journal_for_replay(tmp_path / "missing")


def test_a_separate_reader_sees_commits_while_the_writer_stays_open(tmp_path: Path) -> None:
    path = tmp_path / "j.sqlite3"
    with Journal(path) as writer, Journal(path, readonly=True) as reader:
        writer.append([scan(stamp=1.0)])
        assert reader.last_seq() == 1
        writer.append([scan(stamp=2.0)])
        assert [s for s, _ in reader.scans_after(0)] == [1, 2]


def test_one_instance_is_safe_to_share_between_threads(journal: Journal) -> None:
    def post(unit: str) -> None:
        for i in range(20):
            journal.append([scan(unit, float(i))])

    threads = [threading.Thread(target=post, args=(f"u{k}",)) for k in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert [s for s, _ in journal.scans_after(0)] == list(range(1, 81))
    assert journal.unit_stamps() == {f"u{k}": 19.0 for k in range(4)}


def test_size_counts_the_database_and_its_wal(journal: Journal) -> None:
    before = journal.size_bytes()
    journal.append([scan(stamp=float(i)) for i in range(50)])
    assert journal.size_bytes() > before > 0


def test_schema_version_mismatch_is_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "j.sqlite3"
    Journal(path).close()
    with sqlite3.connect(path) as conn:
        conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    conn.close()
    message = f"schema version {SCHEMA_VERSION + 1}.*reads version {SCHEMA_VERSION}"
    with pytest.raises(JournalError, match=message):
        Journal(path)


def test_a_foreign_file_is_not_taken_for_a_journal(tmp_path: Path) -> None:
    other_db = tmp_path / "other.sqlite3"
    with sqlite3.connect(other_db) as conn:
        conn.execute("CREATE TABLE t (x)")
    conn.close()
    with pytest.raises(JournalError, match="not a fleetmap journal"):
        Journal(other_db)
    text = tmp_path / "notes.txt"
    text.write_text("hello, this is not SQLite at all" * 100)
    with pytest.raises(JournalError, match="not a fleetmap journal"):
        Journal(text)


def test_bad_synchronous_names_the_value(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="synchronous.*'SOMETIMES'"):
        Journal(tmp_path / "j.sqlite3", synchronous="SOMETIMES")


_WRITER = textwrap.dedent(
    """
    import sys
    from mapserver.store.journal import Journal

    journal = Journal(sys.argv[1], synchronous=sys.argv[2])
    ranges = [1.0 + 0.125 * i for i in range(360)]  # float32 values
    for batch in range(100000):
        scans = [
            {"unit_id": f"u{k}", "stamp": float(batch), "frame": "map",
             "pose": {"x": 1.0, "y": 2.0, "yaw": 0.0}, "angle_min": 0.0,
             "angle_increment": 0.0175, "range_min": 0.05, "range_max": 20.0,
             "ranges": ranges}
            for k in range(3)
        ]
        for seq in journal.append(scans):
            print(seq, flush=True)
    """
)


@pytest.mark.parametrize("synchronous", ["FULL", "OFF"])
def test_every_acknowledged_scan_survives_sigkill(tmp_path: Path, synchronous: str) -> None:
    path = tmp_path / "j.sqlite3"
    root = Path(__file__).resolve().parents[2]
    child = subprocess.Popen(
        [sys.executable, "-c", _WRITER, str(path), synchronous],
        stdout=subprocess.PIPE,
        text=True,
        cwd=root,
    )
    acknowledged: list[int] = []
    try:
        assert child.stdout is not None
        while len(acknowledged) < 150:
            line = child.stdout.readline()
            assert line, f"writer exited early with code {child.wait()}"
            acknowledged.append(int(line))
        child.send_signal(signal.SIGKILL)
        acknowledged += [int(line) for line in child.stdout.read().split()]
    finally:
        child.kill()
        child.wait()
    assert child.returncode == -signal.SIGKILL  # killed mid-way, not finished
    with Journal(path) as journal:
        stored = [s for s, _ in journal.scans_after(0)]
        assert set(acknowledged) <= set(stored)
        assert stored == list(range(1, len(stored) + 1))  # nothing torn, no gaps
        assert journal.unit_stamps()["u0"] >= (max(acknowledged) - 1) // 3


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    st.lists(
        st.one_of(
            st.none(),
            st.just(math.inf),
            st.just(-math.inf),
            st.floats(-1e6, 1e6, width=32),
        ),
        min_size=1,
        max_size=64,
    )
)
def test_a_records_fields_make_the_scan_its_json_object_makes(tmp_path, ranges) -> None:
    """``Record.fields`` (ranges as the array, what replay reads) and ``Record.scan`` (the
    2.1 object, ranges a list) validate to the same scan, bit for bit."""
    body = {**scan(), "ranges": ranges}
    with Journal(tmp_path / f"fields-{len(ranges)}.sqlite3") as journal:
        journal.append([body])
        (record,) = journal.records_after(journal.last_seq() - 1)
    assert record.scan == body
    from_fields = Scan.from_dict(record.fields())
    assert from_fields.digest() == Scan.from_dict(record.scan).digest()
    assert np.array_equal(from_fields.ranges, Scan.from_dict(body).ranges, equal_nan=True)


def test_a_damaged_records_fields_raise_its_problem(journal: Journal) -> None:
    journal.append([scan()])
    with journal._lock:
        journal._db().execute("UPDATE scans SET body = ?", (b"{not json",))
    (record,) = journal.records_after(0)
    assert record.scan is None and record.header is None and record.ranges is None
    with pytest.raises(RecordError, match="checksum mismatch"):
        record.fields()


def test_a_header_orjson_refuses_is_read_back_by_the_fallback(journal: Journal) -> None:
    """A record whose header holds what only Python's json reads (written by
    ``json.dumps`` before orjson wrote the headers) comes back as that json reads it."""
    seq = journal.append([scan("u1", 1.0)])[0]
    with journal._lock:  # the header as json.dumps wrote it, with a NaN of another field
        journal._db().execute(
            "UPDATE scans SET body = ?, checksum = NULL WHERE seq = ?",
            ('{"unit_id": "u1", "stamp": 1.0, "extra": NaN, "big": 123456789012345678901}', seq),
        )
        journal._db().commit()
    (record,) = list(journal.records_after(0))
    assert record.problem is None
    assert math.isnan(record.scan["extra"]) and record.scan["big"] == 1.2345678901234568e20
