"""Drop the fleet's own units from its scans before they reach the shared map.

Every unit's LiDAR sees the other units. Painted into the shared map, a unit's body
becomes a lethal blob that blocks its own planning and the lanes it stands on, and it
stays behind when the unit drives on. A fleet knows where its units are, so (as fleet
managers filter their robots out of the shared map) every return that ends within
``margin`` [m] of another unit's footprint is marked invalid (NaN, REP 117: dropped)
before posting.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from fleet.poster import ScanPoster
from mapserver.client import ScanAck
from mapserver.scan import Scan


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
        others = [(x, y, r) for uid, (x, y, r) in units.items() if uid != scan.unit_id]
        if not others:
            return scan
        r = scan.ranges
        angles = scan.pose.yaw + scan.angle_min + scan.angle_increment * np.arange(r.size)
        with np.errstate(invalid="ignore"):
            finite = np.isfinite(r)
            ex = scan.pose.x + np.where(finite, r, 0.0) * np.cos(angles)
            ey = scan.pose.y + np.where(finite, r, 0.0) * np.sin(angles)
        hit = np.zeros(r.size, dtype=bool)
        for x, y, radius in others:
            hit |= finite & (np.hypot(ex - x, ey - y) <= radius + self.margin)
        if not hit.any():
            return scan
        self.dropped += int(hit.sum())
        return replace(scan, ranges=np.where(hit, np.nan, r))
