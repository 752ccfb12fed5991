"""The costmap is built beside fusion, over a mirror of the belief (``costmap_follower``):
a refresh, a slow reader or a snapshot's copy never holds up the scans behind them, the
costmap still catches up without a reader, and every read sees every acknowledged scan."""

import time

import numpy as np
from test_costmap_lag import scans, service


def wait_until(condition, timeout: float = 20.0) -> None:
    """Poll ``condition`` every 10 ms until it holds or ``timeout`` [s] passed (the
    caller asserts it after)."""
    deadline = time.monotonic() + timeout
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.01)


def test_scans_are_acknowledged_while_the_costmap_is_held(tmp_path):
    s = service(tmp_path, refresh_s=0.01)
    try:
        with s.follower.costmap_current():  # what a long refresh or a slow reader holds
            acks = [s.submit([scan]).result(timeout=20) for scan in scans(6)]
            assert [a[0].seq for a in acks] == [1, 2, 3, 4, 5, 6]
            assert s.version == 6 and s.costmap.version < 6  # held: not refreshed
        read = s.costmap_read()  # and once let go, a read sees them all
        assert read.version == 6
        assert np.array_equal(read.data, s.costmap.build_costs(s.belief.stamp))
    finally:
        s.close()


def test_a_snapshot_due_while_the_costmap_is_held_does_not_hold_up_scans(tmp_path):
    s = service(tmp_path, refresh_s=60.0, journal={"snapshot_every_scans": 2})
    try:
        with s.follower.costmap_current():
            for scan in scans(5):  # snapshots fall due after the 2nd and the 4th
                s.submit([scan]).result(timeout=20)
        wait_until(lambda: s.journal.snapshot_seqs() != [])
        assert s.journal.snapshot_seqs()  # taken from the mirror once it was let go
    finally:
        s.close()
    reopened = service(tmp_path, refresh_s=60.0)
    try:
        assert reopened.version == 5 and reopened.belief.scans_fused == 5
    finally:
        reopened.close()


def test_without_a_reader_the_costmap_catches_up_on_its_own_thread(tmp_path):
    s = service(tmp_path, refresh_s=1.0)
    try:
        for scan in scans(3):
            s.ingest([scan])
        assert s.costmap_read().version == 3  # a refresh, then a scan well within 1 s
        s.ingest(scans(4)[-1:])
        wait_until(lambda: s.costmap.version >= 4)  # no scan, no read: its thread refreshes it
        assert s.costmap.version == s.version == 4
        with s.follower.costmap_current() as now:
            assert np.array_equal(now.costmap.costs, s.costmap.build_costs(s.belief.stamp))
    finally:
        s.close()


def test_the_snapshot_and_belief_reads_equal_the_live_belief(tmp_path):
    s = service(tmp_path, refresh_s=60.0)
    try:
        for scan in scans(7):
            s.ingest([scan])
        seq = s.snapshot()
        live = s.belief.state_arrays()
        assert seq == 7
        snapshot = s.journal.load_snapshot(7)
        assert (snapshot.stamp, int(snapshot.arrays["scans_fused"])) == (s.belief.stamp, 7)
        for name, array in live.items():
            assert snapshot.arrays[name].tobytes() == array.tobytes()
        assert s.age_read().version == 7
        assert np.array_equal(
            s.age_read().data, s.belief.age_at().astype(np.float32), equal_nan=True
        )
    finally:
        s.close()
