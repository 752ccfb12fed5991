"""The costmap follows the belief lazily (``reads.costmap_refresh_s``): every read still
sees every acknowledged scan, and the costmap it sees is the one built from scratch."""

import numpy as np
from conftest import make_scan
from server_helpers import small_settings

from mapserver.service.map_service import MapService


def scans(n: int, unit: str = "u1"):
    return [make_scan(np.full(300, 2.0), x=3.0 + 0.4 * k, y=5.0, yaw=0.1 * k, stamp=float(k),
                      angle_min=-1.5, unit_id=unit) for k in range(1, n + 1)]  # fmt: skip


def service(tmp_path, refresh_s: float, **overrides) -> MapService:
    """A service in ``tmp_path`` whose costmap may lag ``refresh_s`` [s] without a reader."""
    return MapService(
        small_settings(tmp_path / "data", reads={"costmap_refresh_s": refresh_s}, **overrides)
    )


def test_with_no_reader_the_costmap_lags_and_every_read_brings_it_up_first(tmp_path):
    s = service(tmp_path, refresh_s=60.0)
    try:
        for scan in scans(5):
            s.ingest([scan])
        assert s.version == 5 and s.costmap.version < 5  # nobody read: not refreshed yet
        read = s.costmap_read()
        assert (read.version, s.costmap.version) == (5, 5)
        assert np.array_equal(read.data, s.costmap.build_costs(s.belief.stamp))
        s.ingest(scans(6)[-1:])
        version, _, patches = s.updates_since(5)
        assert version == 6 and patches  # the updates read refreshed it too
        assert s.segments([[1.0, 5.0, 9.0, 5.0]])[0].max_cost is not None
    finally:
        s.close()


def test_a_lazy_costmap_reads_as_one_refreshed_after_every_scan(tmp_path):
    lazy, eager = service(tmp_path / "lazy", 60.0), service(tmp_path / "eager", 0.0)
    try:
        for scan in scans(8) + scans(4, unit="u2"):
            lazy.ingest([scan])
            eager.ingest([scan])
            assert eager.costmap.version == eager.version  # refreshed at once
        assert np.array_equal(lazy.costmap_read().data, eager.costmap_read().data)
        points = [[3.0, 5.0], [6.0, 5.2], [4.5, 6.9]]
        assert lazy.cell_columns(points) == eager.cell_columns(points)
    finally:
        lazy.close()
        eager.close()


def test_with_no_lag_allowed_every_group_refreshes_the_costmap_without_a_reader(tmp_path):
    s = service(tmp_path, refresh_s=0.0)
    try:
        for scan in scans(3):
            s.ingest([scan])
            assert s.costmap.version == s.version
    finally:
        s.close()
