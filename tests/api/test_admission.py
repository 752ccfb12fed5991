"""Admission of heavy reads: a bounded number compute, a bounded number wait, the rest
are refused at once with 429 and Retry-After; workers run at a lower CPU priority."""

import asyncio
import os
import threading

import pytest
from fastapi import HTTPException

from mapserver.api.admission import Admission


def test_past_running_and_waiting_a_call_is_refused_with_retry_after():
    admission = Admission("plan", running=1, waiting=1, retry_after_s=2, nice=0)
    release = threading.Event()

    async def scenario():
        first = asyncio.ensure_future(admission.run(release.wait))
        second = asyncio.ensure_future(admission.run(lambda: "second"))
        await asyncio.sleep(0.05)
        assert admission.admitted == 2  # one computing, one waiting
        with pytest.raises(HTTPException) as refused:
            await admission.run(lambda: "third")
        release.set()
        return refused.value, await first, await second

    refused, first, second = asyncio.run(scenario())
    admission.close()
    assert refused.status_code == 429 and refused.headers == {"Retry-After": "2"}
    assert refused.detail.startswith("plan: the server is busy (1 computing and 1 waiting")
    assert (first, second) == (True, "second")
    assert (admission.admitted, admission.refused) == (0, 1)


def test_workers_run_at_the_lower_priority():
    admission = Admission("query", running=1, waiting=0, retry_after_s=1, nice=7)
    mine = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

    def priority():
        return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

    assert asyncio.run(admission.run(priority)) == min(19, mine + 7)
    admission.close()


def test_bad_bounds_are_refused():
    with pytest.raises(ValueError, match="running must be >= 1"):
        Admission("query", running=0, waiting=1, retry_after_s=1)
