"""Shared test helpers: tiny grids and hand-made scans."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import HealthCheck, settings

from mapserver.core.scan import Pose2D, PoseStd, Scan

# Behaviour, never speed: no per-example deadline, and a slow machine is not a failure.
settings.register_profile("fleetmap", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("fleetmap")


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
