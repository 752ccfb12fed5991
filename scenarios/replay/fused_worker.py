"""The ``/fleetmap/scans`` messages of a run's journal, made in a process of their own
while the replay's writer packs the rest (``write_replay``).

Reading a fused scan back from the journal (its checksum, its header, its ranges
inflated), validating it as the server does at start-up (``Scan.from_dict``) and encoding
its message take about 80 us a scan on this project's 2-core machine: 10 s of
``busy_shift``'s 120,000 scans, in a writer that also builds the viewing channels and
compresses the file's chunks. So a child interpreter (``python -m
scenarios.replay.fused_worker JOURNAL``) reads the journal as ``FusedScans.scans`` does
and writes each message to its standard output as a frame: the stamp [ns] as a
little-endian int64, the message's length as a uint32, the message. The writer reads
the frames as it needs them; the pipe's buffer holds the child back when the writer is
slower. The messages are those ``messages`` makes in process, byte for byte.

A journal of fewer than ``worker_from`` scans is read in process: starting the child
(its imports: about 1.3 s) costs more than it saves.
"""

from __future__ import annotations

try:
    import fcntl
except ImportError:  # not on Windows
    fcntl = None
import os
import struct
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import scenarios
from mapserver.service.replay import ReplayError, opened_journal
from scenarios.replay.foxglove_messages import stamp_ns
from scenarios.replay.fused import FusedScans, ZonedFusedScans, fused_message, journal_fused

WORKER_FROM = 20_000
"""Journals with at least this many seqs are read in a child process."""

_FRAME = struct.Struct("<qI")  # stamp [ns], message length [bytes]
_PIPE_BYTES = 1 << 20
"""Bytes written and read at a time, and the pipe's buffer where Linux allows it: in
64 KB (the default pipe) the two processes took turns rather than working together."""


def fused_items(
    fused: FusedScans | ZonedFusedScans, worker_from: int = WORKER_FROM
) -> Iterator[tuple[int, bytes]]:
    """(stamp [ns], ``/fleetmap/scans`` message) of every fused scan, in seq order
    (module docstring; a zoned run's merged journals are read in process); ReplayError
    when a journal cannot be read."""
    if isinstance(fused, ZonedFusedScans) or _seq_count(fused.journal) < worker_from:
        for seq, scan in fused.scans():
            yield stamp_ns(scan.stamp), fused_message(seq, scan)
        return
    command = [sys.executable, "-m", __name__, str(fused.journal)]
    with tempfile.TemporaryFile() as errors:  # a file: a chatty child never blocks on it
        child = subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=errors, bufsize=_PIPE_BYTES, env=_child_env()
        )
        _widen(child.stdout)
        finished = False
        try:
            yield from _frames(child.stdout)
            finished = True
        finally:
            child.stdout.close()
            if not finished:
                child.kill()  # the writer stopped early, or a frame was cut: stop the child
            code = child.wait()
        if code != 0:
            errors.seek(0)
            text = errors.read().decode(errors="replace").strip()
            raise ReplayError(text or f"{fused.journal}: the journal's reader exited {code}")


def messages(journal: Path) -> Iterator[tuple[int, bytes]]:
    """(stamp [ns], message) of the journal's fused scans, in seq order, in process."""
    for seq, scan in journal_fused(journal):
        yield stamp_ns(scan.stamp), fused_message(seq, scan)


def _frames(stream) -> Iterator[tuple[int, bytes]]:
    """The (stamp [ns], message) frames of ``stream`` until its end."""
    read = stream.read
    while head := read(_FRAME.size):
        if len(head) < _FRAME.size:
            raise ReplayError("the journal's reader stopped inside a frame")
        ns, size = _FRAME.unpack(head)
        message = read(size)
        if len(message) < size:
            raise ReplayError("the journal's reader stopped inside a frame")
        yield ns, message


def _child_env() -> dict[str, str]:
    """This process's environment with the folder that holds ``scenarios`` first on the
    child's import path, so it runs this code wherever it was imported from."""
    root = str(Path(scenarios.__file__).resolve().parents[1])
    paths = [root, *filter(None, os.environ.get("PYTHONPATH", "").split(os.pathsep))]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(paths)}


def _widen(stream) -> None:
    """Give the pipe behind ``stream`` a ``_PIPE_BYTES`` buffer (Linux; elsewhere, or
    above the system's limit, it keeps its own)."""
    setpipe = getattr(fcntl, "F_SETPIPE_SZ", None)  # None without fcntl too
    if setpipe is None:
        return
    try:
        fcntl.fcntl(stream.fileno(), setpipe, _PIPE_BYTES)
    except OSError:
        pass


def _seq_count(journal: Path) -> int:
    """How many seqs the journal spans; ReplayError when it cannot be read."""
    with opened_journal(journal) as opened:
        return opened.last_seq() - opened.deleted_through()


def main(argv: list[str]) -> int:
    """Write the frames of the journal ``argv[0]`` to standard output (module docstring)."""
    out = open(sys.stdout.fileno(), "wb", buffering=_PIPE_BYTES, closefd=False)
    pack = _FRAME.pack
    try:
        for ns, message in messages(Path(argv[0])):
            out.write(pack(ns, len(message)))
            out.write(message)
        out.flush()
    except ValueError as exc:  # ReplayError among them
        print(exc, file=sys.stderr)
        return 1
    except BrokenPipeError:  # the writer stopped reading
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
