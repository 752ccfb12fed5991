"""The single-server lock of a data directory: ``flock`` on files in it.

The map server holds an exclusive lock on ``server.lock`` and on the journal file itself
for its lifetime, so deleting ``server.lock`` does not let a second server in: the
journal's inode is the one both would write. The ``fleetmap journal`` commands take a
shared lock on the journal file (``shared=True``): any number of them may read, and none
runs beside a server.

``flock`` locks (BSD) and SQLite's ``fcntl`` record locks (POSIX) are independent on
Linux. One caution from POSIX locks: closing *any* descriptor of a file drops the whole
process's ``fcntl`` locks on it, SQLite's included, so a lock here is released only after
the journal connections of this process on that file are closed.
"""

from __future__ import annotations

import fcntl
import os
from collections.abc import Sequence
from pathlib import Path

from mapserver.core.errors import FleetmapError


class LockBusy(FleetmapError, RuntimeError):
    """Another holder has one of the files locked; ``path`` names it."""

    def __init__(self, path: Path) -> None:
        super().__init__(f"{path} is locked by another process")
        self.path = path


class FileLocks:
    """Non-blocking ``flock`` on each of ``paths`` (all or none), held until ``close``.

    shared: a shared lock (readers) instead of an exclusive one (the server).
    create: create a missing file (empty) instead of raising FileNotFoundError.
    Raises LockBusy when another open file holds a conflicting lock.
    """

    def __init__(self, paths: Sequence[Path], *, shared: bool = False, create: bool = True):
        self._fds: list[int] = []
        flags = os.O_RDWR | os.O_CREAT if create else os.O_RDONLY
        operation = (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB
        try:
            for path in paths:
                fd = os.open(path, flags | os.O_CLOEXEC, 0o644)
                self._fds.append(fd)
                try:
                    fcntl.flock(fd, operation)
                except BlockingIOError:
                    raise LockBusy(Path(path)) from None
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Release every lock (idempotent)."""
        while self._fds:
            os.close(self._fds.pop())

    def __del__(self) -> None:  # an owner that failed half-way still lets go
        self.close()

    def __enter__(self) -> FileLocks:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
