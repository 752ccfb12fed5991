"""Reading a journal back as the server does at start-up and ``fleetmap replay`` does:
each record parsed and validated, in seq order, so that a damaged record is set aside
rather than stopping the reader or entering the map.

The clock rule (``mapserver.service.map_clock``) judged each scan when it arrived, and
the journal holds the scans it accepted, so replaying them all rebuilds the map
(docs/map-time.md, "Replay and restart"). Only a stamp still ahead of the wall clock
(``not_after``) cannot have been accepted by any rule: a journal written before the
clock rule existed. It is set aside like a damaged record (``ahead``)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

from mapserver.core.scan import DEFAULT_MAX_BEAMS, Scan, ScanError
from mapserver.store.journal import Journal, RecordError


@dataclass(frozen=True)
class ReadRecord:
    """One journal record read back: its ``scan``, or None and the ``problem`` that sets
    it aside (``ahead`` when the problem is a stamp ahead of the wall clock, not damage)."""

    seq: int
    unit_id: str
    scan: Scan | None
    problem: str | None = None
    ahead: bool = False


def read_records(
    journal: Journal,
    after: int = 0,
    until: float | None = None,
    max_beams: int = DEFAULT_MAX_BEAMS,
    not_after: float = math.inf,
) -> Iterator[ReadRecord]:
    """The records after seq ``after`` (stamps <= ``until`` [s] when given); a stamp past
    ``not_after`` [s] (the wall clock now plus the clock's lead) is set aside."""
    for record in journal.records_after(after, until_stamp=until):
        try:
            scan = Scan.from_dict(
                record.fields(), max_beams, float32_ranges=not record.float64_ranges
            )
        except (RecordError, ScanError) as exc:
            yield ReadRecord(record.seq, record.unit_id, None, str(exc))
            continue
        if scan.stamp > not_after:
            problem = (
                f"stamp: {scan.stamp!r} is ahead of the server's clock at start-up "
                f"({not_after!r} s with the clock's lead): journaled before the clock rule"
            )
            yield ReadRecord(record.seq, scan.unit_id, None, problem, ahead=True)
            continue
        yield ReadRecord(record.seq, scan.unit_id, scan)
