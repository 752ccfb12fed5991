"""LiDAR casters: how a unit's fan of planar beams finds its true ranges in the world.

A caster is made once per LiDAR for its ``BeamFan`` (the beams in the unit's body frame)
and returns, for a unit of a ``fleet.world.World``, the distance [m] from the sensor to
the first surface along each beam over ``[fan.start, fan.stop)``, ``+inf`` where there
is none (a surface exactly at ``stop`` is none). Sensor flaws are not a caster's
business: ``fleet.lidar.Lidar.corrupt`` applies them after either.

- ``bullet``: PyBullet's ``rayTestBatch`` against the world's triangle meshes, the rays
  fixed in the unit's body frame (``World.cast_rays`` with ``frame_unit``): the reference.
- ``grid``: ``fleet.footprint_index`` / ``fleet.planar_cast`` in numba against the same
  solids as planar footprints in a uniform grid, so a ray tests only the bodies near it.
  The two agree on the first body hit and on its range within 1 mm but where a beam
  passes within Bullet's edge tolerance of a body's vertical edge
  (``tests/fleet/test_caster_agreement.py``); about ten times faster
  (``tests/benchmarks/sim.py``).

Both start each beam at ``fan.start`` from the sensor, outside the unit's own body
(``fleet.lidar``), so neither ever sees it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from mapserver.core.errors import FieldError

if TYPE_CHECKING:  # the world imports PyBullet; choosing a caster does not
    from fleet.world import World

CASTERS = ("grid", "bullet")
"""The casters by name (module docstring)."""
DEFAULT_CASTER = "grid"
"""The caster a LiDAR uses unless told (``lidar.caster`` in a scenario file)."""
CASTER_CHOICES = f"must be one of {list(CASTERS)}"
"""Why a name that is not a caster's is refused."""


def check_caster(name: object) -> str:
    """``name`` if it names a caster; else FieldError on ``caster`` naming the choices."""
    if not isinstance(name, str) or name not in CASTERS:
        raise FieldError("caster", name, CASTER_CHOICES)
    return name


@dataclass(frozen=True, eq=False)
class BeamFan:
    """A fan of horizontal beams in a unit's body frame: beam i at ``angles[i]`` [rad] from
    the heading, from ``start`` to ``stop`` [m] from the sensor at ``height`` [m] above the
    floor (the sensor on the unit's centre line)."""

    angles: np.ndarray
    start: float
    stop: float
    height: float


class FanCaster(Protocol):
    """Casts one ``BeamFan`` from a unit (module docstring)."""

    def cast(self, world: World, unit_id: str) -> np.ndarray:
        """[m] the true range of each beam from unit ``unit_id``; +inf: no surface."""
        ...


class BulletCaster:
    """The fan cast by PyBullet's ``rayTestBatch`` in the unit's body frame."""

    def __init__(self, fan: BeamFan) -> None:
        c, s = np.cos(fan.angles), np.sin(fan.angles)
        z = np.full(c.shape, fan.height)
        self._start = fan.start
        self._span = fan.stop - fan.start
        # Body-frame ray ends as Python lists, built once: PyBullet converts lists fastest.
        self._from = np.stack([fan.start * c, fan.start * s, z], axis=1).tolist()
        self._to = np.stack([fan.stop * c, fan.stop * s, z], axis=1).tolist()

    def cast(self, world: World, unit_id: str) -> np.ndarray:
        fractions = world.cast_rays(self._from, self._to, frame_unit=unit_id)
        return fractions * self._span + self._start  # inf stays inf


class GridCaster:
    """The fan cast in numba against the world's footprints (``World.footprints``)."""

    def __init__(self, fan: BeamFan) -> None:
        self._fan = fan
        self._cos = np.cos(fan.angles)
        self._sin = np.sin(fan.angles)

    def cast(self, world: World, unit_id: str) -> np.ndarray:
        pose = world.unit_pose(unit_id)
        fan = self._fan
        ranges, _ = world.footprints.cast_fans(
            np.array([pose.x, pose.y, pose.yaw]),
            self._cos, self._sin, fan.height, fan.start, fan.stop,
        )  # fmt: skip
        return ranges[0]


def fan_caster(name: str, fan: BeamFan) -> FanCaster:
    """The caster called ``name`` (``CASTERS``) for ``fan``."""
    return {"grid": GridCaster, "bullet": BulletCaster}[check_caster(name)](fan)
