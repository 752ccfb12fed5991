"""``cancel_log``: a request cancelled at the shutdown deadline logs no traceback."""

from __future__ import annotations

import asyncio
import logging

from mapserver.service.cancel_log import CancelledRequestFilter, install


def record(exc: BaseException | None) -> logging.LogRecord:
    info = (type(exc), exc, None) if exc is not None else None
    return logging.LogRecord("uvicorn.error", logging.ERROR, __file__, 1, "Exception in ASGI "
                             "application\n", None, info)  # fmt: skip


def test_a_cancellation_is_dropped_and_every_other_record_passes():
    quiet = CancelledRequestFilter()
    assert quiet.filter(record(asyncio.CancelledError("timeout graceful shutdown"))) is False
    assert quiet.filter(record(ValueError("a bug"))) is True
    assert quiet.filter(record(None)) is True


def test_install_puts_one_filter_on_the_logger_however_often_it_runs():
    logger = logging.getLogger("test_cancel_log.uvicorn")
    first = install(logger.name)
    assert install(logger.name) is first
    assert [f for f in logger.filters if isinstance(f, CancelledRequestFilter)] == [first]
    logger.removeFilter(first)
