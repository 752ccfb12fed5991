"""``BeliefGrid.copy_cells_from``: a mirror that copies only the boxes fusion reported
equals the grid it follows, cell for cell (the costmap follower relies on it)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_fusion_properties import GEOMETRY, MODEL, scans

from mapserver.core.belief import BeliefGrid, CellBox
from mapserver.core.geometry import GridGeometry
from mapserver.core.sensor_model import Policy


def state_bytes(grid: BeliefGrid) -> dict[str, bytes]:
    return {name: array.tobytes() for name, array in grid.state_arrays().items()}


@settings(max_examples=60, deadline=None)
@given(st.lists(scans(), min_size=1, max_size=6), st.sampled_from(list(Policy)),
       st.integers(1, 3))  # fmt: skip
def test_a_mirror_copying_the_fused_boxes_equals_the_grid(sequence, policy, every):
    live, mirror = BeliefGrid(GEOMETRY, MODEL, policy), BeliefGrid(GEOMETRY, MODEL, policy)
    boxes: list[CellBox] = []
    for k, scan in enumerate(sequence, start=1):
        boxes.append(live.fuse(scan).box)
        if k % every == 0 or k == len(sequence):  # the mirror catches up now and then
            mirror.copy_cells_from(live, boxes)
            boxes = []
            assert state_bytes(mirror) == state_bytes(live)
            assert (mirror.stamp, mirror.scans_fused) == (live.stamp, live.scans_fused)


def test_cells_outside_the_boxes_are_left_as_they_were():
    live, mirror = BeliefGrid(GEOMETRY, MODEL), BeliefGrid(GEOMETRY, MODEL)
    live.raw_log_odds()[:] = 1.0
    live.last_observed()[:] = 3.0
    mirror.copy_cells_from(live, [CellBox(2, 1, 4, 3), CellBox(28, 18, 40, 40)])
    copied = np.zeros(GEOMETRY.shape, dtype=bool)
    copied[1:4, 2:5] = copied[18:, 28:] = True  # the second box clipped to the grid
    assert np.array_equal(mirror.raw_log_odds() == 1.0, copied)
    assert np.array_equal(mirror.last_observed() == 3.0, copied)
    assert np.isnan(mirror.last_observed()[~copied]).all()


@pytest.mark.parametrize(
    "other",
    [
        BeliefGrid(GEOMETRY, MODEL, Policy.DECAY),
        BeliefGrid(GridGeometry(30, 21, 0.25), MODEL, Policy.DUAL),
    ],
)
def test_a_grid_of_another_policy_or_geometry_is_refused(other):
    with pytest.raises(ValueError, match="same geometry and policy"):
        other.copy_cells_from(BeliefGrid(GEOMETRY, MODEL, Policy.DUAL), [])
