"""Progress lines for long work, whether or not the output is a terminal.

A log file or a pipe (CI, ``docker logs``, ``| tee``) shows no progress bar, and a
comparison's first run may take a minute to finish: ``RunProgress`` prints a line as each
run finishes and, between them, a heartbeat every ``every_s`` seconds (``3/9 runs done,
1 m 20 s``); ``SimProgress`` prints one run's simulated time now and then. Every line is
flushed at once. Times are wall-clock seconds from ``clock`` (``time.monotonic``).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, TextIO

if TYPE_CHECKING:  # parallel imports the scenario spec, and so the simulator
    from scenarios.sweep.parallel import RunResult

DEFAULT_EVERY_S = 10.0
"""[s] the longest silence between two progress lines."""


def elapsed(seconds: float) -> str:
    """``45 s``, ``1 m 20 s``, ``2 h 05 m`` for a duration [s]."""
    whole = int(seconds)
    if whole < 60:
        return f"{whole} s"
    if whole < 3600:
        return f"{whole // 60} m {whole % 60:02d} s"
    return f"{whole // 3600} h {whole % 3600 // 60:02d} m"


class RunProgress:
    """``on_result`` and ``on_wait`` for ``run_sweep``: ``[k/total] <run> ok (12.3 s)``
    (or ``FAILED: <error>``) as each run finishes, and ``... k/total runs done, <time>``
    when ``every_s`` [s] passed with no line; on ``stream`` (default stderr)."""

    def __init__(
        self,
        total: int,
        stream: TextIO | None = None,
        every_s: float = DEFAULT_EVERY_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.total = total
        self.stream = stream
        self.every_s = every_s
        self.clock = clock
        self.finished = 0
        self.start = self.last_line = clock()

    def __call__(self, result: RunResult) -> None:
        self.finished += 1
        state = "ok" if result.status == "ok" else f"FAILED: {result.error}"
        self._say(f"[{self.finished}/{self.total}] {result.run.label()} {state} "
                  f"({result.wall_seconds:.1f} s)")  # fmt: skip

    def tick(self) -> None:
        """A heartbeat line if ``every_s`` passed since the last line (call it often)."""
        if self.clock() - self.last_line >= self.every_s:
            self._say(f"... {self.finished}/{self.total} runs done, "
                      f"{elapsed(self.clock() - self.start)}")  # fmt: skip

    def _say(self, line: str) -> None:
        print(line, file=self.stream or sys.stderr, flush=True)
        self.last_line = self.clock()


class SimProgress:
    """A ``(now, total)`` progress callback for one run that prints ``<label>: 60/180 s
    simulated, 20 s`` (sim seconds, then wall time) at most every ``every_s`` [s] of wall
    time, and once at the end (``now >= total``); for a stream that is not a terminal.
    Its lines are whole: ``line_open`` is always False."""

    line_open = False

    def __init__(
        self,
        label: str,
        stream: TextIO | None = None,
        every_s: float = DEFAULT_EVERY_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.label = label
        self.stream = stream
        self.every_s = every_s
        self.clock = clock
        self.start = self.last_line = clock()

    def __call__(self, now: float, total: float) -> None:
        wall = self.clock()
        if wall - self.last_line >= self.every_s or now >= total:
            print(f"{self.label}: {now:.0f}/{total:.0f} s simulated, "
                  f"{elapsed(wall - self.start)}", file=self.stream or sys.stderr,
                  flush=True)  # fmt: skip
            self.last_line = wall


class TerminalBar:
    """A ``(now, total)`` progress callback drawing ``<label> [####   ]  60.0/180 s`` in
    place on a terminal ``stream`` (default stderr), ``width`` characters of bar; the line
    ends at ``now >= total``. ``line_open``: a bar is drawn and its line not ended (what
    prints next must start a line first)."""

    def __init__(self, label: str, width: int, stream: TextIO | None = None) -> None:
        self.label = label
        self.width = width
        self.stream = stream
        self.line_open = False

    def __call__(self, now: float, total: float) -> None:
        stream = self.stream or sys.stderr
        done = min(1.0, now / total) if total > 0 else 1.0
        bar = "#" * int(done * self.width)
        print(f"\r{self.label} [{bar:<{self.width}}] {now:6.1f}/{total:.0f} s", end="",
              file=stream, flush=True)  # fmt: skip
        self.line_open = done < 1.0
        if not self.line_open:
            print(file=stream, flush=True)
