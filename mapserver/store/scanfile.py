"""Scan files (``*.jsonl``): one docs/http-api.md 2.1 scan object per line.

``read_scan_file`` validates every line before returning anything, so a caller that
writes outputs only after it returns never leaves a half-written result behind.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from pathlib import Path

from mapserver.core.errors import FleetmapError
from mapserver.core.scan import DEFAULT_MAX_BEAMS, Scan, ScanError


class ScanFileError(FleetmapError, ValueError):
    """A line of a scan file is not a valid scan; names the file, line and field."""

    def __init__(self, path: Path | str, line: int, field: str, detail: str) -> None:
        self.path, self.line, self.field = str(path), line, field
        super().__init__(f"{path}:{line}: {field}: {detail}")


def parse_scan_lines(
    lines: Iterable[str], source: str = "<scans>", max_beams: int = DEFAULT_MAX_BEAMS
) -> Iterator[Scan]:
    """Parse scan lines (blank lines skipped); raises ScanFileError at the first bad line."""
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            data = json.loads(line)  # accepts Infinity/NaN tokens, as Python writes them
        except json.JSONDecodeError as exc:
            raise ScanFileError(source, number, "json", f"not valid JSON ({exc.msg})") from None
        try:
            yield Scan.from_dict(data, max_beams=max_beams)
        except ScanError as exc:
            raise ScanFileError(source, number, exc.field, str(exc)) from None


def read_scan_file(path: Path | str, max_beams: int = DEFAULT_MAX_BEAMS) -> list[Scan]:
    """All scans of a JSONL file, validated; raises ScanFileError or OSError."""
    path = Path(path)
    with path.open(encoding="utf-8") as handle:
        return list(parse_scan_lines(handle, str(path), max_beams))


def write_scan_file(path: Path | str, scans: Iterable[Scan]) -> int:
    """Write scans as JSONL (no-return beams as ``Infinity``); returns the count."""
    count = 0
    with Path(path).open("w", encoding="utf-8") as handle:
        for scan in scans:
            handle.write(json.dumps(scan.to_dict(), separators=(",", ":")) + "\n")
            count += 1
    return count
