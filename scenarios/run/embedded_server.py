"""A map server of the run's own: ``fleetmap serve`` in a subprocess on a free loopback
port, with a temporary data dir and a settings file; stopped by ``stop``/``kill``.

A separate process keeps the server's GIL apart from the simulator's, so on two cores
fusion runs beside ray casting.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx
import yaml


def free_port() -> int:
    """A TCP port on 127.0.0.1 nobody listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class EmbeddedServer:
    """``fleetmap serve`` on 127.0.0.1 with ``settings`` (a dict of server settings,
    written to a YAML config) on ``data_dir``, on ``port`` (None: a free one). Ready when
    constructed, unless ``wait`` is False (then call ``wait_ready``: servers started
    together start side by side)."""

    def __init__(
        self,
        data_dir: Path,
        settings: dict[str, Any] | None = None,
        env: dict[str, str] | None = None,
        ready_timeout: float = 60.0,
        port: int | None = None,
        wait: bool = True,
    ) -> None:
        self.port = free_port() if port is None else port
        self.url = f"http://127.0.0.1:{self.port}"
        self.data_dir = data_dir = Path(data_dir)
        data_dir.mkdir(parents=True, exist_ok=True)
        cmd = [sys.executable, "-m", "scenarios.cli.main", "serve", "--host", "127.0.0.1",
               "--port", str(self.port), "--data-dir", str(data_dir)]  # fmt: skip
        if settings:
            config = data_dir.parent / f"{data_dir.name}-server.yaml"
            config.write_text(yaml.safe_dump(settings, sort_keys=False))
            cmd += ["--config", str(config)]
        self.proc = subprocess.Popen(
            cmd, env=dict(os.environ, **(env or {})), stderr=subprocess.PIPE, text=True
        )
        self.ready_timeout = ready_timeout
        if wait:
            self.wait_ready()

    def wait_ready(self, timeout: float | None = None) -> None:
        """Poll ``/healthz`` every 0.1 s until it answers 200, with one client (a client
        a poll built an SSL context each time: 1.5 s of CPU over a run's start-up), at
        most ``timeout`` [s] (None: the ``ready_timeout`` it was made with)."""
        timeout = self.ready_timeout if timeout is None else timeout
        deadline = time.monotonic() + timeout
        with httpx.Client(timeout=1.0) as http:
            while time.monotonic() < deadline:
                if self.proc.poll() is not None:
                    raise RuntimeError(f"map server exited: {self.proc.stderr.read()}")
                try:
                    if http.get(self.url + "/healthz").status_code == 200:
                        return
                except httpx.HTTPError:
                    time.sleep(0.1)
        self.kill()
        raise RuntimeError(f"map server on {self.url} did not become ready in {timeout} s")

    def kill(self) -> None:
        """SIGKILL: no shutdown, no final snapshot."""
        self.proc.kill()
        self.proc.wait(timeout=10)

    def stop(self) -> None:
        """Terminate and wait (SIGKILL after 10 s)."""
        self.proc.terminate()
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.kill()

    def __enter__(self) -> EmbeddedServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
