"""``ZonedMapClient``: one site's map served by several map servers, one per zone.

The zones are ``mapserver.client.zones.ZoneLayout``'s strips; each has its own server (its
own process, journal, snapshots and durability promises) reached through its own
``MapClient``. This client routes, as docs/scaling.md ("A site larger than one server")
designs it, and nothing is shared between the servers:

- ``post_scans``: each scan goes to every zone whose exact band its sensor reaches
  (``ZoneLayout.posts_to``), always including the zone it stands in; the zones' requests
  go out together (one thread per zone), so the servers fuse side by side. The ack
  returned for a scan is its home zone's. Each zone takes or refuses its part as one
  batch; when one zone refuses, the others may have journaled theirs, and the first
  refusal (by zone) is raised once every zone has answered.
- ``costmap`` and ``occupancy``: every zone's grid, its core's columns stitched into one
  site grid. The map's "now" is the latest stamp fused, so a zone whose latest scan is
  older than another's is read again at the newest stamp (``at``): the stitched grid
  then equals, cell for cell, one server's of the whole site fed the same scans
  (``tests/client/test_zoned_client.py``).
- ``query_segments`` is worked out on the stitched costmap, as the server works it out
  on its own.
- ``declare_clock`` goes to every zone; ``publish_units`` sends each unit to the zone it
  stands in (that zone's viewer shows it).
- ``map_meta``: the site's geometry, the newest stamp of any zone and the sum of the
  zones' versions (it grows with every scan any zone fuses), the settings of zone 0.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from typing import Any, TypeVar

import numpy as np

from mapserver.api.schemas import ClockOut, MapMeta, ScanAck, UnitState
from mapserver.client.map_client import Grid, MapClient, _short
from mapserver.client.zones import ZoneLayout
from mapserver.core.scan import Scan

T = TypeVar("T")


class ZonedMapClient:
    """The map of ``layout``'s site through ``clients``, one ``MapClient`` per zone, in
    zone order (module docstring). Close it (``close`` or ``with``) to stop its threads;
    the clients stay the caller's."""

    def __init__(self, layout: ZoneLayout, clients: Sequence[MapClient]) -> None:
        if len(clients) != layout.zones:
            raise ValueError(f"need one client per zone ({layout.zones}), got {len(clients)}")
        self.layout = layout
        self.clients = tuple(clients)
        self._pool = ThreadPoolExecutor(max_workers=layout.zones, thread_name_prefix="zone")

    def close(self) -> None:
        """Stop the zones' threads (idempotent)."""
        self._pool.shutdown(wait=True)

    def __enter__(self) -> ZonedMapClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- scans
    def post_scan(self, scan: Scan | Mapping[str, Any]) -> ScanAck:
        """Send one scan to its zones (module docstring); its home zone's ack."""
        return self.post_scans([scan])[0]

    def post_scans(self, scans: Iterable[Scan | Mapping[str, Any]]) -> list[ScanAck]:
        """Send scans to their zones, one batch a zone, all zones at once; one ack per
        scan (its home zone's), in order."""
        scans = list(scans)
        if not scans:
            return []
        xs = np.array([_sensor_x(i, scan) for i, scan in enumerate(scans)], dtype=np.float64)
        homes = self.layout.homes(xs)
        sends = self.layout.posts_to_many(xs)
        sends[np.arange(len(scans)), homes] = True  # a scan off the site: its home refuses it
        picks = {k: np.flatnonzero(sends[:, k]) for k in range(self.layout.zones)}
        picks = {k: rows for k, rows in picks.items() if rows.size}
        parts = {k: [scans[i] for i in rows] for k, rows in picks.items()}
        replies = self._each({k: partial(self.clients[k].post_scans, p) for k, p in parts.items()})
        slot = {k: {int(i): n for n, i in enumerate(rows)} for k, rows in picks.items()}
        return [replies[k][slot[k][i]] for i, k in enumerate(homes.tolist())]

    def declare_clock(self, now: float) -> ClockOut:
        """Declare the simulation's clock to every zone; zone 0's reply."""
        replies = self._each({k: partial(c.declare_clock, now) for k, c in enumerate(self.clients)})
        return replies[0]

    # -- maps
    def map_meta(self) -> MapMeta:
        """The site's meta (module docstring)."""
        metas = self._each({k: c.map_meta for k, c in enumerate(self.clients)})
        site = self.layout.site
        stamps = [m.stamp for m in metas.values() if m.stamp is not None]
        first = metas[0]
        origin = first.origin.model_copy(update={"x": site.origin_x, "y": site.origin_y})
        return first.model_copy(
            update={
                "width": site.width,
                "height": site.height,
                "resolution": site.resolution,
                "origin": origin,
                "stamp": max(stamps) if stamps else None,
                "version": sum(m.version for m in metas.values()),
            }
        )

    def costmap(self, at: float | None = None) -> Grid:
        """The site's Nav2 costmap (uint8) at ``at`` [s] (default: the map's now), stitched."""
        return self._stitched(lambda c, when: c.costmap(when), at)

    def occupancy(self, at: float | None = None) -> Grid:
        """The site's OccupancyGrid (int8) at ``at`` [s] (default: the map's now), stitched."""
        return self._stitched(lambda c, when: c.occupancy(when), at)

    def query_segments(self, segments: Sequence[Sequence[float]] | np.ndarray) -> list:
        """Cost, blockage and unknown share along each segment ``(x0, y0, x1, y1)`` [m],
        worked out on the stitched costmap (``mapserver.core.queries.query_segments``)."""
        from mapserver.core.queries import query_segments  # numba: only when asked

        costs = self.costmap()
        return query_segments(costs.geometry, costs.data, np.asarray(segments, dtype=float))

    # -- units
    def publish_units(self, units: Iterable[UnitState]) -> int:
        """Publish each unit to the zone it stands in; how many units the zones hold a
        state for, in all."""
        units = list(units)
        if not units:
            return 0
        homes = self.layout.homes(np.array([u.pose.x for u in units], dtype=np.float64))
        groups: dict[int, list[UnitState]] = {}
        for unit, home in zip(units, homes.tolist(), strict=True):
            groups.setdefault(home, []).append(unit)
        replies = self._each(
            {k: partial(self.clients[k].publish_units, group) for k, group in groups.items()}
        )
        return sum(replies.values())

    # ------------------------------------------------------------------ internals
    def _stitched(self, read: Callable[[MapClient, float | None], Grid], at: float | None) -> Grid:
        """Every zone's grid (``read(client, at)``), a lagging zone read again at the
        newest stamp when ``at`` is None, stitched into the site's."""
        grids = self._each({k: partial(read, c, at) for k, c in enumerate(self.clients)})
        when = at
        if at is None:
            stamps = [g.stamp for g in grids.values() if g.stamp is not None]
            when = max(stamps) if stamps else None
            behind = {
                k: partial(read, self.clients[k], when)
                for k, g in grids.items()
                if g.stamp is not None and g.stamp < when
            }
            grids.update(self._each(behind))
        data = self.layout.stitch([grids[k].data for k in range(self.layout.zones)])
        data.flags.writeable = False
        version = sum(g.version for g in grids.values())
        return Grid(data=data, geometry=self.layout.site, version=version, stamp=when)

    def _each(self, calls: dict[int, Callable[[], T]]) -> dict[int, T]:
        """``{zone: call()}`` for ``{zone: call}``, all at once; raises the first zone's
        error once every call has ended."""
        futures = {k: self._pool.submit(call) for k, call in calls.items()}
        errors = {k: f.exception() for k, f in futures.items()}
        for k in sorted(errors):
            if errors[k] is not None:
                raise errors[k]
        return {k: f.result() for k, f in futures.items()}


def _sensor_x(index: int, scan: Scan | Mapping[str, Any]) -> float:
    """[m] the sensor's x of ``scans[index]``, a ``Scan`` or its docs/http-api.md 2.1 dict."""
    if isinstance(scan, Scan):
        return scan.pose.x
    try:
        return float(scan["pose"]["x"])
    except (KeyError, TypeError, ValueError):
        raise ValueError(
            f"scans[{index}].pose.x: a zoned map routes a scan by its sensor's x, got "
            f"{_short(scan)}"
        ) from None
