"""When the map service saves its next snapshot.

A snapshot bounds start-up: it loads the newest snapshot and replays the journal after
it. ``journal.snapshot_every_scans`` and ``snapshot_every_seconds`` say how much may lie
after it; but a snapshot's cost grows with the grid, not with the scans: on a 4,000 x
2,000 grid at 5,000 scans/s (``scenarios/thousand_units.yaml``) the 2,000-scan rule asked
for one every 0.4 s while one took seconds to copy, checksum and write, so a snapshot
thread ran all the time and took about 40 % of the server's CPU from fusion and ingest.
``snapshot_max_share`` caps that: a snapshot that took ``s`` seconds to save is followed by
the next no sooner than ``s / snapshot_max_share`` seconds after it began (the share of
wall time spent saving snapshots stays at most ``snapshot_max_share``), so at such rates
more scans lie after each snapshot (start-up replays more of them), and the server keeps
its cores for the scans it is sent. At ordinary rates the scan and time rules decide, as
before.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SnapshotSchedule:
    """every_scans: scans after the last snapshot that make the next due; every_seconds
    [s]: wall time after it that does (with at least one scan); max_share: in (0, 1], the
    most of the wall time saving snapshots may take."""

    every_scans: int
    every_seconds: float
    max_share: float

    def __post_init__(self) -> None:
        if not 0.0 < self.max_share <= 1.0:
            raise ValueError(f"max_share must be in (0, 1], got {self.max_share!r}")

    def due(self, scans_since: int, seconds_since: float, last_save_seconds: float) -> bool:
        """Whether to take a snapshot now: ``scans_since`` scans fused and
        ``seconds_since`` [s] passed since the last one began, which took
        ``last_save_seconds`` [s] to save (0 before the first)."""
        if scans_since <= 0 or seconds_since < last_save_seconds / self.max_share:
            return False
        return scans_since >= self.every_scans or seconds_since >= self.every_seconds
