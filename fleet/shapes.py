"""Planar geometry: the footprints of the world's objects (rotated boxes, circles) and
angle wrapping.

The one place that knows their geometry: the PyBullet world builds bodies from them,
the ground truth rasterises them, collision checks ask whether a point lies inside one.

Conventions: the ``map`` frame (x right, y up, metres); yaw [rad] counter-clockwise
from +x. A point on a shape's boundary counts as inside it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from mapserver.core.errors import FieldError

PRISM_SIDES = 64
"""Sides of the regular prisms that stand for cylinders (people, units) in the PyBullet
world and its planar caster: inscribed in the circle, the vertices at angles
``2 pi k / PRISM_SIDES`` from the body's x axis."""
Bounds = tuple[float, float, float, float]
"""An axis-aligned bounding box ``(xmin, ymin, xmax, ymax)`` [m]."""


def wrap_angle(angle: float) -> float:
    """``angle`` [rad] wrapped into [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


def _check_finite(owner: object, *names: str) -> None:
    for name in names:
        value = getattr(owner, name)
        if isinstance(value, bool) or not isinstance(value, int | float | np.number):
            raise FieldError(name, value, "must be a number")
        if not math.isfinite(value):
            raise FieldError(name, value, "must be finite")


def _check_positive(owner: object, *names: str) -> None:
    for name in names:
        value = getattr(owner, name)
        if not value > 0:
            raise FieldError(name, value, "must be a positive number of metres")


@dataclass(frozen=True)
class Box:
    """A rectangle: centre (x, y) [m], side lengths size_x, size_y [m] along its own axes,
    turned by yaw [rad] about its centre."""

    x: float
    y: float
    size_x: float
    size_y: float
    yaw: float = 0.0

    def __post_init__(self) -> None:
        _check_finite(self, "x", "y", "size_x", "size_y", "yaw")
        _check_positive(self, "size_x", "size_y")

    @classmethod
    def from_bounds(cls, xmin: float, ymin: float, xmax: float, ymax: float) -> Box:
        """The axis-aligned box ``[xmin, xmax] x [ymin, ymax]`` [m]."""
        return cls((xmin + xmax) / 2, (ymin + ymax) / 2, xmax - xmin, ymax - ymin)

    def contains(self, px: float | np.ndarray, py: float | np.ndarray) -> np.ndarray:
        """True where point (px, py) [m] lies inside or on the box (broadcast shape)."""
        dx = np.asarray(px, dtype=np.float64) - self.x
        dy = np.asarray(py, dtype=np.float64) - self.y
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        u = c * dx + s * dy  # the point in the box's own axes
        v = -s * dx + c * dy
        return (np.abs(u) <= self.size_x / 2) & (np.abs(v) <= self.size_y / 2)

    def distance(self, px: float | np.ndarray, py: float | np.ndarray) -> np.ndarray:
        """[m] distance from point (px, py) [m] to the box, 0 inside (broadcast shape)."""
        dx = np.asarray(px, dtype=np.float64) - self.x
        dy = np.asarray(py, dtype=np.float64) - self.y
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        gap_u = np.maximum(np.abs(c * dx + s * dy) - self.size_x / 2, 0.0)
        gap_v = np.maximum(np.abs(-s * dx + c * dy) - self.size_y / 2, 0.0)
        return np.hypot(gap_u, gap_v)

    def bounds(self) -> Bounds:
        """The axis-aligned bounding box [m]."""
        c, s = abs(math.cos(self.yaw)), abs(math.sin(self.yaw))
        hx = (c * self.size_x + s * self.size_y) / 2
        hy = (s * self.size_x + c * self.size_y) / 2
        return (self.x - hx, self.y - hy, self.x + hx, self.y + hy)

    def moved(self, x: float, y: float, yaw: float | None = None) -> Box:
        """The same box with its centre at (x, y) [m] and, when given, turned to yaw [rad]."""
        return replace(self, x=x, y=y, yaw=self.yaw if yaw is None else yaw)


@dataclass(frozen=True)
class Cylinder:
    """A circle: centre (x, y) [m] and radius [m] (an upright cylinder's footprint)."""

    x: float
    y: float
    radius: float

    def __post_init__(self) -> None:
        _check_finite(self, "x", "y", "radius")
        _check_positive(self, "radius")

    def contains(self, px: float | np.ndarray, py: float | np.ndarray) -> np.ndarray:
        """True where point (px, py) [m] lies inside or on the circle (broadcast shape)."""
        dx = np.asarray(px, dtype=np.float64) - self.x
        dy = np.asarray(py, dtype=np.float64) - self.y
        return dx * dx + dy * dy <= self.radius * self.radius

    def distance(self, px: float | np.ndarray, py: float | np.ndarray) -> np.ndarray:
        """[m] distance from point (px, py) [m] to the disc, 0 inside (broadcast shape)."""
        dx = np.asarray(px, dtype=np.float64) - self.x
        dy = np.asarray(py, dtype=np.float64) - self.y
        return np.maximum(np.hypot(dx, dy) - self.radius, 0.0)

    def bounds(self) -> Bounds:
        """The axis-aligned bounding box [m]."""
        r = self.radius
        return (self.x - r, self.y - r, self.x + r, self.y + r)

    def moved(self, x: float, y: float, yaw: float | None = None) -> Cylinder:
        """The same circle centred at (x, y) [m]; yaw is ignored (a circle has none)."""
        return replace(self, x=x, y=y)


Shape = Box | Cylinder
