"""The fused scans' messages made in a child process are the in-process ones, byte for
byte; the child's errors come back as ReplayError; a writer that stops early stops it."""

import os
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from mapserver.core.scan import Pose2D, PoseStd, Scan
from mapserver.service.replay import ReplayError
from mapserver.store.journal import Journal
from scenarios.replay.foxglove_messages import stamp_ns
from scenarios.replay.fused import FusedScans, fused_message, fused_scan
from scenarios.replay.fused_worker import fused_items, messages


def journal_of(path: Path, stamps: list[float], beams: int = 90) -> Path:
    """A journal holding one scan of each of three units at each stamp [s]."""
    rng = np.random.default_rng(7)
    scans = []
    for stamp in stamps:
        for k in range(3):
            ranges = rng.uniform(0.2, 9.0, beams)
            ranges[rng.random(beams) < 0.1] = np.nan  # invalid beams
            ranges[rng.random(beams) < 0.1] = np.inf  # no return
            std = PoseStd(0.02, 0.01) if k == 1 else None
            pose = Pose2D(1.0 + k, 2.5, 0.3 * k)
            ranges = ranges.astype(np.float32).astype(np.float64)
            scan = Scan(f"u{k}", stamp, pose, -3.1, 6.2 / beams, 0.05, 10.0, ranges, std)
            scans.append(scan.journal_record())
    with Journal(path) as journal:
        journal.append(scans)
    return path


def in_process(path: Path) -> list[tuple[int, bytes]]:
    fused = FusedScans({}, path)
    return [(stamp_ns(scan.stamp), fused_message(seq, scan)) for seq, scan in fused.scans()]


def test_the_child_makes_the_in_process_messages_byte_for_byte(tmp_path):
    path = journal_of(tmp_path / "j.sqlite3", [0.1 * k for k in range(1, 41)])
    expected = in_process(path)
    assert len(expected) == 120
    assert list(messages(path)) == expected
    assert list(fused_items(FusedScans({}, path), worker_from=0)) == expected  # the child
    assert list(fused_items(FusedScans({}, path), worker_from=10**6)) == expected  # in process
    seq, scan = fused_scan(expected[4][1])  # and each message reads back as its scan
    assert seq == 5 and scan.unit_id == "u1" and scan.pose_std == PoseStd(0.02, 0.01)


def test_a_damaged_record_is_left_out_by_the_child_as_in_process(tmp_path):
    path = journal_of(tmp_path / "j.sqlite3", [0.1, 0.2, 0.3])
    with sqlite3.connect(path) as db:  # a flipped byte: its checksum no longer matches
        db.execute("UPDATE scans SET body = replace(body, '\"u1\"', '\"u7\"') WHERE seq = 5")
    expected = in_process(path)
    assert len(expected) == 8 and all(fused_scan(m)[0] != 5 for _, m in expected)
    assert list(fused_items(FusedScans({}, path), worker_from=0)) == expected


def test_the_childs_error_comes_back_naming_what_was_wrong(tmp_path):
    path = journal_of(tmp_path / "j.sqlite3", [-0.5, 0.1])  # a stamp no replay can hold
    with pytest.raises(ValueError, match="stamp must be a finite, non-negative sim time"):
        list(fused_items(FusedScans({}, path), worker_from=10**6))
    with pytest.raises(ReplayError, match="stamp must be a finite, non-negative sim time"):
        list(fused_items(FusedScans({}, path), worker_from=0))


def test_a_missing_journal_is_a_replay_error_on_both_paths(tmp_path):
    for worker_from in (0, 10**6):
        with pytest.raises(ReplayError, match="neither a journal file"):
            list(fused_items(FusedScans({}, tmp_path / "none.sqlite3"), worker_from=worker_from))


def test_a_writer_that_stops_early_leaves_no_child_behind(tmp_path):
    path = journal_of(tmp_path / "j.sqlite3", [0.01 * k for k in range(1, 2001)], beams=360)
    items = fused_items(FusedScans({}, path), worker_from=0)
    first = [next(items) for _ in range(3)]
    assert first == in_process(path)[:3] and _children_reading(path) != []
    items.close()  # the child, blocked on a full pipe, is stopped and waited for
    assert _children_reading(path) == []


def _children_reading(journal: Path) -> list[int]:
    """The pids of this process's children whose command line names ``journal``."""
    pids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        if int(stat[1]) == os.getpid() and str(journal).encode() in cmdline:
            pids.append(int(entry.name))
    return pids
