"""A submission that fails after validation (its journal write, its fusion) fails alone:
the others of its group are answered as if it had not been there, in order, and durable;
the failure is logged with its unit and reason, at most once per rate window."""

import logging
import sqlite3
import threading

import numpy as np
import pytest
from conftest import make_scan
from server_helpers import small_settings

from mapserver.service.lograte import RateLimitFilter
from mapserver.service.map_service import MapService
from mapserver.service.scan_gate import IngestError


def scan(unit: str, stamp: float, row: int = 0):
    return make_scan(np.full(120, 2.0), x=3.0 + row, y=3.0, stamp=stamp, angle_min=-1.0,
                     unit_id=unit)  # fmt: skip


class HeldJournal:
    """Wraps ``service.journal.append``: the first call waits for ``release`` (so what is
    submitted meanwhile forms one group), and a write holding a scan for which
    ``doomed(unit_id, stamp)`` is true raises a disk I/O error, as SQLite does."""

    def __init__(self, service: MapService, doomed) -> None:
        self.append = service.journal.append
        self.doomed = doomed
        self.entered = threading.Event()  # the first call waits
        self.release = threading.Event()
        self.calls: list[list[tuple[str, float]]] = []
        service.journal.append = self  # type: ignore[method-assign]

    def __call__(self, records):
        self.calls.append([(r["unit_id"], r["stamp"]) for r in records])
        if len(self.calls) == 1:
            self.entered.set()
            assert self.release.wait(10)
        if any(self.doomed(r["unit_id"], r["stamp"]) for r in records):
            raise sqlite3.OperationalError("disk I/O error")
        return self.append(records)


@pytest.fixture
def service(tmp_path):
    service = MapService(small_settings(tmp_path / "data"))
    yield service
    service.close()


@pytest.fixture
def rate_limited_log(caplog):
    """The map service's log as ``fleetmap serve`` filters it: one record per template
    per minute here."""
    caplog.set_level(logging.INFO, logger="mapserver.service.map_service")
    limit = RateLimitFilter(burst=1, interval_s=60.0)
    caplog.handler.addFilter(limit)
    yield caplog
    caplog.handler.removeFilter(limit)


def outcome(future):
    try:
        return [ack.seq for ack in future.result(timeout=10)]
    except IngestError as exc:
        return exc.status


def test_a_failing_journal_write_fails_its_submission_alone(service, rate_limited_log):
    held = HeldJournal(service, lambda unit, stamp: unit == "u3" and stamp >= 5.0)
    first = service.submit([scan("u1", 1.0)])  # its write waits: the next ones queue up
    assert held.entered.wait(10)
    group = [
        service.submit([scan("u1", 2.0)]),
        service.submit([scan("u3", 5.0)]),  # its write fails
        service.submit([scan("u2", 2.0), scan("u2", 3.0)]),
        service.submit([scan("u3", 4.0)]),  # refused beside u3 at 5 s; fine without it
        service.submit([scan("u1", 3.0)]),
    ]
    held.release.set()
    assert outcome(first) == [1]
    assert [outcome(f) for f in group] == [[2], 503, [3, 4], [5], [6]]
    assert held.calls[1] == [("u1", 2.0), ("u3", 5.0), ("u2", 2.0), ("u2", 3.0), ("u1", 3.0)]
    journaled = [(s["unit_id"], s["stamp"]) for _, s in service.journal.scans_after(0)]
    assert journaled == [("u1", 1.0), ("u1", 2.0), ("u2", 2.0), ("u2", 3.0), ("u3", 4.0),
                         ("u1", 3.0)]  # fmt: skip
    assert service.version == 6
    with pytest.raises(IngestError, match="^journal write failed: disk I/O error$"):
        service.ingest([scan("u3", 6.0)])  # alone this time: fails again, not logged again
    assert outcome(service.submit([scan("u3", 7.0, row=1)])) == 503
    assert outcome(service.submit([scan("u2", 4.0)])) == [7]
    lines = [r.getMessage() for r in rate_limited_log.records if "journal write" in r.msg]
    reason = "OperationalError: disk I/O error"
    assert lines == [f"journal write failed for unit 'u3' (1 scans): {reason}"]


def test_a_scan_that_cannot_be_fused_is_quarantined_and_fails_alone(service, tmp_path):
    held = HeldJournal(service, lambda unit, stamp: False)
    fuse_many = service.belief.fuse_many

    def poisoned(scans):
        if any(s.unit_id == "bad" for s in scans):
            raise FloatingPointError("a pathological scan")
        return fuse_many(scans)

    service.belief.fuse_many = poisoned  # type: ignore[method-assign]
    first = service.submit([scan("u1", 1.0)])
    assert held.entered.wait(10)
    group = [
        service.submit([scan("u1", 2.0)]),
        service.submit([scan("bad", 2.0), scan("bad", 2.5)]),
        service.submit([scan("u2", 2.0, row=1)]),
    ]
    held.release.set()
    assert outcome(first) == [1]
    assert outcome(group[0]) == [2] and outcome(group[2]) == [5]
    with pytest.raises(IngestError) as refused:
        group[1].result(timeout=10)
    assert refused.value.status == 500
    assert "unit 'bad'" in refused.value.detail and "[3, 4]" in refused.value.detail
    assert "FloatingPointError: a pathological scan" in refused.value.detail
    assert [row[:2] for row in service.journal.quarantined_rows()] == [(3, "bad"), (4, "bad")]
    # the map holds u1 and u2's scans, exactly as fused alone
    alone = MapService(small_settings(tmp_path / "alone"))
    try:
        alone.ingest([scan("u1", 1.0)])
        alone.ingest([scan("u1", 2.0)])
        alone.ingest([scan("u2", 2.0, row=1)])
        assert np.array_equal(alone.belief.raw_log_odds(), service.belief.raw_log_odds())
        live = service.belief.raw_log_odds().copy()
    finally:
        alone.close()
    service.belief.fuse_many = fuse_many  # type: ignore[method-assign]
    assert outcome(service.submit([scan("u2", 3.0, row=1)])) == [6]
    live = service.belief.raw_log_odds().copy()
    service.close()
    replayed = MapService(small_settings(tmp_path / "data"))  # the quarantined ones skipped
    try:
        assert np.array_equal(replayed.belief.raw_log_odds(), live)
    finally:
        replayed.close()
