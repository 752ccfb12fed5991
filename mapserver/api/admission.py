"""Admission of heavy reads (queries, plans): they compute on worker threads, a bounded
number at a time, and past a bounded queue they are refused at once with 429 and
``Retry-After`` rather than pile up, so that scan ingest and ``/healthz``, which run on
the event loop, keep their pace whatever readers do."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import TypeVar

import anyio.to_thread
from fastapi import HTTPException

T = TypeVar("T")


class Admission:
    """At most ``running`` calls of ``run`` compute at once and ``waiting`` wait for a
    turn; a call beyond both is refused (429) naming ``what`` and the bound.

    retry_after_s: [s] the ``Retry-After`` of a refusal.
    """

    def __init__(self, what: str, running: int, waiting: int, retry_after_s: int) -> None:
        if running < 1 or waiting < 0:
            raise ValueError(f"running must be >= 1 and waiting >= 0, got {running}, {waiting}")
        self.what = what
        self.running = running
        self.waiting = waiting
        self.retry_after_s = retry_after_s
        self.admitted = 0  # calls inside (running or waiting) now
        self.refused = 0  # calls refused so far
        self._turns: asyncio.Semaphore | None = None  # made on the event loop

    async def run(self, work: Callable[[], T]) -> T:
        """``work()`` on a worker thread once it has a turn; 429 when the queue is full."""
        if self.admitted >= self.running + self.waiting:
            self.refused += 1
            raise HTTPException(
                429,
                f"{self.what}: the server is busy ({self.running} computing and "
                f"{self.waiting} waiting at most); retry after {self.retry_after_s} s",
                headers={"Retry-After": str(self.retry_after_s)},
            )
        if self._turns is None:
            self._turns = asyncio.Semaphore(self.running)
        self.admitted += 1
        try:
            async with self._turns:
                return await anyio.to_thread.run_sync(work)
        finally:
            self.admitted -= 1
