"""Property tests for fusion: locality, bounds, box, determinism."""

import math

import numpy as np
from conftest import make_scan
from hypothesis import given, settings
from hypothesis import strategies as st

from mapserver.core.belief import BeliefGrid
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import BEAM_NO_RETURN, BEAM_RETURN, PoseStd
from mapserver.core.sensor_model import DecayParams, Policy, SensorModel

GEOMETRY = GridGeometry(30, 20, 0.25, origin_x=-1.0, origin_y=0.5)
MODEL = SensorModel()
# Beams only: the fill between beams clears cells no beam crosses by design; its own
# properties are in test_fusion_fill.py.
BEAMS_ONLY = SensorModel(fill_between_beams=False)

range_values = st.one_of(
    st.floats(0.0, 12.0),
    st.just(math.inf),
    st.just(math.nan),
    st.just(-1.0),
    st.just(-math.inf),
)


@st.composite
def scans(draw, stamp=None):
    n = draw(st.integers(1, 40))
    range_min = draw(st.floats(0.0, 0.5))
    std = draw(st.one_of(st.none(), st.builds(PoseStd, st.floats(0, 0.3), st.floats(0, 0.1))))
    return make_scan(
        draw(st.lists(range_values, min_size=n, max_size=n)),
        x=draw(st.floats(-2.0, 7.5)),
        y=draw(st.floats(-0.5, 6.5)),
        yaw=draw(st.floats(-math.pi, math.pi)),
        stamp=draw(st.floats(0.0, 100.0)) if stamp is None else stamp,
        angle_min=draw(st.floats(-math.pi, math.pi)),
        angle_increment=draw(st.floats(1e-3, 0.5)),
        range_min=range_min,
        range_max=draw(st.floats(range_min + 0.1, 10.0)),
        pose_std=std,
    )


def distance_to_segment(px, py, x0, y0, x1, y1):
    dx, dy = x1 - x0, y1 - y0
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0 else np.clip(((px - x0) * dx + (py - y0) * dy) / length2, 0, 1)
    return np.hypot(px - (x0 + t * dx), py - (y0 + t * dy))


def beam_segments(scan):
    classes = scan.beam_classes()
    for i, r in enumerate(scan.ranges):
        if classes[i] == BEAM_RETURN:
            length = r
        elif classes[i] == BEAM_NO_RETURN:
            length = scan.range_max
        else:
            continue
        a = scan.pose.yaw + scan.angle_min + i * scan.angle_increment
        x, y = scan.pose.x, scan.pose.y
        yield x, y, x + length * math.cos(a), y + length * math.sin(a)


@settings(max_examples=150, deadline=None)
@given(scan=scans(), policy=st.sampled_from(list(Policy)))
def test_a_scan_changes_only_cells_its_beams_cross_up_to_their_returns(scan, policy):
    b = BeliefGrid(GEOMETRY, BEAMS_ONLY, policy)
    result = b.fuse(scan)
    changed = ~np.isnan(b.last_observed())
    assert np.array_equal(changed, b.raw_log_odds() != 0.0)
    rows, cols = np.nonzero(changed)
    assert result.cells == len(rows)
    if len(rows) == 0:
        assert result.box.empty
        return
    xs = GEOMETRY.origin_x + (cols + 0.5) * GEOMETRY.resolution
    ys = GEOMETRY.origin_y + (rows + 0.5) * GEOMETRY.resolution
    nearest = np.full(len(xs), np.inf)
    for seg in beam_segments(scan):
        nearest = np.minimum(nearest, distance_to_segment(xs, ys, *seg))
    # Bresenham between end cells stays within 0.5 + sqrt(2)/2 cells of the true beam.
    assert np.all(nearest <= 1.21 * GEOMETRY.resolution)
    box = result.box
    assert box.col0 == cols.min() and box.col1 == cols.max()
    assert box.row0 == rows.min() and box.row1 == rows.max()


@settings(max_examples=60, deadline=None)
@given(sequence=st.lists(scans(), min_size=1, max_size=8))
def test_clamped_policies_never_leave_the_clamp_range(sequence):
    for policy in (Policy.DECAY, Policy.BINARY, Policy.DUAL):
        b = BeliefGrid(GEOMETRY, MODEL, policy, DecayParams(5.0, 20.0))
        for scan in sorted(sequence, key=lambda s: s.stamp):
            b.fuse(scan)
            lo = b.raw_log_odds()
            assert lo.min() >= MODEL.clamp_min and lo.max() <= MODEL.clamp_max
            faded = b.log_odds_at(b.stamp + 7.0)
            assert faded.min() >= MODEL.clamp_min and faded.max() <= MODEL.clamp_max


@settings(max_examples=40, deadline=None)
@given(sequence=st.lists(scans(), min_size=1, max_size=6), policy=st.sampled_from(list(Policy)))
def test_the_same_scans_give_the_same_grid(sequence, policy):
    grids = [BeliefGrid(GEOMETRY, MODEL, policy) for _ in range(2)]
    for b in grids:
        for scan in sequence:
            b.fuse(scan)
    assert grids[0].raw_log_odds().tobytes() == grids[1].raw_log_odds().tobytes()
    assert grids[0].last_observed().tobytes() == grids[1].last_observed().tobytes()


@settings(max_examples=60, deadline=None)
@given(sequence=st.lists(scans(), min_size=1, max_size=8))
def test_void_space_is_void_for_good_and_was_free_when_it_turned(sequence):
    b = BeliefGrid(GEOMETRY, MODEL, Policy.DUAL)
    void = b.void_mask()
    for scan in sorted(sequence, key=lambda s: s.stamp):
        before = b.raw_log_odds().copy()
        b.fuse(scan)
        now = b.void_mask()
        assert not (void & ~now).any()  # never taken back
        turned = now & ~void
        assert (b.raw_log_odds()[turned] < MODEL.l_void).all()
        assert (before[turned] >= MODEL.l_void).all()
        void = now
