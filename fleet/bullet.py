"""PyBullet, the simulator's one optional dependency, imported in this one place.

PyBullet is the ``sim`` extra (``pip install 'fleetmap[sim]'``): it has wheels for
Python up to 3.11 only, so the map server, client, planner and ``map build`` never need
it. ``load_pybullet()`` imports it and returns the module; without it, it raises
``SimulatorMissing``, whose message says how to install it, and which ``fleetmap`` prints
as its one-line error (``scenarios.cli.main``).

PyBullet's C code prints ``pybullet build time: ...`` (on standard error) when it is
first imported. ``load_pybullet`` points file descriptors 1 and 2 at ``os.devnull``
around the import (flushing C's stdio buffers before pointing them back, and restoring
them even when the import fails), so no command prints it. Meanwhile whatever another
thread writes to either is lost too, so import the simulator before starting threads
(``fleetmap run`` and the sweep's workers import it before anything else runs).
"""

from __future__ import annotations

import ctypes
import importlib
import os
import sys
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from types import ModuleType

from mapserver.core.errors import FleetmapError

INSTALL_HINT = (
    "the simulator needs pybullet, which is not installed: pip install 'fleetmap[sim]' "
    "(pybullet has wheels for Python 3.11{source})"
)
"""The message of ``SimulatorMissing``; ``{source}`` is ``SOURCE_BUILD`` on Python 3.12+."""
SOURCE_BUILD = "; on {version} pip builds it from source, which needs a C++ compiler"
"""The hint's tail where no wheel exists; ``{version}`` is the running ``Python 3.x``."""
QUIET_FDS = (1, 2)
"""Standard output and error: PyBullet prints its banner on standard error (3.2.6), and
either may carry it in other builds."""


class SimulatorMissing(FleetmapError, ModuleNotFoundError):
    """PyBullet is not installed: the simulator (``fleet.world`` and all that uses it)
    cannot run. The message names the extra to install."""


def load_pybullet() -> ModuleType:
    """The ``pybullet`` module, imported without its build-time banner.

    Raises ``SimulatorMissing`` (a ``ModuleNotFoundError``) when it is not installed.
    """
    loaded = sys.modules.get("pybullet")
    if loaded is not None:
        return loaded
    try:
        return import_silently("pybullet")
    except ModuleNotFoundError as exc:
        if exc.name != "pybullet":
            raise
        raise SimulatorMissing(install_hint(sys.version_info[:2]), name="pybullet") from None


def install_hint(version: tuple[int, int]) -> str:
    """``SimulatorMissing``'s message on Python ``version`` (major, minor)."""
    source = (
        ""
        if version < (3, 12)
        else SOURCE_BUILD.format(version=f"Python {version[0]}.{version[1]}")
    )
    return INSTALL_HINT.format(source=source)


def import_silently(name: str) -> ModuleType:
    """Import ``name`` with file descriptors 1 and 2 pointed at ``os.devnull``; both are
    restored whether the import succeeds or raises. A descriptor that is not open is left
    as it is."""
    for stream in (sys.stdout, sys.stderr):
        if stream is not None:  # None without a console (pythonw)
            stream.flush()
    with ExitStack() as stack:
        null = os.open(os.devnull, os.O_WRONLY)
        stack.callback(os.close, null)
        for fd in QUIET_FDS:
            stack.enter_context(_pointed_at(fd, null))
        stack.callback(_flush_c_stdio)  # unwound first: what C still buffers goes to devnull
        return importlib.import_module(name)


@contextmanager
def _pointed_at(fd: int, target: int) -> Iterator[None]:
    """Point ``fd`` at ``target`` for the block, then back at what it was."""
    try:
        saved = os.dup(fd)
    except OSError:  # not open: nothing to protect
        yield
        return
    try:
        os.dup2(target, fd)
        yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


def _flush_c_stdio() -> None:
    """``fflush(NULL)``: write out every C stdio buffer of the process (where a piped
    standard output holds what C code printed). A platform without a C library to load
    this way (Windows) skips it."""
    try:
        libc = ctypes.CDLL(None)
    except (OSError, TypeError):
        return
    libc.fflush(None)
