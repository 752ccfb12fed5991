"""``RateLimitFilter``: a logging filter that passes at most ``burst`` records per message
template per ``interval_s`` seconds, and says how many it dropped.

A flood of bad requests logs one warning each (uvicorn's "Invalid HTTP request
received." is one line per request): 3,000 such requests wrote 123 kB of log, and a
steady stream fills a disk. A template is the record's logger and its unformatted
message (``record.msg``), so "scan from %s refused" counts as one whatever the unit.
When a template's interval is over, its next record is preceded by one line
``suppressed K similar messages in the last S s: <template>`` (at the next record, as
journald does: a flood that stops is summed up when the template logs again).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

SUMMARY = "fleetmap_rate_summary"  # the attribute that marks a summary record
MAX_TEMPLATES = 1000  # past this many, templates idle for an interval are forgotten


@dataclass
class _Window:
    start: float  # [s] clock time the interval began
    passed: int = 1
    suppressed: int = 0


class RateLimitFilter(logging.Filter):
    """At most ``burst`` records per template per ``interval_s`` [s] (see the module)."""

    def __init__(
        self, burst: int, interval_s: float, clock: Callable[[], float] = time.monotonic
    ) -> None:
        super().__init__()
        if burst < 1 or not interval_s > 0:
            raise ValueError(f"burst must be >= 1 and interval_s > 0, got {burst}, {interval_s}")
        self.burst = burst
        self.interval_s = interval_s
        self.clock = clock
        self._windows: dict[tuple[str, str], _Window] = {}

    def filter(self, record: logging.LogRecord) -> bool:
        if getattr(record, SUMMARY, False):
            return True
        key = (record.name, str(record.msg))
        now = self.clock()
        window = self._windows.get(key)
        if window is not None and now - window.start < self.interval_s:
            if window.passed < self.burst:
                window.passed += 1
                return True
            window.suppressed += 1
            return False
        if len(self._windows) >= MAX_TEMPLATES:
            self._forget_idle(now)
        self._windows[key] = _Window(now)
        if window is not None and window.suppressed:
            self._summarise(record, window.suppressed, now - window.start)
        return True

    def _summarise(self, record: logging.LogRecord, suppressed: int, seconds: float) -> None:
        logging.getLogger(record.name).log(
            record.levelno,
            "suppressed %d similar messages in the last %.0f s: %s",
            suppressed,
            seconds,
            record.msg,
            extra={SUMMARY: True},
        )

    def _forget_idle(self, now: float) -> None:
        for key in [k for k, w in self._windows.items() if now - w.start >= self.interval_s]:
            del self._windows[key]


def install(burst: int, interval_s: float, logger_names: Iterable[str]) -> int:
    """Give every handler of the named loggers a RateLimitFilter of its own; returns how
    many handlers got one."""
    count = 0
    for name in logger_names:
        for handler in logging.getLogger(name or None).handlers:
            handler.addFilter(RateLimitFilter(burst, interval_s))
            count += 1
    return count
