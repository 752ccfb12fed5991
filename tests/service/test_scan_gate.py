"""The ingest checks on their own: all or none per submission, retries, and a group that
is abandoned (its journal write failed) or committed."""

import math

from server_helpers import scan_body

from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Scan
from mapserver.service.map_clock import MapClock
from mapserver.service.scan_gate import Ack, IngestError, ScanGate


def scan(stamp, unit="u1", **fields):
    return Scan.from_dict(scan_body(stamp=stamp, unit=unit, **fields))


def gate(unit_stamps=None, find_scan=lambda unit, stamp: None):
    clock = MapClock(5.0, wall_clock=lambda: 1e9)
    return ScanGate(GridGeometry(200, 100, 0.1), clock, unit_stamps or {}, find_scan, 16384)


def test_a_refused_submission_changes_nothing_of_the_group():
    g = gate()
    check = g.open_group()
    first = check.admit([scan(1.0)])
    refused = check.admit([scan(2.0, "u2"), scan(0.5)])  # u1 goes backwards: all refused
    assert isinstance(refused, IngestError) and refused.status == 409
    assert refused.detail.startswith("scans[1].stamp: unit 'u1' already sent stamp 1.0")
    assert [s.unit_id for s in check.new] == ["u1"] and g.clock.map_stamp == 1.0
    check.commit([Ack(7, 7)])
    assert check.answers(first, [Ack(7, 7)]) == [Ack(7, 7)]


def test_an_abandoned_group_leaves_the_gate_as_it_was():
    g = gate()
    check = g.open_group()
    check.admit([scan(1.0), scan(1.0, "u2")])
    check.abandon()  # the journal write failed
    assert g.clock.map_stamp == -math.inf
    again = g.open_group()
    assert isinstance(again.admit([scan(1.0)]), list)  # not a retry of an unjournaled scan
    assert len(again.new) == 1


def test_a_retry_after_a_restart_is_answered_from_the_journal():
    stored = scan_body(stamp=4.0)
    g = gate(
        {"u1": 4.0}, lambda unit, stamp: (12, stored) if (unit, stamp) == ("u1", 4.0) else None
    )
    check = g.open_group()
    entries = check.admit([scan(4.0)])
    assert check.answers(entries, []) == [Ack(12, 12)] and check.new == []
    other = check.admit([scan(4.0, y=6.0)])
    assert isinstance(other, IngestError) and "already sent another scan" in other.detail


def test_a_refused_single_scan_changes_nothing():
    g = gate()
    check = g.open_group()
    check.admit([scan(1.0)])
    refused = check.admit([scan(1e12, "u9")])  # leads the wall clock (1e9 s here)
    assert isinstance(refused, IngestError) and refused.status == 422
    assert [s.unit_id for s in check.new] == ["u1"] and g.clock.map_stamp == 1.0
    assert isinstance(check.admit([scan(2.0, "u9")]), list)  # u9 has no stamp recorded


def test_a_new_scan_is_taken_unhashed_and_only_a_repeat_at_its_stamp_is_hashed():
    journal = {}  # (unit, stamp) -> (seq, scan object), as the journal answers find_scan
    g = gate(find_scan=lambda unit, stamp: journal.get((unit, stamp)))
    first, later = scan(1.0), scan(2.0)
    for seq, taken in enumerate((first, later), start=1):
        check = g.open_group()
        assert isinstance(check.admit([taken]), list)
        journal[("u1", taken.stamp)] = (seq, taken.to_dict())
        check.commit([Ack(seq, seq + 10)])
    hashed = lambda s: "_digest" in vars(s)  # noqa: E731 - functools.cached_property's slot
    assert not hashed(first) and not hashed(later)  # no digest for a scan simply taken
    assert g._latest["u1"].scan is None  # nor the scan kept once journaled
    check = g.open_group()
    retry, other = scan(2.0), scan(2.0, y=6.0)
    assert check.answers(check.admit([retry]), []) == [Ack(2, 12)]  # its own ack again
    refused = check.admit([other])
    assert isinstance(refused, IngestError) and "already sent another scan" in refused.detail
    assert hashed(retry) and hashed(other) and not hashed(first) and not hashed(later)


def test_a_journaled_scan_that_no_longer_reads_refuses_the_repeat_alone():
    stored = scan_body(stamp=4.0)
    g = gate({"u1": 4.0}, lambda unit, stamp: (12, stored))
    g._max_beams = 2  # the server restarted with a lower beam limit than it journaled under
    check = g.open_group()
    refused = check.admit([scan(4.0)])
    assert isinstance(refused, IngestError) and refused.status == 409
    assert isinstance(check.admit([scan(4.0, "u2")]), list)  # the group goes on
