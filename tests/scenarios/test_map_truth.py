"""The shared map against ground truth (scenarios.score.map_truth): exact counts on hand-made
maps, the reachable floor, the metrics of a short run, and the replay's and report's
views of them."""

import json
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from matplotlib.figure import Figure
from mcap.reader import make_reader
from scipy import ndimage

from mapserver.core.geometry import GridGeometry
from scenarios.replay.map_truth_channel import MAP_TRUTH_TOPIC, SCHEMA
from scenarios.replay.mcap import write_replay
from scenarios.run import runner
from scenarios.run.record import MapTruthSample, RunRecord
from scenarios.score.map_truth import KEYS, _near, footprints, measure, reachable_floor, summary
from scenarios.score.report_map_truth import draw_map_truth
from scenarios.spec.scenario import load_scenario


def costs(*rows: list[int]) -> np.ndarray:
    """A hand-made costmap, row 0 first."""
    return np.array(rows, dtype=np.uint8)


# Nav2 costs by hand: 0 free, 100 graded, 253 inscribed, 254 lethal, 255 unknown.
SHARED = costs([0, 254, 253, 255, 0], [254, 0, 100, 255, 253], [0, 0, 0, 0, 0],
               [255, 255, 0, 254, 255])  # fmt: skip
TRUTH = costs([0, 254, 0, 0, 0], [0, 254, 254, 0, 253], [0, 253, 0, 0, 0],
              [0, 0, 0, 0, 254])  # fmt: skip
# rows 2 and 3 but the truth's inscribed (2, 1) and lethal (3, 4): 8 cells
REACHABLE = np.zeros(SHARED.shape, dtype=bool)
REACHABLE[2:, :] = True
REACHABLE[2, 1] = REACHABLE[3, 4] = False


def test_counts_cell_for_cell_on_a_hand_made_map():
    # phantom: (0,2) 253 on truth 0, (1,0) 254 on 0, (3,3) 254 on 0; not (0,1) (lethal in
    # both) nor (1,4) (inscribed in both).
    # forgotten: truth-lethal (1,1) reads 0 and (1,2) reads 100; not (0,1) (lethal) nor
    # (3,4) (unknown: never claimed free).
    # unknown: of the 8 reachable cells, (3,0) and (3,1).
    sample = measure(2.5, SHARED, TRUTH, REACHABLE, tolerance_cells=0)
    assert sample == MapTruthSample(2.5, 3, 2, 2 / 8)


def test_counts_within_one_cell_of_the_truth_on_a_hand_made_map():
    # every phantom of the cell-for-cell count touches a truth-blocked cell ((0,1), (1,1),
    # (3,4)), and both forgotten cells touch the map's lethal (0,1).
    assert measure(2.5, SHARED, TRUTH, REACHABLE) == MapTruthSample(2.5, 0, 0, 2 / 8)


NOWHERE = np.zeros((1, 8), dtype=bool)


def test_a_phantom_more_than_a_cell_from_the_truths_blocked_cells_counts():
    truth = costs([254, 253, 100, 0, 0, 0, 0, 0])
    shared = costs([255, 254, 253, 253, 0, 254, 0, 0])  # blocked 1, 2, 3 and 5
    assert measure(0.0, shared, truth, NOWHERE, tolerance_cells=0).phantom_cells == 3
    assert measure(0.0, shared, truth, NOWHERE).phantom_cells == 2  # 3 and 5
    assert measure(0.0, shared, truth, NOWHERE, tolerance_cells=2).phantom_cells == 1  # 5


def test_a_forgotten_cell_more_than_a_cell_from_the_maps_lethal_counts():
    truth = costs([0, 254, 254, 254, 254, 0, 0, 0])
    shared = costs([0, 0, 0, 0, 254, 0, 0, 0])  # the map holds the pod's last cell
    assert measure(0.0, shared, truth, NOWHERE, tolerance_cells=0).forgotten_cells == 3
    assert measure(0.0, shared, truth, NOWHERE).forgotten_cells == 2  # 1 and 2


def test_a_perfect_map_has_no_phantom_or_forgotten_cell_and_nothing_unknown():
    assert measure(0.0, TRUTH, TRUTH, REACHABLE) == MapTruthSample(0.0, 0, 0, 0.0)


def test_nothing_reachable_is_no_unknown_share():
    nowhere = np.zeros(SHARED.shape, dtype=bool)
    assert measure(0.0, SHARED, TRUTH, nowhere).unknown_share == 0.0


@given(
    mask=arrays(bool, st.tuples(st.integers(1, 12), st.integers(1, 12))),
    cells=st.integers(0, 3),
)
def test_the_tolerance_grows_a_mask_as_a_square_dilation(mask, cells):
    square = np.ones((2 * cells + 1,) * 2, dtype=bool)
    expected = ndimage.binary_dilation(mask, structure=square) if cells else mask
    assert np.array_equal(_near(mask, cells), expected)
    if cells:  # a lone cell grows to the square around it, clipped at the edges
        lone = np.zeros((9, 9), dtype=bool)
        lone[0, 4] = True
        grown = _near(lone, cells)
        assert np.count_nonzero(grown) == (cells + 1) * (2 * cells + 1)


def test_shapes_must_agree():
    with pytest.raises(ValueError, match="shapes differ"):
        measure(0.0, SHARED, TRUTH[:3], REACHABLE)


FLOOR = costs([0, 0, 254, 0, 0], [254, 254, 254, 0, 254], [0, 253, 254, 100, 0],
              [0, 0, 254, 254, 0])  # fmt: skip


