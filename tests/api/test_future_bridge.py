"""The future bridge: every awaitable gets its future's outcome, and a burst of
completions from another thread wakes the event loop once."""

from __future__ import annotations

import asyncio
import gc
import threading
import weakref
from collections import deque
from concurrent.futures import Future

import pytest

from mapserver.api.future_bridge import FutureBridge, bridge_for, wrap_in_bursts


def complete_in_thread(futures: list[Future], outcomes: list[object]) -> None:
    """Complete ``futures`` with ``outcomes`` (an exception instance is raised) from
    another thread, and wait for it: the caller's loop cannot run meanwhile."""

    def work() -> None:
        for future, outcome in zip(futures, outcomes, strict=True):
            if isinstance(outcome, BaseException):
                future.set_exception(outcome)
            else:
                future.set_result(outcome)

    thread = threading.Thread(target=work)
    thread.start()
    thread.join()


def test_a_burst_of_completions_wakes_the_loop_once_and_each_waiter_gets_its_outcome():
    async def main() -> tuple[list[object], int]:
        bridge = FutureBridge(asyncio.get_running_loop())
        futures = [Future() for _ in range(100)]
        waiters = [bridge.wrap(f) for f in futures]
        outcomes: list[object] = [
            ValueError(f"refused {i}") if i % 7 == 3 else {"seq": i} for i in range(100)
        ]
        complete_in_thread(futures, outcomes)
        got = await asyncio.gather(*waiters, return_exceptions=True)
        return [repr(g) if isinstance(g, BaseException) else g for g in got], bridge.wakeups

    got, wakeups = asyncio.run(main())
    assert got == [
        repr(ValueError(f"refused {i}")) if i % 7 == 3 else {"seq": i} for i in range(100)
    ]
    assert wakeups == 1


def test_a_completion_after_the_loop_settled_wakes_it_again():
    async def main() -> tuple[list[int], int]:
        bridge = FutureBridge(asyncio.get_running_loop())
        first, second = Future(), Future()
        waiters = [bridge.wrap(first), bridge.wrap(second)]
        complete_in_thread([first], [1])
        assert await waiters[0] == 1
        complete_in_thread([second], [2])
        return [await waiters[1]], bridge.wakeups

    got, wakeups = asyncio.run(main())
    assert got == [2]
    assert wakeups == 2


def test_a_cancelled_waiter_is_skipped_and_the_others_still_settle():
    async def main() -> tuple[bool, int]:
        bridge = FutureBridge(asyncio.get_running_loop())
        gone, kept = Future(), Future()
        gone_waiter, kept_waiter = bridge.wrap(gone), bridge.wrap(kept)
        gone_waiter.cancel()
        complete_in_thread([gone, kept], ["dropped", 7])
        return gone.result() == "dropped", await kept_waiter

    assert asyncio.run(main()) == (True, 7)


def test_a_future_done_before_it_is_wrapped_and_a_cancelled_one():
    async def main() -> tuple[int, bool]:
        done, cancelled = Future(), Future()
        done.set_result(5)
        cancelled.cancel()
        value = await wrap_in_bursts(done)
        waiter = wrap_in_bursts(cancelled)
        with pytest.raises(asyncio.CancelledError):
            await waiter
        return value, waiter.cancelled()

    assert asyncio.run(main()) == (5, True)


def test_each_loop_has_its_own_bridge():
    async def bridge_of_running_loop() -> FutureBridge:
        loop = asyncio.get_running_loop()
        assert bridge_for(loop) is bridge_for(loop)
        return bridge_for(loop)

    assert asyncio.run(bridge_of_running_loop()) is not asyncio.run(bridge_of_running_loop())


def test_a_bridge_lets_its_loop_go_and_drops_what_completes_after():
    loop = asyncio.new_event_loop()
    bridge = bridge_for(loop)
    future = Future()
    waiter = loop.run_until_complete(_wrap_on(bridge, future))
    loop.close()
    future.set_result(1)  # the loop is closed: nothing to wake, nothing kept
    assert bridge._completed == deque() and not waiter.done()
    ref = weakref.ref(loop)
    del waiter, future, loop  # the request's own references go with it
    gc.collect()
    assert ref() is None  # the per-loop table does not keep a loop alive


async def _wrap_on(bridge: FutureBridge, future: Future) -> asyncio.Future:
    return bridge.wrap(future)


def test_wrapping_on_another_loop_than_the_bridges_is_refused():
    async def main() -> None:
        other = FutureBridge(asyncio.new_event_loop())
        with pytest.raises(RuntimeError, match="another loop"):
            other.wrap(Future())

    asyncio.run(main())
