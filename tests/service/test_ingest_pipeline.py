"""Ingest in two stages (journal, then fusion on its own thread): an ack is only given
once the map holds its scan, retries included, and groups are fused in journal order."""

import threading

import numpy as np
from conftest import make_scan
from server_helpers import small_settings

from mapserver.service.map_service import MapService


def scan(unit: int, k: int):
    return make_scan(np.full(120, 2.0), x=2.0 + unit, y=2.0 + 0.05 * k, stamp=float(k),
                     angle_min=-1.0, unit_id=f"u{unit}")  # fmt: skip


def test_every_ack_is_answered_once_the_map_holds_its_scan(tmp_path):
    service = MapService(small_settings(tmp_path / "data"))
    seen: list[tuple[int, int]] = []  # (ack's map version, the map's version when answered)
    lock = threading.Lock()

    def record(future):
        (ack,) = future.result()
        with lock:
            seen.append((ack.map_version, service.version))

    def unit(u: int) -> None:
        for k in range(1, 26):
            first = scan(u, k)
            for future in (service.submit([first]), service.submit([scan(u, k)])):  # a retry
                future.add_done_callback(record)

    try:
        threads = [threading.Thread(target=unit, args=(u,)) for u in range(4)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        service.ingest([scan(9, 1)])  # after everything queued before it
        assert len(seen) == 200
        assert all(version >= acked for acked, version in seen)
        assert service.version == service.journal.last_seq() == 101  # 100 scans + the last
    finally:
        service.close()


def test_groups_fuse_in_journal_order_to_the_map_a_replay_builds(tmp_path):
    service = MapService(small_settings(tmp_path / "data"))
    try:
        futures = [service.submit([scan(u, k)]) for k in range(1, 11) for u in range(3)]
        acks = [f.result()[0] for f in futures]
        assert [a.seq for a in acks] == sorted(a.seq for a in acks)
        live = service.belief.raw_log_odds().copy()
    finally:
        service.close()
    replayed = MapService(small_settings(tmp_path / "data"))  # from the journal alone
    try:
        assert np.array_equal(replayed.belief.raw_log_odds(), live)
    finally:
        replayed.close()


def test_groups_waiting_for_fusion_are_fused_in_one_kernel_call(tmp_path):
    """While the fusion thread is held, ten submissions are journaled as groups of their
    own; once it is free, it fuses all of them in one ``fuse_many`` call, in journal
    order, and answers each with its own ack: the map a replay builds."""
    service = MapService(small_settings(tmp_path / "data"))
    calls: list[int] = []
    fuse_many = service.belief.fuse_many

    def counted(scans):
        calls.append(len(scans))
        return fuse_many(scans)

    service.belief.fuse_many = counted
    try:
        with service._lock:  # the fusion thread waits here with what it took
            first = service.submit([scan(0, 1)])
            deadline = threading.Event()
            while service.journal.last_seq() < 1 and not deadline.wait(0.01):
                pass
            deadline.wait(0.2)  # the fusion thread has taken the first group
            futures = [service.submit([scan(u, 2)]) for u in range(10)]
            while service.journal.last_seq() < 11 and not deadline.wait(0.01):
                pass
        acks = [first.result()[0]] + [f.result()[0] for f in futures]
        assert [a.seq for a in acks] == list(range(1, 12))
        # the first group alone (taken before the lock let go), then the ten waiting as one
        assert sum(calls) == 11 and len(calls) <= 2 and calls[-1] >= 10
        assert all(a.map_version == 11 for a in acks[1:])
        live = service.belief.raw_log_odds().copy()
    finally:
        service.close()
    replayed = MapService(small_settings(tmp_path / "data"))
    try:
        assert np.array_equal(replayed.belief.raw_log_odds(), live)
    finally:
        replayed.close()
