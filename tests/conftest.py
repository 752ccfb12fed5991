"""Shared test helpers: tiny grids and hand-made scans; which tests need the simulator.

The simulator's tests (every module under ``tests/fleet/`` and ``tests/scenarios/``, and
any test marked ``sim``) need PyBullet, the ``sim`` extra, which has wheels for Python
3.11 only. Without it they are skipped, saying why, and the modules under those folders
are not even imported; everything else runs (the map server, client, planner, stores).
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

from mapserver.core.scan import Pose2D, PoseStd, Scan

# Behaviour, never speed: no per-example deadline, and a slow machine is not a failure.
settings.register_profile("fleetmap", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("fleetmap")

TESTS = Path(__file__).resolve().parent
SIM_FOLDERS = (TESTS / "fleet", TESTS / "scenarios")
"""Folders whose every test runs the simulator or imports it."""
HAVE_SIM = importlib.util.find_spec("pybullet") is not None
SIM_MISSING = "needs the simulator: pybullet is not installed (pip install 'fleetmap[sim]')"


def needs_sim(path: Path) -> bool:
    """Whether the test file at ``path`` is in a simulator folder."""
    return any(path.resolve().is_relative_to(folder) for folder in SIM_FOLDERS)


class SkippedSimModule(pytest.Module):
    """A simulator test module, skipped whole without importing it."""

    def collect(self):
        pytest.skip(f"{self.path.name} {SIM_MISSING}", allow_module_level=True)


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "sim: runs the simulator (PyBullet); skipped without it")


def pytest_pycollect_makemodule(module_path: Path, parent: pytest.Collector):
    if not HAVE_SIM and needs_sim(module_path):
        return SkippedSimModule.from_parent(parent, path=module_path)
    return None


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark the simulator folders' tests ``sim``; skip every ``sim`` test without it."""
    for item in items:
        if needs_sim(item.path):
            item.add_marker(pytest.mark.sim)
        if not HAVE_SIM and item.get_closest_marker("sim"):
            item.add_marker(pytest.mark.skip(reason=SIM_MISSING))


def make_scan(
    ranges,
    x: float = 0.5,
    y: float = 0.5,
    yaw: float = 0.0,
    stamp: float = 0.0,
    angle_min: float = 0.0,
    angle_increment: float = 0.01,
    range_min: float = 0.05,
    range_max: float = 20.0,
    pose_std: PoseStd | None = None,
    unit_id: str = "u1",
) -> Scan:
    """A scan from (x, y, yaw) with beams starting at angle_min (radians, relative)."""
    return Scan(
        unit_id=unit_id,
        stamp=stamp,
        pose=Pose2D(x, y, yaw),
        angle_min=angle_min,
        angle_increment=angle_increment,
        range_min=range_min,
        range_max=range_max,
        ranges=np.asarray(ranges, dtype=np.float64),
        pose_std=pose_std,
    )


def p_of(log_odds: float) -> float:
    return 1.0 / (1.0 + math.exp(-log_odds))
