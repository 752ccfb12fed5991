"""The guard of glancing faces: a return whose neighbours outline one straight surface
with it stops clearing where it comes within a cell of that surface, square to it, so
beams glancing along a face do not wear away the cells square beams hit
(docs/clearing.md)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapserver.core.belief import BeliefGrid
from mapserver.core.fusion_kernel import GLANCE_CAP_CELLS, SURFACE_UNKNOWN, glance_cutoff
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Pose2D, Scan
from mapserver.core.sensor_model import Policy, SensorModel

RES = 0.1  # [m]
GUARD = SensorModel(fill_between_beams=False)
NO_GUARD = SensorModel(fill_between_beams=False, guard_glancing_faces=False)
GEOMETRY = GridGeometry(200, 100, RES)  # 20 m x 10 m
SENSOR = (1.05, 0.05)  # [m] the centre of cell (row 0, col 10)
STEP = math.radians(1.0)  # [rad] between the three beams


def face_ranges(angle: float, face_y: float) -> list[float]:
    """Ranges [m] of three beams at angle - STEP, angle, angle + STEP to the line y = face_y."""
    rise = face_y - SENSOR[1]
    return [rise / math.sin(angle + k * STEP) for k in (-1, 0, 1)]


def fused(model, ranges, angle, policy=Policy.DECAY) -> BeliefGrid:
    b = BeliefGrid(GEOMETRY, model, policy)
    b.fuse(Scan("u1", 1.0, Pose2D(*SENSOR, 0.0), angle - STEP, STEP, 0.05, 20.0,
                np.asarray(ranges, dtype=float)))  # fmt: skip
    return b


def on_line(r: float, alpha: float, delta: float) -> float:
    """[m] range at bearing ``delta`` [rad] to the line through (r, 0) at ``alpha`` [rad]
    to the beam (the sine rule)."""
    return r * math.sin(alpha) / math.sin(alpha - delta)


def test_the_cut_is_a_cell_less_than_a_cell_over_the_sine_of_the_glancing_angle():
    r, step = 5.0, 0.01
    sin10 = math.sin(math.radians(10))
    for alpha_deg, expected in ((10.0, RES * (1 / sin10 - 1)), (90.0, 0.0)):
        alpha = math.radians(alpha_deg)
        ranges = np.array([on_line(r, alpha, -step), r, on_line(r, alpha, step)])
        cut = glance_cutoff(ranges, 1, 0.05, 20.0, math.sin(step), math.cos(step), RES)
        assert cut == pytest.approx(expected, abs=1e-9)


def test_the_cut_is_capped_and_needs_both_neighbours_on_one_line_with_it():
    sin_s, cos_s = math.sin(STEP), math.cos(STEP)
    grazing = np.array(face_ranges(math.radians(3.0), 0.15))  # 3 degrees: 1.81 m, capped
    assert glance_cutoff(grazing, 1, 0.05, 20.0, sin_s, cos_s, RES) == GLANCE_CAP_CELLS * RES
    edge = np.array([3.0, 3.0, 9.0])  # an occlusion edge: the three outline no one face
    assert glance_cutoff(edge, 1, 0.05, 20.0, sin_s, cos_s, RES) == SURFACE_UNKNOWN
    # A face at 10 degrees 0.5 m out: its outline spans 0.10 m, under two 0.1 m cells
    # (within range noise), so no cut; with 0.04 m cells the same outline is a face.
    near = np.array([on_line(0.5, math.radians(10), d) for d in (-STEP, 0.0, STEP)])
    assert glance_cutoff(near, 1, 0.05, 20.0, sin_s, cos_s, RES) == 0.0  # seen, not measured
    assert glance_cutoff(near, 1, 0.05, 20.0, sin_s, cos_s, 0.04) == pytest.approx(
        0.04 * (1 / math.sin(math.radians(10)) - 1), rel=0.05
    )
    lone = np.array([math.inf, 3.0, 3.0])  # next to a no-return: no surface is known
    assert glance_cutoff(lone, 1, 0.05, 20.0, sin_s, cos_s, RES) == SURFACE_UNKNOWN
    assert glance_cutoff(np.array([3.0, 3.0]), 0, 0.05, 20.0, sin_s, cos_s, RES) == 0.0


def test_a_glancing_return_leaves_the_cells_along_the_face_alone():
    # A face along y = 1.0 m (the top of row 9 is 1.0: the face cuts nothing), met at 10
    # degrees: the middle beam stops 0.1 m / sin(10) - 0.1 m = 0.476 m short of it.
    angle = math.radians(10.0)
    ranges = face_ranges(angle, 1.0 + 1e-6)
    guarded, unguarded = fused(GUARD, ranges, angle), fused(NO_GUARD, ranges, angle)
    spared = (unguarded.raw_log_odds() < 0) & (guarded.raw_log_odds() == 0)
    rows, cols = np.nonzero(spared)
    assert len(rows) > 0  # cells only the glancing passes reached
    # Every spared cell lies within a cell of the face, square to it: the cut ends
    # 0.1 m * (1 - sin 10) = 0.083 m below y = 1 m, in row 9. Bresenham steps from cell
    # centre to cell centre, and the endpoints' centres are in row 10 (y 1.05 m): the
    # discrete line's last cells run along the face's own row, the wear this guard stops.
    assert set(rows.tolist()) <= {8, 9, 10}
    assert 10 in rows
    cut = RES * (1 / math.sin(angle) - 1)
    far = ranges[1] - cut  # where the middle beam now stops [m]
    xs = GEOMETRY.origin_x + (cols + 0.5) * RES - SENSOR[0]
    assert np.all(xs >= far * math.cos(angle) - RES)  # only the beam's last 0.476 m
    # The endpoints' cells are hit either way.
    assert np.array_equal(guarded.raw_log_odds() > 0, unguarded.raw_log_odds() > 0)


def test_a_square_face_an_occlusion_edge_and_binary_are_as_before():
    # Square to the beams at 8 m (a chord of 0.28 m: a surface is known, alpha ~90 deg),
    # and an occlusion edge (a cut of 1 m without the bend rule).
    for ranges in ([8.0, 8.0, 8.0], [3.0, 3.0, 9.0]):
        angle = math.radians(45)
        guarded, unguarded = fused(GUARD, ranges, angle), fused(NO_GUARD, ranges, angle)
        assert np.array_equal(guarded.raw_log_odds(), unguarded.raw_log_odds()), ranges
    angle = math.radians(10.0)
    ranges = face_ranges(angle, 1.0 + 1e-6)
    a = fused(GUARD, ranges, angle, Policy.BINARY)
    b = fused(NO_GUARD, ranges, angle, Policy.BINARY)
    assert np.array_equal(a.raw_log_odds(), b.raw_log_odds())
    assert a.glance_margin == 0.0


def test_the_guard_is_on_by_default_and_refuses_a_non_boolean():
    assert SensorModel().guard_glancing_faces is True
    with pytest.raises(ValueError, match="guard_glancing_faces must be true or false, got 1"):
        SensorModel(guard_glancing_faces=1)


@settings(max_examples=150, deadline=None)
@given(
    ranges=st.lists(st.one_of(st.floats(0.3, 19.0), st.just(math.inf)), min_size=2, max_size=60),
    step_deg=st.floats(0.1, 3.0),
    yaw=st.floats(-math.pi, math.pi),
)
def test_the_guard_only_ever_clears_less_and_never_touches_a_hit(ranges, step_deg, yaw):
    step = math.radians(step_deg)
    maps = []
    for model in (GUARD, NO_GUARD):
        b = BeliefGrid(GEOMETRY, model, Policy.DECAY)
        b.fuse(Scan("u1", 1.0, Pose2D(*SENSOR, yaw), 0.0, step, 0.05, 20.0,
                    np.asarray(ranges, dtype=float)))  # fmt: skip
        maps.append(b.raw_log_odds())
    guarded, unguarded = maps
    assert np.array_equal(guarded > 0, unguarded > 0)  # the same cells hit
    assert not ((guarded < 0) & ~(unguarded < 0)).any()  # nothing cleared it did not clear
    cleared = guarded < 0
    # one update each, never a stronger one: the same, or the weaker no-return update where
    # the guard cut a return short and only a no-return beam still crosses the cell
    assert np.all(guarded[cleared] >= unguarded[cleared])
    updates = np.float32([GUARD.l_miss - GUARD.l0, GUARD.l_miss_no_return - GUARD.l0])
    assert np.isin(guarded[cleared], updates).all()
    assert np.isin(unguarded[cleared], updates).all()


def test_a_cell_the_guard_keeps_from_a_return_may_still_take_a_neighbouring_no_return_pass():
    """Found by the property above: the guard stops a glancing return short of the cell at
    row 7, column 12; a no-return beam beside it still crosses that cell, so it is cleared
    with the weaker no-return evidence instead of a return's."""
    ranges = [1.0, math.inf, 1.0, math.inf, 1.0, 1.0, 2.0, 1.0, 0.5, math.inf]
    maps = []
    for model in (GUARD, NO_GUARD):
        b = BeliefGrid(GEOMETRY, model, Policy.DECAY)
        b.fuse(Scan("u1", 1.0, Pose2D(*SENSOR, 1.0), 0.0, math.radians(2.0), 0.05, 20.0,
                    np.asarray(ranges)))  # fmt: skip
        maps.append(b.raw_log_odds())
    guarded, unguarded = maps
    assert unguarded[7, 12] == np.float32(GUARD.l_miss - GUARD.l0)
    assert guarded[7, 12] == np.float32(GUARD.l_miss_no_return - GUARD.l0)