def test_reachable_floor_is_eight_connected_passable_cells_of_the_starts():
    left = np.zeros(FLOOR.shape, dtype=bool)
    left[0, 0:2] = True  # sealed by the lethal row below and column 2
    assert np.array_equal(reachable_floor(FLOOR, [(0, 0)]), left)
    right = np.zeros(FLOOR.shape, dtype=bool)  # (1,3) -> (2,4) diagonally -> (3,4)
    right[0, 3:] = right[1, 3] = right[2, 3:] = right[3, 4] = True
    assert np.array_equal(reachable_floor(FLOOR, [(4, 3)]), right)
    assert np.array_equal(reachable_floor(FLOOR, [(0, 0), (4, 0)]), left | right)


def test_starts_on_an_obstacle_or_off_the_grid_seed_nothing():
    assert not reachable_floor(FLOOR, [(1, 2), (2, 0), (9, 9), (-1, 0)]).any()  # 253, 254, off
    assert not reachable_floor(FLOOR, []).any()


def test_a_units_footprint_is_the_cells_whose_centres_it_covers():
    geometry = GridGeometry(10, 10, 0.1)
    mask = footprints(geometry, [(0.5, 0.5, 0.1), (0.95, 0.05, 0.04)])
    expected = np.zeros((10, 10), dtype=bool)
    expected[4:6, 4:6] = True  # centres 0.45, 0.55: 0.0707 m off; 0.35: 0.158 m off
    expected[0, 9] = True  # the corner cell, centre (0.95, 0.05)
    assert np.array_equal(mask, expected)
    assert not footprints(geometry, []).any()


def test_summary_is_the_mean_over_reads_and_the_last_read():
    samples = [MapTruthSample(0.5, 4, 0, 0.5), MapTruthSample(1.0, 1, 3, 0.25),
               MapTruthSample(1.5, 2, 1, 0.0)]  # fmt: skip
    assert summary(samples) == {
        "phantom_cells": {"mean": 2.333, "final": 2},
        "forgotten_cells": {"mean": 1.333, "final": 1},
        "unknown_share": {"mean": 0.25, "final": 0.0},
    }
    assert summary([]) == {k: {"mean": None, "final": None} for k in KEYS}


def _short_run(seed: int):
    scenario = replace(load_scenario("scenarios/tiny.yaml"), duration=3.0)
    return runner.run(scenario.with_seed(seed))


@pytest.fixture(scope="module")
def short_runs():
    return _short_run(0), _short_run(0)


def test_a_run_measures_at_every_map_read_and_sums_it_up(short_runs):
    record, _ = short_runs
    stamps = [s.stamp for s in record.map_truth]
    assert stamps == pytest.approx([0.1 + 0.5 * k for k in range(6)])  # map_read_s 0.5
    metrics = record.metrics["map_truth"]
    assert set(metrics) == set(KEYS)
    for key in ("phantom_cells", "forgotten_cells"):
        assert isinstance(metrics[key]["final"], int) and metrics[key]["final"] >= 0
        assert metrics[key]["mean"] >= 0
    share = metrics["unknown_share"]
    assert 0.0 <= share["final"] <= 1.0 and 0.0 <= share["mean"] <= 1.0
    assert record.map_truth[0].unknown_share > record.map_truth[-1].unknown_share  # looked
    assert metrics == summary(record.map_truth)
    json.dumps(metrics, allow_nan=False)


def test_same_seed_same_map_truth(short_runs):
    first, second = short_runs
    assert first.map_truth == second.map_truth
    assert first.metrics["map_truth"] == second.metrics["map_truth"]


SAMPLES = [MapTruthSample(0.1, 5, 2, 0.75), MapTruthSample(0.6, 3, 0, 0.5)]


def test_the_replay_carries_one_map_truth_message_per_read(tmp_path):
    record = RunRecord("t", "decay", 0, GridGeometry(4, 4, 0.1), map_truth=list(SAMPLES))
    path = write_replay(record, tmp_path / "replay.mcap")
    with open(path, "rb") as f:
        messages = [
            (schema, message) for schema, channel, message in make_reader(f).iter_messages()
            if channel.topic == MAP_TRUTH_TOPIC
        ]  # fmt: skip
    assert [json.loads(s.data) for s, _ in messages[:1]] == [SCHEMA]
    assert [m.log_time for _, m in messages] == [100_000_000, 600_000_000]
    assert [json.loads(m.data) for _, m in messages] == [
        {"timestamp": {"sec": 0, "nsec": 100_000_000}, "phantom_cells": 5,
         "forgotten_cells": 2, "unknown_share": 0.75},
        {"timestamp": {"sec": 0, "nsec": 600_000_000}, "phantom_cells": 3,
         "forgotten_cells": 0, "unknown_share": 0.5},
    ]  # fmt: skip


def test_the_report_panel_plots_the_three_over_time():
    record = RunRecord("t", "decay", 0, GridGeometry(4, 4, 0.1), map_truth=list(SAMPLES))
    ax = Figure().add_subplot()
    share = draw_map_truth(ax, record, end=1.0)
    phantom, forgotten = ax.get_lines()
    assert list(phantom.get_xdata()) == [0.1, 0.6] and list(phantom.get_ydata()) == [5, 3]
    assert list(forgotten.get_ydata()) == [2, 0]
    assert list(share.get_lines()[0].get_ydata()) == [75.0, 50.0]  # percent
    assert draw_map_truth(Figure().add_subplot(), replace(record, map_truth=[]), 1.0) is None
