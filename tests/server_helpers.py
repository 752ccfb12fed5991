"""Helpers for map-server tests: settings on a small grid, scan bodies, a real server."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx

from mapserver.settings import Settings, load_settings

GRID = {"width": 200, "height": 100, "resolution": 0.1}  # 20 m x 10 m


def small_settings(data_dir: Path, **overrides) -> Settings:
    return load_settings(None, {"data_dir": data_dir, "grid": GRID, **overrides})


def scan_body(stamp: float = 1.0, unit: str = "u1", x: float = 5.0, y: float = 5.0, **fields):
    body = {
        "unit_id": unit,
        "stamp": stamp,
        "frame": "map",
        "pose": {"x": x, "y": y, "yaw": 0.0},
        "angle_min": -1.0,
        "angle_increment": 0.01,
        "range_min": 0.05,
        "range_max": 20.0,
        "ranges": [3.0] * 200,
    }
    body.update(fields)
    return body


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ServerProcess:
    """``fleetmap serve`` in a subprocess on 127.0.0.1, stopped by ``stop``/``kill``;
    its grid is ``grid`` cells at 0.1 m (default 30 m x 20 m)."""

    def __init__(
        self, data_dir: Path, config: Path | None = None, grid: tuple[int, int] = (300, 200)
    ) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        cmd = [sys.executable, "-m", "scenarios.cli", "serve", "--host", "127.0.0.1",
               "--port", str(self.port), "--data-dir", str(data_dir)]  # fmt: skip
        if config is not None:
            cmd += ["--config", str(config)]
        env = dict(os.environ, FLEETMAP_GRID__WIDTH=str(grid[0]),
                   FLEETMAP_GRID__HEIGHT=str(grid[1]), FLEETMAP_GRID__RESOLUTION="0.1")  # fmt: skip
        self.proc = subprocess.Popen(cmd, env=env, stderr=subprocess.PIPE, text=True)
        self._wait_ready()

    def _wait_ready(self, timeout: float = 60.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited: {self.proc.stderr.read()}")
            try:
                if httpx.get(self.url + "/healthz", timeout=1.0).status_code == 200:
                    return
            except httpx.HTTPError:
                time.sleep(0.1)
        self.kill()
        raise RuntimeError("server did not become ready")

    def kill(self) -> None:
        """SIGKILL: no shutdown, no final snapshot."""
        self.proc.kill()
        self.proc.wait(timeout=10)

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.kill()
