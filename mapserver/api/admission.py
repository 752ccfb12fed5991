"""Admission of heavy reads (queries, plans): they compute on worker threads of their
own, a bounded number at a time, and past a bounded queue they are refused at once with
429 and ``Retry-After`` rather than pile up, so that scan ingest and ``/healthz``, which
run on the event loop and the ingest thread, keep their pace whatever readers do.

The workers run at a lower CPU priority (``nice``, Linux: a thread is a task with its
own nice value), so on a machine with fewer cores than busy threads the scheduler gives
ingest the CPU first; a read still gets every cycle ingest does not need."""

from __future__ import annotations

import asyncio
import logging
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from fastapi import HTTPException

logger = logging.getLogger(__name__)
MAX_REST_S = 5.0  # [s] the longest a turn rests after a call, however long it took

T = TypeVar("T")


class Admission:
    """At most ``running`` calls of ``run`` compute at once and ``waiting`` wait for a
    turn; a call beyond both is refused (429) naming ``what`` and the bound.

    retry_after_s: [s] the ``Retry-After`` of a refusal.
    nice: how much lower the workers' CPU priority is (0: the same as ingest's).
    busy_share: the share of time a turn may compute (0 < share <= 1): a call that took
        t [s] keeps its turn for ``t * (1 / busy_share - 1)`` more after answering, so
        back-to-back reads hold Python's GIL, which ingest and the event loop also need,
        at most this share of the time (a nice value cannot share the GIL).
    ``close()`` stops the workers.
    """

    def __init__(
        self,
        what: str,
        running: int,
        waiting: int,
        retry_after_s: int,
        nice: int = 0,
        busy_share: float = 1.0,
    ) -> None:
        if running < 1 or waiting < 0:
            raise ValueError(f"running must be >= 1 and waiting >= 0, got {running}, {waiting}")
        if not 0 < busy_share <= 1:
            raise ValueError(f"busy_share must be in (0, 1], got {busy_share!r}")
        self.busy_share = float(busy_share)
        self._workers = ThreadPoolExecutor(
            running, thread_name_prefix=f"fleetmap-{what}", initializer=_lower_priority,
            initargs=(nice,),
        )  # fmt: skip
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
            raise too_many(
                f"{self.what}: the server is busy ({self.running} computing and "
                f"{self.waiting} waiting at most); retry after {self.retry_after_s} s",
                self.retry_after_s,
            )
        if self._turns is None:
            self._turns = asyncio.Semaphore(self.running)
        self.admitted += 1
        loop = asyncio.get_running_loop()
        try:
            await self._turns.acquire()
            start = time.perf_counter()
            try:
                return await loop.run_in_executor(self._workers, work)
            finally:
                rest = (time.perf_counter() - start) * (1.0 / self.busy_share - 1.0)
                loop.call_later(min(rest, MAX_REST_S), self._turns.release)
        finally:
            self.admitted -= 1

    def close(self) -> None:
        """Stop the workers once they finish what they compute."""
        self._workers.shutdown(wait=True, cancel_futures=True)


def too_many(detail: str, retry_after_s: int) -> HTTPException:
    """The server's 429 (for heavy reads here, for scans past a budget in
    ``ingest_budget``): ``detail`` and ``Retry-After`` in whole seconds (at least 1)."""
    return HTTPException(429, detail, headers={"Retry-After": str(max(1, int(retry_after_s)))})


def _lower_priority(nice: int) -> None:
    """Lower the calling thread's CPU priority by ``nice`` (where the OS allows it)."""
    if nice <= 0:
        return
    try:
        current = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), min(19, current + nice))
    except (AttributeError, OSError) as exc:  # not Linux, or not permitted: same priority
        logger.info("heavy reads run at the normal priority (%s)", exc)
