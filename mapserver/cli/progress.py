"""A progress line for long work over scans, on stderr.

On a terminal the line is redrawn in place at most every ``every_s``; elsewhere (a log,
CI) a line is written at most every ``quiet_every_s``. The last line, with the count
reached, is always written by ``finish``.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


class ScanProgress:
    """``progress(done, total)`` for ``fuse_all`` and the importers; ``label`` leads the
    line (``fused``, ``sent``); total None: unknown (no percentage)."""

    def __init__(
        self,
        label: str,
        stream: TextIO | None = None,
        every_s: float = 0.2,
        quiet_every_s: float = 10.0,
    ) -> None:
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.interactive = self.stream.isatty()
        self.every_s = every_s if self.interactive else quiet_every_s
        self.started = time.perf_counter()
        self._last_shown = self.started
        self._done = 0
        self._total: int | None = None

    def __call__(self, done: int, total: int | None) -> None:
        self._done, self._total = done, total
        now = time.perf_counter()
        if now - self._last_shown >= self.every_s:
            self._last_shown = now
            self._show(end="" if self.interactive else "\n")

    def line(self) -> str:
        """The progress line: count, share of the total when known, rate [scans/s]."""
        elapsed = time.perf_counter() - self.started
        rate = self._done / elapsed if elapsed > 0 else 0.0
        if self._total:
            share = f"/{self._total} scans ({100 * self._done / self._total:.0f} %)"
        else:
            share = " scans"
        return f"{self.label} {self._done}{share}, {rate:,.0f} scans/s"

    def finish(self) -> None:
        """Write the final line (always, whatever the interval)."""
        self._show(end="\n")

    def _show(self, end: str) -> None:
        lead = "\r" if self.interactive else ""
        print(lead + self.line(), end=end, file=self.stream, flush=True)
