"""Helpers for map-server tests: settings on a small grid, scan bodies, a real server."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from fastapi.testclient import TestClient

from mapserver.api.app import create_app
from mapserver.service.settings import Settings, load_settings
from scenarios.run.embedded_server import EmbeddedServer

GRID = {"width": 200, "height": 100, "resolution": 0.1}  # 20 m x 10 m
JSON = {"content-type": "application/json"}  # what every POST must declare


# TestClient's requests carry ``Host: testserver``; an open server accepts it only as a
# configured local name.
TEST_SERVER = {"local_hostnames": ["testserver"]}


def small_settings(data_dir: Path, **overrides) -> Settings:
    return load_settings(
        None, {"data_dir": data_dir, "grid": GRID, "server": TEST_SERVER, **overrides}
    )


@pytest.fixture
def limited_client(tmp_path):
    """A test client of an open server on a small grid whose bodies may hold 10,000 bytes
    (import it into a test module to use it)."""
    settings = small_settings(tmp_path / "data", limits={"max_body_bytes": 10_000})
    with TestClient(create_app(settings)) as test_client:
        yield test_client


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


class ServerProcess(EmbeddedServer):
    """``fleetmap serve`` in a subprocess on 127.0.0.1 (``scenarios.run.embedded_server``);
    its grid is ``grid`` cells at 0.1 m (default 30 m x 20 m); ``port`` None: a free one."""

    def __init__(
        self,
        data_dir: Path,
        config: Path | None = None,
        grid: tuple[int, int] = (300, 200),
        port: int | None = None,
    ) -> None:
        settings = {"grid": {"width": grid[0], "height": grid[1], "resolution": 0.1}}
        if config is not None:
            settings.update(yaml.safe_load(config.read_text()) or {})
        super().__init__(data_dir, settings, port=port)
