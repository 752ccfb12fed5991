"""Drop the fleet's own units from its scans before they reach the shared map.

Every unit's LiDAR sees the other units. Painted into the shared map, a unit's body
becomes a lethal blob that blocks its own planning and the lanes it stands on, and it
stays behind when the unit drives on. A fleet knows where its units are, so (as fleet
managers filter their robots out of the shared map) every return that ends within
``margin`` [m] of another unit's footprint is marked invalid (NaN, REP 117: dropped)
before posting.

All of a tick's scans are filtered in one numba call (``fleet_hits``): with a hundred
units and more, a Python loop over units per scan cost the runner more than its sim.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np
from numba import njit

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
        return self.poster.post(self.filtered(scans, self.positions()))

    def flush(self) -> list[ScanAck]:
        return self.poster.flush()

    def filtered(
        self, scans: Sequence[Scan], units: Mapping[str, tuple[float, float, float]]
    ) -> list[Scan]:
        """``scans`` with the returns that end on another unit's footprint (plus
        ``margin``) invalid; a scan with none is returned as it is."""
        if not scans:
            return []
        index = {uid: k for k, uid in enumerate(units)}
        fleet = np.array(
            [(x, y, radius + self.margin) for x, y, radius in units.values()], dtype=np.float64
        ).reshape(-1, 3)
        params = np.array(
            [
                (s.pose.x, s.pose.y, s.pose.yaw, s.angle_min, s.angle_increment, s.range_max)
                for s in scans
            ],
            dtype=np.float64,
        )
        owners = np.array([index.get(s.unit_id, -1) for s in scans], dtype=np.int64)
        offsets = np.zeros(len(scans) + 1, dtype=np.int64)
        np.cumsum([s.ranges.size for s in scans], out=offsets[1:])
        ranges = np.concatenate([s.ranges for s in scans]).astype(np.float64, copy=False)
        hit = fleet_hits(ranges, offsets, params, owners, fleet)
        out = []
        for k, scan in enumerate(scans):
            mine = hit[offsets[k] : offsets[k + 1]]
            if not mine.any():
                out.append(scan)
                continue
            self.dropped += int(mine.sum())
            kept = scan.ranges.copy()
            kept[mine] = np.nan
            out.append(replace(scan, ranges=kept))
        return out


@njit(cache=True, nogil=True)
def fleet_hits(ranges, offsets, params, owners, fleet):
    """Which returns end on another unit: bool per element of ``ranges``.

    ranges: [m] every scan's ranges, scan k's at ``offsets[k]:offsets[k + 1]``; params:
    per scan (x, y, yaw [m, rad], angle_min, angle_increment [rad], range_max [m]);
    owners: the row of ``fleet`` that is the scan's own unit (-1: none); fleet: per unit
    (x, y [m], reach = radius + margin [m]).

    Per scan, only units within ``range_max + reach`` count, and only the beams that
    point at one of them are looked at: those within ``asin(reach / distance)`` of its
    bearing (every beam when the sensor is inside a reach or a unit spans more than the
    scan); a looked-at, finite return whose endpoint lies within the reach of any of
    those units is a hit.
    """
    hit = np.zeros(ranges.shape[0], dtype=np.bool_)
    near = np.empty(fleet.shape[0], dtype=np.int64)
    for k in range(offsets.shape[0] - 1):
        start, n = offsets[k], offsets[k + 1] - offsets[k]
        ox, oy, yaw, angle_min, inc, range_max = params[k]
        look = np.zeros(n, dtype=np.bool_)
        count = 0
        for u in range(fleet.shape[0]):
            x, y, reach = fleet[u, 0], fleet[u, 1], fleet[u, 2]
            d = math.hypot(x - ox, y - oy)
            if u == owners[k] or d - reach > range_max:
                continue
            near[count] = u
            count += 1
            if d <= reach or inc * n < 2 * math.asin(min(1.0, reach / d)):
                look[:] = True  # around the sensor, or wider than the scan: every beam
                continue
            half = math.asin(reach / d)
            centre = (math.atan2(y - oy, x - ox) - yaw - angle_min) % math.tau
            for turn in (centre - math.tau, centre, centre + math.tau):  # across angle_min
                first = max(math.floor((turn - half) / inc), 0)
                last = min(math.ceil((turn + half) / inc), n - 1)
                if first <= last:
                    look[first : last + 1] = True
        if count == 0:
            continue
        base = yaw + angle_min
        for i in range(n):
            r = ranges[start + i]
            if not look[i] or not math.isfinite(r):
                continue
            a = base + inc * i
            ex = ox + r * math.cos(a)
            ey = oy + r * math.sin(a)
            for j in range(count):
                u = near[j]
                if math.hypot(ex - fleet[u, 0], ey - fleet[u, 1]) <= fleet[u, 2]:
                    hit[start + i] = True
                    break
    return hit
