"""A ``fleetmap serve`` subprocess for the load and fault benchmarks, and readings of it.

``LoggedServer`` is ``scenarios.run.embedded_server.EmbeddedServer`` with the server's
stdout and stderr in a log file (a pipe nobody reads stalls a server that logs a lot),
an optional descriptor limit (``nofile``, set in the child before exec), and this
checkout as the working directory (so ``-m scenarios.cli.main`` runs this checkout's code).
It reads the server process: RSS [MiB], CPU time [s], log and journal size [bytes],
journaled scans. Not a benchmark itself (imported by ``fleet_load`` and
``fault_probes``).
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import yaml

from mapserver.store.journal import Journal, journal_path
from scenarios.run.embedded_server import EmbeddedServer, free_port

ROOT = Path(__file__).resolve().parents[2]
MIB = 1024 * 1024


class LoggedServer(EmbeddedServer):
    """``fleetmap serve`` on 127.0.0.1 with ``settings`` on ``data_dir``, logging to
    ``log_path`` (next to the data dir); ``nofile``: its RLIMIT_NOFILE (soft = hard).
    Ready when constructed; ``RuntimeError`` (with the log) if it exits or never answers."""

    def __init__(
        self,
        data_dir: Path,
        settings: dict[str, Any] | None = None,
        nofile: int | None = None,
        ready_timeout: float = 60.0,
    ) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.data_dir = Path(data_dir)
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self.log_path = self.data_dir.parent / f"{self.data_dir.name}-{self.port}.log"
        cmd = [sys.executable, "-m", "scenarios.cli.main", "serve", "--host", "127.0.0.1",
               "--port", str(self.port), "--data-dir", str(self.data_dir)]  # fmt: skip
        if settings:
            config = self.data_dir.parent / f"{self.data_dir.name}-{self.port}.yaml"
            config.write_text(yaml.safe_dump(settings, sort_keys=False))
            cmd += ["--config", str(config)]

        def limit_descriptors() -> None:
            if nofile is not None:
                resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, nofile))

        with open(self.log_path, "ab") as log:
            self.proc = subprocess.Popen(
                cmd, cwd=ROOT, stdout=log, stderr=log, preexec_fn=limit_descriptors
            )
        # EmbeddedServer reports a failed start with proc.stderr.read(): the log, here.
        self.proc.stderr = open(self.log_path)  # noqa: SIM115 - closed by stop()
        self.ready_timeout = ready_timeout
        self.wait_ready()

    @property
    def pid(self) -> int:
        return self.proc.pid

    def stop(self) -> None:
        """SIGTERM and wait (SIGKILL after 10 s, as EmbeddedServer)."""
        try:
            super().stop()
        finally:
            self.proc.stderr.close()

    def timed_stop(self) -> tuple[float, int | None]:
        """``stop()``: ([s] from SIGTERM to exit, exit code; -9 when it had to be killed)."""
        t0 = time.monotonic()
        self.stop()
        return time.monotonic() - t0, self.proc.returncode

    def alive(self) -> bool:
        return self.proc.poll() is None

    def rss_mib(self) -> float | None:
        """[MiB] VmRSS of the server process and its children (its map process with
        ``server.map_process``); None once it has exited."""
        sizes = [rss_mib(pid) for pid in (self.pid, *child_pids(self.pid))]
        return None if sizes[0] is None else sum(s for s in sizes if s is not None)

    def cpu_seconds(self) -> float | None:
        """[s] user + system CPU time of the server process and its running children so
        far (None once it has exited)."""
        own = cpu_seconds(self.pid)
        if own is None:
            return None
        return own + sum(cpu_seconds(pid) or 0.0 for pid in child_pids(self.pid))

    def log_bytes(self) -> int:
        return self.log_path.stat().st_size

    def log_text(self) -> str:
        return self.log_path.read_text(errors="replace")

    def journal_bytes(self) -> int:
        """[bytes] the journal file and its -wal file (as the server's metric counts)."""
        path = journal_path(self.data_dir)
        return sum(p.stat().st_size for p in (path, Path(f"{path}-wal")) if p.exists())

    def journal_count(self) -> int | None:
        """Scans in the journal (read-only; None if it cannot be read)."""
        return journal_count(self.data_dir)


def child_pids(pid: int) -> list[int]:
    """The running processes whose parent is ``pid``."""
    try:
        listed = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return []
    return [int(child) for child in listed]


def cpu_seconds(pid: int) -> float | None:
    """[s] user + system CPU time of process ``pid`` so far (None if it has exited)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def rss_mib(pid: int) -> float | None:
    """[MiB] VmRSS of process ``pid`` (None if it has exited)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024 / MIB
    except OSError:
        return None
    return None


def journal_shape(data_dir: Path) -> dict[str, float] | None:
    """What the journal of ``data_dir`` holds (read-only; None if it cannot be read):
    ``held`` scans, ``snapshots`` and their ``snapshot_mib``, the file's ``free_mib``
    (freelist pages, reused by later writes) and the ``wal_mib`` of its -wal file."""
    path = journal_path(Path(data_dir))
    try:
        with Journal(path, readonly=True) as journal:
            infos = journal.snapshot_infos()
            _, free, page_size = journal.page_stats()
            held = journal.count()
    except Exception:  # a probe reports what it finds, whatever the journal's state
        return None
    wal = Path(f"{path}-wal")
    return {
        "held": held,
        "snapshots": len(infos),
        "snapshot_mib": round(sum(i.nbytes for i in infos) / MIB, 1),
        "free_mib": round(free * page_size / MIB, 1),
        "wal_mib": round((wal.stat().st_size if wal.exists() else 0) / MIB, 1),
    }


def journal_count(data_dir: Path) -> int | None:
    """Scans in the journal of ``data_dir`` (read-only; None if it cannot be read)."""
    try:
        with Journal(journal_path(Path(data_dir)), readonly=True) as journal:
            return journal.count()
    except Exception:  # a probe reports what it finds, whatever the journal's state
        return None
