"""Drop the fleet's own units from its scans before they reach the shared map.

Every unit's LiDAR sees the other units. Painted into the shared map, a unit's body
becomes a lethal blob that blocks its own planning and the lanes it stands on, and it
stays behind when the unit drives on. A fleet knows where its units are, so (as fleet
managers filter their robots out of the shared map) every return that ends within
``margin`` [m] of another unit's footprint is marked invalid (NaN, REP 117: dropped)
before posting.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from fleet.poster import ScanPoster
from mapserver.client import ScanAck
from mapserver.core.scan import Scan


class FleetMemberFilter:
    """A poster that filters ``positions()`` (unit id -> (x, y, radius) [m]) out of scans
    and hands them to ``poster``."""

    def __init__(
        self,
        poster: ScanPoster,
        positions: Callable[[], Mapping[str, tuple[float, float, float]]],
        margin: float = 0.15,
    ) -> None:
        self.poster = poster
        self.positions = positions
        self.margin = margin
        self.dropped = 0  # returns filtered so far

    def post(self, scans: Sequence[Scan]) -> list[ScanAck]:
        units = self.positions()
        return self.poster.post([self._filter(scan, units) for scan in scans])

    def flush(self) -> list[ScanAck]:
        return self.poster.flush()

    def _filter(self, scan: Scan, units: Mapping[str, tuple[float, float, float]]) -> Scan:
        """``scan`` with the returns that end on another unit's footprint (plus
        ``margin``) invalid. Only the beams that point at a unit within range are looked
        at: those within ``asin((radius + margin) / distance)`` of its bearing."""
        r = scan.ranges
        n = r.size
        ox, oy = scan.pose.x, scan.pose.y
        inc = scan.angle_increment
        look = np.zeros(n, dtype=bool)  # the beams to check
        near: list[tuple[float, float, float]] = []
        for uid, (x, y, radius) in units.items():
            reach = radius + self.margin
            d = math.hypot(x - ox, y - oy)
            if uid == scan.unit_id or d - reach > scan.range_max:
                continue
            near.append((x, y, reach))
            if d <= reach or inc * n < 2 * math.asin(min(1.0, reach / d)):
                look[:] = True  # around the sensor, or wider than the scan: every beam
                continue
            half = math.asin(reach / d)
            centre = (math.atan2(y - oy, x - ox) - scan.pose.yaw - scan.angle_min) % math.tau
            for turn in (centre - math.tau, centre, centre + math.tau):  # across angle_min
                first = max(math.floor((turn - half) / inc), 0)
                last = min(math.ceil((turn + half) / inc), n - 1)
                if first <= last:
                    look[first : last + 1] = True
        if not near:
            return scan
        index = np.flatnonzero(look)
        angles = scan.pose.yaw + scan.angle_min + scan.angle_increment * index
        ranges = r[index]
        with np.errstate(invalid="ignore"):
            finite = np.isfinite(ranges)
            ex = ox + np.where(finite, ranges, 0.0) * np.cos(angles)
            ey = oy + np.where(finite, ranges, 0.0) * np.sin(angles)
        hit = np.zeros(index.size, dtype=bool)
        for x, y, reach in near:
            hit |= finite & (np.hypot(ex - x, ey - y) <= reach)
        if not hit.any():
            return scan
        self.dropped += int(hit.sum())
        out = r.copy()
        out[index[hit]] = np.nan
        return replace(scan, ranges=out)
