"""Awaiting futures another thread completes in bursts, with one wake-up of the event
loop per burst.

``asyncio.wrap_future`` wakes the event loop once per future (``call_soon_threadsafe``:
a write to the loop's self-pipe, then the loop's turn to read it), and the writing thread
releases and takes back the GIL for each write. The map service answers a fused group of
scans at once, up to hundreds of futures in a row: under a hundred units' load each of
those hand-offs waited for the busy event loop to let go of the GIL. Here the futures
completed in a row are handed to the loop together: the first completion schedules one
``_settle`` and the ones that come before it runs join it.

Unlike ``wrap_future``, cancelling the awaitable does not cancel the concurrent future
(the map service answers every submission it queued; its answer is then dropped).
"""

from __future__ import annotations

import asyncio
import threading
import weakref
from collections import deque
from concurrent.futures import Future

_BRIDGES: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, FutureBridge] = (
    weakref.WeakKeyDictionary()
)
_BRIDGES_LOCK = threading.Lock()


class FutureBridge:
    """Hands completed concurrent futures to one event loop's awaitables, in bursts. It
    holds its loop weakly: ``bridge_for`` keeps a bridge per loop, and a strong reference
    from the bridge would keep every loop it ever served alive."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop_ref = weakref.ref(loop)
        self._completed: deque[tuple[Future, asyncio.Future]] = deque()
        self._lock = threading.Lock()
        self._scheduled = False
        self.wakeups = 0  # times the loop was woken (``call_soon_threadsafe``)

    def wrap(self, future: Future) -> asyncio.Future:
        """An awaitable on this bridge's loop with ``future``'s result or exception (call
        from the loop's thread)."""
        loop = asyncio.get_running_loop()
        if loop is not self._loop_ref():
            raise RuntimeError("FutureBridge.wrap: called from another loop than the bridge's")
        waiter = loop.create_future()
        future.add_done_callback(lambda done: self._complete(done, waiter))
        return waiter

    def _complete(self, future: Future, waiter: asyncio.Future) -> None:
        """``future`` is done (called in the thread that completed it): queue it, and wake
        the loop unless a wake-up is already on its way."""
        self._completed.append((future, waiter))
        with self._lock:
            if self._scheduled:
                return
            self._scheduled = True
            self.wakeups += 1
        loop = self._loop_ref()
        try:
            if loop is None:
                raise RuntimeError("the loop is gone")
            loop.call_soon_threadsafe(self._settle)
        except RuntimeError:  # the loop is closed or gone: nobody awaits these any more
            with self._lock:
                self._scheduled = False
                self._completed.clear()

    def _settle(self) -> None:
        """On the loop: give every queued awaitable its future's outcome. The flag is
        cleared first, so a completion queued after the loop below ends schedules anew."""
        with self._lock:
            self._scheduled = False
        while self._completed:
            future, waiter = self._completed.popleft()
            if waiter.done():  # cancelled: the request went away
                continue
            if future.cancelled():
                waiter.cancel()
            elif (exc := future.exception()) is not None:
                waiter.set_exception(exc)
            else:
                waiter.set_result(future.result())


def bridge_for(loop: asyncio.AbstractEventLoop) -> FutureBridge:
    """The bridge of ``loop`` (made on first use; dropped with the loop)."""
    with _BRIDGES_LOCK:
        bridge = _BRIDGES.get(loop)
        if bridge is None:
            bridge = _BRIDGES[loop] = FutureBridge(loop)
        return bridge


def wrap_in_bursts(future: Future) -> asyncio.Future:
    """``asyncio.wrap_future`` for the running loop, waking it once per burst of
    completions (see the module docstring)."""
    return bridge_for(asyncio.get_running_loop()).wrap(future)
