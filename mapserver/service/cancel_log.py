"""``CancelledRequestFilter``: uvicorn's traceback of a request it cancelled itself is
dropped.

On SIGTERM uvicorn gives requests in flight ``server.shutdown_timeout_s`` [s], then
cancels those still running and logs one line, ``Cancel N running task(s), timeout
graceful shutdown exceeded``. Each cancelled request's ``CancelledError`` then reaches
uvicorn's ASGI wrapper, which logs it as ``Exception in ASGI application`` with a
traceback of some 40 lines. Whether those get logged before the process exits is a race
that Python 3.12's ``asyncio.wait_for`` (no inner task any more) wins: 10 slow clients
gave 10 tracebacks there and none on 3.11. The one line says it all, so this filter,
on the ``uvicorn.error`` logger, drops the records whose exception is a cancellation.
"""

from __future__ import annotations

import asyncio
import logging

UVICORN_ERROR_LOGGER = "uvicorn.error"


class CancelledRequestFilter(logging.Filter):
    """Passes every record but one logged with an ``asyncio.CancelledError``."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        return not isinstance(exc, asyncio.CancelledError)


def install(logger_name: str = UVICORN_ERROR_LOGGER) -> CancelledRequestFilter:
    """Put a ``CancelledRequestFilter`` on the named logger (its records, whichever
    handler they reach), once however often it is called; returns it."""
    logger = logging.getLogger(logger_name)
    for existing in logger.filters:
        if isinstance(existing, CancelledRequestFilter):
            return existing
    quiet = CancelledRequestFilter()
    logger.addFilter(quiet)
    return quiet
