"""Localisation noise: the pose a unit believes it has, and the uncertainty it reports.

A real unit knows its pose only from its localiser. ``Localizer.estimate`` turns the
true sensor pose into the reported one: a fixed bias (a miscalibrated localiser; the
localiser does not know it) plus independent gaussian noise per scan. The reported
``pose_std`` is honest: exactly the configured noise std (the bias is not in it, as a
real localiser cannot report an error it does not know of).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fleet.shapes import wrap_angle
from mapserver.core.errors import FieldError
from mapserver.core.scan import Pose2D, PoseStd


@dataclass(frozen=True)
class PoseNoise:
    """Localisation error: bias_x, bias_y [m], bias_yaw [rad] added to every estimate;
    std_xy [m] (per axis) and std_yaw [rad] of independent gaussian noise per estimate."""

    bias_x: float = 0.0
    bias_y: float = 0.0
    bias_yaw: float = 0.0
    std_xy: float = 0.0
    std_yaw: float = 0.0

    def __post_init__(self) -> None:
        for name in ("bias_x", "bias_y", "bias_yaw", "std_xy", "std_yaw"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (
                isinstance(value, int | float) and math.isfinite(value)
            ):
                raise FieldError(name, value, "must be a finite number")
        for name in ("std_xy", "std_yaw"):
            if getattr(self, name) < 0:
                raise FieldError(name, getattr(self, name), "must be >= 0")

    @property
    def pose_std(self) -> PoseStd:
        """The uncertainty a unit reports with this noise (docs/http-api.md 2.1 ``pose_std``)."""
        return PoseStd(xy=self.std_xy, yaw=self.std_yaw)


class Localizer:
    """Pose estimates with ``noise``, drawn from ``rng``: three normal variates per
    estimate whatever the configuration, so the stream is the same for any noise."""

    def __init__(self, noise: PoseNoise, rng: np.random.Generator) -> None:
        self.noise = noise
        self.rng = rng

    def estimate(self, true_pose: Pose2D) -> tuple[Pose2D, PoseStd]:
        """The reported pose for ``true_pose`` and its honest ``pose_std``."""
        n = self.noise
        ex, ey, eyaw = self.rng.standard_normal(3)
        pose = Pose2D(
            true_pose.x + n.bias_x + n.std_xy * float(ex),
            true_pose.y + n.bias_y + n.std_xy * float(ey),
            wrap_angle(true_pose.yaw + n.bias_yaw + n.std_yaw * float(eyaw)),
        )
        return pose, n.pose_std
