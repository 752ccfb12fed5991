"""The fleet-member filter: returns ending on another unit are dropped, nothing else."""

import math
from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mapserver.core.scan import Pose2D, Scan
from scenarios.run.fleet_filter import FleetMemberFilter

MARGIN = 0.15


class Keep:
    """A poster that keeps what it is given."""

    def __init__(self) -> None:
        self.posted: list[Scan] = []

    def post(self, scans):
        self.posted.extend(scans)
        return []

    def flush(self):
        return []


def brute_force(scan: Scan, units, margin: float) -> np.ndarray:
    """Every beam against every other unit: the reference."""
    r = scan.ranges
    out = r.copy()
    for i, value in enumerate(r):
        if not math.isfinite(value):
            continue
        a = scan.pose.yaw + scan.angle_min + scan.angle_increment * i
        ex, ey = scan.pose.x + value * math.cos(a), scan.pose.y + value * math.sin(a)
        for uid, (x, y, radius) in units.items():
            if uid != scan.unit_id and math.hypot(ex - x, ey - y) <= radius + margin:
                out[i] = math.nan
    return out


def make_scan(x, y, yaw, ranges, fov, range_max=20.0) -> Scan:
    n = len(ranges)
    return Scan(
        unit_id="u0", stamp=1.0, pose=Pose2D(x, y, yaw), angle_min=-fov / 2,
        angle_increment=fov / n, range_min=0.05, range_max=range_max,
        ranges=np.asarray(ranges, dtype=np.float64),
    )  # fmt: skip


@settings(max_examples=200, deadline=None)
@given(
    data=st.data(),
    n=st.integers(8, 120),
    fov=st.sampled_from([2 * math.pi, 6.0, math.pi, 1.0]),
    yaw=st.floats(-3.1, 3.1),
    others=st.lists(st.tuples(st.floats(-6, 6), st.floats(-6, 6), st.floats(0.1, 0.5)), max_size=6),
)
def test_the_filter_drops_exactly_the_returns_a_brute_force_check_drops(data, n, fov, yaw, others):
    units = {"u0": (0.0, 0.0, 0.3)} | {f"u{k + 1}": o for k, o in enumerate(others)}
    values = st.one_of(st.floats(0.05, 9.0), st.just(math.inf), st.just(math.nan))
    ranges = data.draw(st.lists(values, min_size=n, max_size=n))
    # aim some beams exactly at the other units, so hits are common
    for x, y, _ in others:
        a = math.atan2(y, x) - yaw + fov / 2
        i = math.floor(a % (2 * math.pi) / (fov / n))
        if 0 <= i < n:
            ranges[i] = math.hypot(x, y)
    scan = make_scan(0.0, 0.0, yaw, ranges, fov, range_max=9.0)
    keep = Keep()
    FleetMemberFilter(keep, lambda: units, MARGIN).post([scan])
    expected = brute_force(scan, units, MARGIN)
    np.testing.assert_array_equal(np.isnan(keep.posted[0].ranges), np.isnan(expected))
    finite = ~np.isnan(expected)
    np.testing.assert_array_equal(keep.posted[0].ranges[finite], expected[finite])


@settings(max_examples=60, deadline=None)
@given(
    fleet=st.lists(
        st.tuples(st.floats(-8, 8), st.floats(-8, 8), st.floats(-3.1, 3.1)), min_size=1, max_size=6
    ),
    n=st.integers(8, 90),
    seed=st.integers(0, 2**16),
)
def test_a_ticks_scans_are_filtered_together_each_against_the_others(fleet, n, seed):
    """Several units' scans in one post (one numba call for the tick): each scan loses
    exactly what the brute force drops for its own unit, and a scan that loses nothing is
    posted as it came."""
    rng = np.random.default_rng(seed)
    units = {f"u{k}": (x, y, 0.3) for k, (x, y, _) in enumerate(fleet)}
    scans = []
    for k, (x, y, yaw) in enumerate(fleet):
        ranges = rng.uniform(0.05, 12.0, n)
        ranges[rng.random(n) < 0.1] = math.inf
        for ux, uy, _ in units.values():  # aim a beam at each other unit's centre
            a = math.atan2(uy - y, ux - x) - yaw + math.pi
            i = math.floor(a % (2 * math.pi) / (2 * math.pi / n))
            if 0 <= i < n and (ux, uy) != (x, y):
                ranges[i] = math.hypot(ux - x, uy - y)
        scan = make_scan(x, y, yaw, ranges, 2 * math.pi, range_max=30.0)  # reaches every unit
        scans.append(replace(scan, unit_id=f"u{k}"))
    keep = Keep()
    member_filter = FleetMemberFilter(keep, lambda: units, MARGIN)
    member_filter.post(scans)
    dropped = 0
    for scan, posted in zip(scans, keep.posted, strict=True):
        expected = brute_force(scan, units, MARGIN)
        np.testing.assert_array_equal(np.isnan(posted.ranges), np.isnan(expected))
        lost = int(np.isnan(expected).sum())
        dropped += lost
        assert (posted is scan) == (lost == 0)
    assert member_filter.dropped == dropped
