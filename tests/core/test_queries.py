"""Cell and segment queries on hand-made costmaps."""

import math

import numpy as np
import pytest
from conftest import make_scan
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from mapserver.core.belief import BeliefGrid
from mapserver.core.costvalues import FREE, INSCRIBED, LETHAL, UNKNOWN
from mapserver.core.geometry import GridGeometry
from mapserver.core.queries import SegmentReport, _segments_kernel, query_cells, query_segments
from mapserver.core.sensor_model import SensorModel

GEOMETRY = GridGeometry(20, 10, 1.0)


def costs_with(**cells) -> np.ndarray:
    costs = np.full(GEOMETRY.shape, FREE, dtype=np.uint8)
    for name, (col, row) in cells.items():
        costs[row, col] = {"lethal": LETHAL, "inscribed": INSCRIBED, "unknown": UNKNOWN}[
            name.rstrip("0123456789")
        ]
    return costs


def test_segment_reports_the_first_blocked_cell_from_its_start_and_the_max_cost():
    costs = costs_with(inscribed=(12, 5), lethal=(15, 5), unknown1=(3, 5))
    (forward,) = query_segments(GEOMETRY, costs, [[0.5, 5.5, 19.5, 5.5]])
    (backward,) = query_segments(GEOMETRY, costs, [[19.5, 5.5, 0.5, 5.5]])
    assert forward.blocked and forward.first_blocked == (12.5, 5.5)
    assert backward.first_blocked == (15.5, 5.5)
    assert forward.max_cost == LETHAL
    assert forward.unknown_fraction == pytest.approx(1 / 20)


def test_cells_off_the_map_count_as_unknown_and_huge_segments_are_answered():
    costs = costs_with()
    half_off, huge, outside = query_segments(
        GEOMETRY, costs, [[10.5, 2.5, 29.5, 2.5], [-1e300, 2.5, 1e300, 2.5], [-9, -9, -5, -5]]
    )
    assert half_off.unknown_fraction == pytest.approx(0.5) and not half_off.blocked
    assert half_off.max_cost == FREE
    assert huge.unknown_fraction == 1.0 and huge.max_cost == FREE
    assert outside.unknown_fraction == 1.0 and outside.max_cost is None


def read_element_by_element(geometry, costs, segments):
    """The reports as ``query_segments`` made them before it read the kernel's answer as
    Python scalars: numpy arrays indexed segment by segment (the reference)."""
    g, seg = geometry, np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    with np.errstate(over="ignore", invalid="ignore"):
        span = np.maximum(np.abs(seg[:, 2] - seg[:, 0]), np.abs(seg[:, 3] - seg[:, 1]))
        span /= g.resolution
        total = np.where(np.isfinite(span), np.floor(span) + 1.0, math.inf)
    grid = (g.width, g.height, g.origin_x, g.origin_y, g.resolution)
    on_map, max_cost, unknown, count, first = _segments_kernel(costs.reshape(-1), grid, seg)
    reports = []
    for i in range(seg.shape[0]):
        inside = count[i] if on_map[i] else 0
        blocked = on_map[i] and first[i] >= 0
        known_max = max_cost[i] if on_map[i] else -1
        unknown_cells = (unknown[i] if on_map[i] else 0) + max(total[i] - inside, 0.0)
        whole = max(total[i], inside)
        row, col = divmod(int(first[i]), g.width)
        reports.append(SegmentReport(
            None if known_max < 0 else int(known_max),
            bool(blocked),
            1.0 if not math.isfinite(whole) else min(1.0, float(unknown_cells) / float(whole)),
            g.cell_to_world(col, row) if blocked else None,
        ))  # fmt: skip
    return reports


coordinate = st.one_of(st.floats(-5.0, 25.0), st.sampled_from([-1e300, 1e300, 0.5, 19.5]))


@settings(max_examples=60, deadline=None)
@given(
    costs=arrays(
        np.uint8, GEOMETRY.shape, elements=st.sampled_from([FREE, 80, INSCRIBED, LETHAL, UNKNOWN])
    ),
    segments=st.lists(
        st.tuples(coordinate, coordinate, coordinate, coordinate), min_size=1, max_size=12
    ),
)
def test_segment_reports_are_the_kernels_answer_segment_by_segment(costs, segments):
    reports = query_segments(GEOMETRY, costs, segments)
    assert reports == read_element_by_element(GEOMETRY, costs, segments)
    for report in reports:  # plain Python values, as JSON and the lane graph take them
        assert type(report.blocked) is bool and type(report.unknown_fraction) is float
        assert report.max_cost is None or type(report.max_cost) is int
        assert report.first_blocked is None or all(type(v) is float for v in report.first_blocked)


def test_cells_report_state_probability_cost_and_age_and_outside_points():
    belief = BeliefGrid(GEOMETRY)
    for _ in range(3):
        belief.fuse(make_scan([5.0], x=0.5, y=2.5, stamp=10.0))
    costs = costs_with(lethal=(5, 2))
    free, hit, never, off = query_cells(
        belief, costs, [[1.5, 2.5], [5.5, 2.5], [5.5, 8.5], [99.0, 0.0]], at=12.0
    )
    assert (free.state, free.cost, free.last_observed, free.age) == ("free", FREE, 10.0, 2.0)
    faded = 3 * SensorModel().l_miss * 2 ** (-2 / 120)  # three passes, 2 s of a 120 s half life
    assert free.p_occ == pytest.approx(1 / (1 + np.exp(-faded)), abs=1e-6)
    assert (hit.state, hit.cost) == ("occupied", LETHAL)
    assert (never.state, never.p_occ, never.age) == ("unknown", None, None)
    assert (off.state, off.cost, off.p_occ) == ("outside", None, None)
