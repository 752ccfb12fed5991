"""The fill between beams: where neighbouring beams are more than a cell apart, the cells
between two neighbouring returns that neither beam crosses are cleared too, up to one
cell short of the surface the two outline (docs/clearing.md)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapserver.core.belief import BeliefGrid
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Pose2D, Scan
from mapserver.core.sensor_model import Policy, SensorModel, logit

RES = 0.1  # [m]
ONE_DEGREE = math.radians(1.0)
FILL = SensorModel()
NO_FILL = SensorModel(fill_between_beams=False)
# 30 m x 10 m, the sensor at (0.05, 0.05) m: the centre of cell (row 30, col 0).
GEOMETRY = GridGeometry(300, 100, RES, origin_x=0.0, origin_y=-3.0)
SENSOR_ROW = 30


def grid(model=FILL, policy=Policy.DECAY) -> BeliefGrid:
    return BeliefGrid(GEOMETRY, model, policy)


def scan(ranges, angle_min=-ONE_DEGREE / 2, angle_increment=ONE_DEGREE, yaw=0.0) -> Scan:
    return Scan(
        "u1", 1.0, Pose2D(0.05, 0.05, yaw), angle_min, angle_increment, 0.05, 20.0,
        np.asarray(ranges, dtype=float),
    )  # fmt: skip


def changed_by_fill(ranges, **kw) -> np.ndarray:
    """Cells the fill changes: the map with it minus the map without it, as a mask."""
    with_fill, without = grid(), grid(NO_FILL)
    with_fill.fuse(scan(ranges, **kw))
    without.fuse(scan(ranges, **kw))
    return with_fill.raw_log_odds() != without.raw_log_odds()


def test_the_fill_ray_clears_the_cells_between_two_beams_up_to_a_cell_before_the_face():
    # Returns at 10 m at -0.5 and +0.5 degrees: 0.175 m apart there, so one fill ray at 0
    # degrees, from 0.1 m / 1 degree = 5.73 m out to 0.1 m short of the face the two
    # outline, x = 0.05 + 9.9996 m: to x = 9.9496 m, in cell 99.
    b = grid()
    b.fuse(scan([10.0, 10.0]))
    row = b.raw_log_odds()[SENSOR_ROW]
    # The beams leave the sensor's row (y 0.05 m, the row's centre) at 5.73 m, in cell 57:
    # cells 58 to 99 are crossed by the fill ray only.
    assert row[58:100] == pytest.approx([logit(0.4)] * 42)  # l_miss, each once
    assert row[100] == 0.0  # the face's own cell: untouched
    b = grid(NO_FILL)
    b.fuse(scan([10.0, 10.0]))
    assert np.all(b.raw_log_odds()[SENSOR_ROW, 58:101] == 0.0)  # what the fill adds


def test_nothing_is_filled_where_the_beams_are_less_than_a_cell_apart():
    # At 5 m, 1 degree beams are 0.087 m apart: the beams alone cross every cell between.
    assert not changed_by_fill([5.0, 5.0]).any()


def test_a_no_return_neighbour_outlines_nothing_so_nothing_is_filled():
    assert not changed_by_fill([10.0, math.inf]).any()
    assert not changed_by_fill([math.inf, math.inf]).any()
    assert not changed_by_fill([math.nan, 10.0]).any()


def test_binary_the_nav2_baseline_traces_its_beams_only():
    with_fill = BeliefGrid(GEOMETRY, FILL, Policy.BINARY)
    without = BeliefGrid(GEOMETRY, NO_FILL, Policy.BINARY)
    for b in (with_fill, without):
        b.fuse(scan([10.0, 10.0]))
    assert np.array_equal(with_fill.raw_log_odds(), without.raw_log_odds())
    assert with_fill.fill_margin == 0.0


def test_sticky_fills_like_decay():
    b = grid(policy=Policy.STICKY)
    b.fuse(scan([10.0, 10.0]))
    assert b.raw_log_odds()[SENSOR_ROW, 70] == pytest.approx(logit(0.4))


def test_a_sensor_model_refuses_a_fill_flag_that_is_not_a_boolean():
    with pytest.raises(ValueError, match="fill_between_beams must be true or false, got 'yes'"):
        SensorModel(fill_between_beams="yes")


@settings(max_examples=150, deadline=None)
@given(
    range_a=st.floats(0.3, 19.9),
    range_b=st.floats(0.3, 19.9),
    step_deg=st.floats(0.1, 5.0),
    yaw=st.floats(-math.pi, math.pi),
)
def test_filled_cells_lie_between_the_beams_in_front_of_the_outlined_surface(
    range_a, range_b, step_deg, yaw
):
    step = math.radians(step_deg)
    changed = changed_by_fill([range_a, range_b], angle_min=0.0, angle_increment=step, yaw=yaw)
    without = grid(NO_FILL)
    without.fuse(scan([range_a, range_b], angle_min=0.0, angle_increment=step, yaw=yaw))
    # A return's own cell is never touched by the fill (a HIT is never weakened).
    hits = without.raw_log_odds() > 0
    assert not (changed & hits).any()
    rows, cols = np.nonzero(changed)
    if rows.size == 0:
        return
    # Cell centres relative to the sensor [m]. Bresenham runs from the centre of the ray's
    # first cell to the centre of its last (each within half a diagonal of the ray's ends)
    # and keeps within half a cell of that line: within 1.21 cells of the fill ray.
    cx = GEOMETRY.origin_x + (cols + 0.5) * RES - 0.05
    cy = GEOMETRY.origin_y + (rows + 0.5) * RES - 0.05
    slack = 1.21 * RES
    ax, ay = range_a * math.cos(yaw), range_a * math.sin(yaw)
    bx, by = range_b * math.cos(yaw + step), range_b * math.sin(yaw + step)
    ex, ey = bx - ax, by - ay
    edge = math.hypot(ex, ey)
    # Signed distance from the segment's line, positive on the sensor's side.
    side = ((cx - ax) * ey - (cy - ay) * ex) / edge
    sensor_side = ((0 - ax) * ey - (0 - ay) * ex) / edge
    assert np.all(np.sign(sensor_side) * side >= RES - slack)  # never past the surface
    # Between the two beams' directions (give or take the slack), beyond the start.
    bearing = np.arctan2(cy, cx) - yaw
    bearing = (bearing + math.pi) % (2 * math.pi) - math.pi
    dist = np.hypot(cx, cy)
    assert np.all(bearing >= -slack / dist)
    assert np.all(bearing <= step + slack / dist)
    assert np.all(dist >= RES / step - slack)
