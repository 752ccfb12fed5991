"""A planar LiDAR on a drive unit: its beams cast in the world by a caster
(``fleet.casters``: ``grid``, numba over the bodies' footprints, or ``bullet``, PyBullet's
``rayTestBatch``), then its flaws applied, the same way whichever cast.

The sensor sits on the unit's centre line, ``height`` [m] above the floor, and sweeps
``beams`` horizontal beams over ``fov`` centred on the unit's heading
(``fleet.boxworld.beam_angles``: beam i at ``-fov / 2 + i * fov / beams``).

Own body: each ray starts ``start`` = body radius + ``RAY_START_CLEARANCE_M`` from the
sensor, outside the unit's own convex body, so the unit never sees itself; ranges are
still measured from the sensor. Anything closer than ``start`` (inside the body) is never
seen; a beam that starts inside another body (one the unit touches) reads where it leaves
that body, as Bullet's ray test reports the far wall of a closed mesh from inside.

Ranges follow ROS REP 117 (docs/http-api.md 2.1): a miss (no surface within ``range_max``) reads
``+inf``. Sensor flaws, applied in this order with the LiDAR's own generator:

1. range noise: every return gets gaussian noise of std ``range_noise`` [m] (kept >= 0);
   a noisy return beyond ``range_max`` becomes a miss, one below ``range_min`` stays (the
   server drops it as invalid, REP 117);
2. dropouts: each beam independently reads ``+inf`` (no return) with ``dropout_prob``;
3. spurious returns: each beam independently, with ``spurious_prob``, reads a return
   uniform in ``[range_min, min(true range, range_max)]`` (dust, a reflection).

Each flaw draws a fixed number of variates per scan whatever the geometry, so a seeded
LiDAR's flaws do not depend on what it sees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from fleet.boxworld import beam_angles
from fleet.casters import DEFAULT_CASTER, BeamFan, fan_caster
from mapserver.core.errors import FieldError

if TYPE_CHECKING:  # the world imports PyBullet; a scenario file's LiDAR settings do not
    from fleet.world import World

RAY_START_CLEARANCE_M = 0.001
"""[m] gap between the unit's body and the start of its rays."""


@dataclass(frozen=True)
class LidarConfig:
    """A planar LiDAR's specification.

    beams: number of beams; fov: [rad] field of view in (0, 2 pi], centred on the heading.
    range_min, range_max: [m] the sensor's limits (REP 117).
    rate_hz: [Hz] scans per second.
    height: [m] the scan plane above the floor (objects lower than it are not seen).
    range_noise: [m] std of gaussian noise on each return.
    dropout_prob: probability that a beam reads no return.
    spurious_prob: probability that a beam reads a spurious short return.
    """

    beams: int = 360
    fov: float = 2 * math.pi
    range_min: float = 0.05
    range_max: float = 20.0
    rate_hz: float = 10.0
    height: float = 0.2
    range_noise: float = 0.0
    dropout_prob: float = 0.0
    spurious_prob: float = 0.0

    def __post_init__(self) -> None:
        beam_angles(self.beams, self.fov)  # checks beams and fov
        if not (math.isfinite(self.range_max) and 0 <= self.range_min < self.range_max):
            raise FieldError(
                "range_min", self.range_min, f"must be in [0, range_max = {self.range_max!r}) m"
            )
        for name in ("rate_hz", "height"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise FieldError(name, value, "must be positive and finite")
        if not (math.isfinite(self.range_noise) and self.range_noise >= 0):
            raise FieldError("range_noise", self.range_noise, "must be >= 0 m")
        for name in ("dropout_prob", "spurious_prob"):
            value = getattr(self, name)
            if not 0 <= value <= 1:
                raise FieldError(name, value, "must be a probability in [0, 1]")

    @property
    def period(self) -> float:
        """[s] time between two scans."""
        return 1.0 / self.rate_hz

    @property
    def angle_min(self) -> float:
        """[rad] the first beam's angle from the heading."""
        return beam_angles(self.beams, self.fov)[0]

    @property
    def angle_increment(self) -> float:
        """[rad] the angle between neighbouring beams."""
        return beam_angles(self.beams, self.fov)[1]

    def angles(self) -> np.ndarray:
        """[rad] each beam's angle from the heading."""
        return self.angle_min + self.angle_increment * np.arange(self.beams)


class Lidar:
    """One unit's LiDAR: ``config``, mounted on a body of ``body_radius`` [m], flaws drawn
    from ``rng``, beams cast by the caster named ``caster`` (``fleet.casters.CASTERS``)."""

    def __init__(
        self,
        config: LidarConfig,
        body_radius: float,
        rng: np.random.Generator,
        caster: str = DEFAULT_CASTER,
    ) -> None:
        self.config = config
        self.rng = rng
        self.start = body_radius + RAY_START_CLEARANCE_M
        if not self.start < config.range_max:
            raise FieldError(
                "range_max",
                config.range_max,
                f"must exceed the unit's radius plus {RAY_START_CLEARANCE_M} m ({self.start} m)",
            )
        self.angle_min, self.angle_increment = beam_angles(config.beams, config.fov)  # [rad]
        fan = BeamFan(config.angles(), self.start, config.range_max, config.height)
        self.caster = caster
        self._caster = fan_caster(caster, fan)
        self._scene: object = None  # the key of the last cast and its ranges [m]
        self._ranges = np.empty(0)

    def true_ranges(self, world: World, unit_id: str, scene: object = None) -> np.ndarray:
        """[m] flawless ranges from unit ``unit_id``'s sensor; +inf where nothing is hit.

        scene: a key of what the sensor can see (e.g. the world's revision, the unit's
        pose and the poses of the units in range), or None. When it equals the key of the
        last cast, nothing it can see has moved, so the last ranges are the answer (the
        same rays in the same scene hit the same surfaces) and no rays are cast.
        """
        if scene is not None and scene == self._scene:
            return self._ranges
        ranges = self._caster.cast(world, unit_id)
        ranges.flags.writeable = False
        self._scene, self._ranges = scene, ranges
        return ranges

    def corrupt(self, ranges: np.ndarray) -> np.ndarray:
        """``ranges`` [m] with the configured noise, dropouts and spurious returns (new array)."""
        cfg = self.config
        true = np.asarray(ranges, dtype=np.float64)
        n = true.shape[0]
        out = true.copy()
        if cfg.range_noise > 0:  # a miss (+inf) stays a miss
            out = np.maximum(out + self.rng.normal(0.0, cfg.range_noise, n), 0.0)
            out[out > cfg.range_max] = np.inf
        if cfg.dropout_prob > 0:
            out[self.rng.random(n) < cfg.dropout_prob] = np.inf
        if cfg.spurious_prob > 0:
            chance, where = self.rng.random((2, n))
            spurious = chance < cfg.spurious_prob
            if spurious.any():
                far = np.minimum(true[spurious], cfg.range_max)
                span = np.maximum(far - cfg.range_min, 0.0)
                out[spurious] = cfg.range_min + where[spurious] * span
        return out

    def measure(self, world: World, unit_id: str, scene: object = None) -> np.ndarray:
        """[m] one scan's ranges from unit ``unit_id``: cast (or, for an unchanged
        ``scene``, the last cast: ``true_ranges``), then corrupted afresh."""
        return self.corrupt(self.true_ranges(world, unit_id, scene))
