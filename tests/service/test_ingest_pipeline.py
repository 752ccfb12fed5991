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
