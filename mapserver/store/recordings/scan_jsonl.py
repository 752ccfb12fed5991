"""Scan files (``*.jsonl``, docs/http-api.md 2.1 per line) as a recording, streamed."""

from __future__ import annotations

from collections.abc import Iterator

from mapserver.core.scan import Scan
from mapserver.store.recordings.base import Recording
from mapserver.store.scanfile import parse_scan_lines


class ScanFileRecording(Recording):
    """A JSONL scan file, line by line; ``start``/``end`` count from its first scan's
    stamp; ``unit_id`` (when given) replaces each scan's own. Bad lines raise
    ``ScanFileError`` naming the file, the line and the field."""

    def __iter__(self) -> Iterator[Scan]:
        first: float | None = None
        with self.path.open(encoding="utf-8") as handle:
            for scan in parse_scan_lines(handle, str(self.path)):
                first = scan.stamp if first is None else first
                if not self.options.within(scan.stamp - first):
                    continue
                yield self._relabelled(scan)

    def _relabelled(self, scan: Scan) -> Scan:
        unit_id = self.options.unit_id
        if unit_id is None or unit_id == scan.unit_id:
            return scan
        return Scan.from_dict({**scan.to_dict(), "unit_id": unit_id})

    def scan_count(self) -> int | None:
        with self.path.open("rb") as handle:
            return sum(1 for line in handle if line.strip())

    def describe(self) -> str:
        return f"{self.path}: scan file (JSONL)"