def test_a_grazing_return_beside_a_no_return_clears_but_turns_no_face_cell_void():
    """Under dual, 1 degree beams 17 m out along a face 1.0 m off the sensor's line, each
    beside a no-return (no surface outlined, so no glance cut): they clear the cells they
    cross, as before, but none within the cap (1 m here) of their endpoints is seen
    CLEAR, so the face row they graze never turns void (it did, in the dropouts
    warehouse: 142 face cells forgotten, 50 with this rule)."""
    face_y = 1.0 + 0.03  # the face cuts row 10 (1.0 .. 1.1 m) near its bottom
    b = BeliefGrid(GEOMETRY, SensorModel(fill_between_beams=False), Policy.DUAL)
    for k in range(40):  # a unit driving along y = 0.05 m, looking back along the face
        x = 19.0 - 0.05 * k
        reach = x - 2.0  # [m] to the face's far part
        angle = math.pi - math.atan2(face_y - SENSOR[1], reach)
        r = math.hypot(reach, face_y - SENSOR[1])
        ranges = np.array([math.inf, r, math.inf])
        b.fuse(Scan("u1", 1.0 + 0.1 * k, Pose2D(x, SENSOR[1], 0.0), angle - STEP, STEP, 0.05,
                    20.0, ranges))  # fmt: skip
    row = b.void_mask()[10]
    assert not row.any()  # the face row: grazed, never void
    assert b.void_mask()[0:9].any()  # space the beams crossed clear of any face is void
