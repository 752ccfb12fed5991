"""Reading a journal back as the server does at start-up and ``fleetmap replay`` does:
each record parsed and checked against the fleet clock's rule (``fleet_clock``), in seq
order, so that a damaged record or a stamp that breaks the rule is set aside rather
than stopping the reader or entering the map."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from mapserver.core.scan import DEFAULT_MAX_BEAMS, Scan, ScanError
from mapserver.service.fleet_clock import FleetClock
from mapserver.store.journal import Journal, RecordError


@dataclass(frozen=True)
class ReadRecord:
    """One journal record read back: its ``scan``, or None and the ``problem`` that sets
    it aside (``clock_lead`` when the problem is the clock rule, not damage)."""

    seq: int
    unit_id: str
    scan: Scan | None
    problem: str | None = None
    clock_lead: bool = False


def read_records(
    journal: Journal,
    clock: FleetClock,
    after: int = 0,
    until: float | None = None,
    max_beams: int = DEFAULT_MAX_BEAMS,
) -> Iterator[ReadRecord]:
    """The records after seq ``after`` (stamps <= ``until`` [s] when given). ``clock``
    first hears the scans up to ``after`` (what the server had heard then) and then
    every scan yielded with a ``scan``."""
    for unit_id, stamp in journal.recent_units(after, clock.window_scans):
        clock.observe(unit_id, stamp)
    for record in journal.records_after(after, until_stamp=until):
        try:
            body = record.body()
            scan = Scan.from_dict(body, max_beams, float32_ranges=not record.float64_ranges)
        except (RecordError, ScanError) as exc:
            yield ReadRecord(record.seq, record.unit_id, None, str(exc))
            continue
        lead = clock.check(scan.stamp)
        if lead is not None:
            yield ReadRecord(record.seq, scan.unit_id, None, f"stamp: {lead.describe()}", True)
            continue
        clock.observe(scan.unit_id, scan.stamp)
        yield ReadRecord(record.seq, scan.unit_id, scan)
