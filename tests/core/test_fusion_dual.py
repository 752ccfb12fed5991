"""The ``dual`` policy: structure and transients told apart by the free-space history.

One row of 1 m cells with the sensor in cell 0 looking along +x (as in
test_fusion_log_odds): range 3.5 ends in cell 4, range 9.0 passes it (ending 4 m past
it: a clear pass, which can release structure). Default model:
+0.847 per hit, -0.405 per pass, clamp +-5, void below logit(0.05) = -2.944.
"""

import math

import numpy as np
import pytest
from conftest import make_scan

from mapserver.core.belief import BeliefGrid, CellState
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Pose2D, Scan
from mapserver.core.sensor_model import DecayParams, Policy, SensorModel, sigmoid

CELL = 4
HIT, PASS = 3.5, 9.0
NEAR = 5.2  # a pass that ends at x = 5.7 m, in cell 5, within 1 m of cell 4
NEAR_DEFAULT = 4.7  # ends at x = 5.2 m, within the default release_margin (0.3 m) of it


def row_grid(model: SensorModel | None = None) -> BeliefGrid:
    return BeliefGrid(GridGeometry(12, 1, 1.0), model or SensorModel(), Policy.DUAL)


def fuse(b: BeliefGrid, ranges: list[float], stamp: float) -> None:
    for r in ranges:
        b.fuse(make_scan([r], stamp=stamp))


def state(b: BeliefGrid, stamp: float | None = None) -> CellState:
    return CellState(b.states_at(stamp)[0, CELL])


def test_structure_seen_through_near_the_end_of_beams_keeps_the_textbook_13_passes():
    """Passes that end 0.7 m past the cell (within release_margin of it, as range noise at
    a face does) do not release structure: the seed's clamped numbers hold for it."""
    textbook = SensorModel(p_hit=sigmoid(0.9), p_miss=sigmoid(-0.4), release_margin=1.0)
    b = row_grid(textbook)
    fuse(b, [HIT] * 20, 0.0)
    assert b.raw_log_odds()[0, CELL] == 5.0 and b.structure_mask()[0, CELL]
    n = 0
    while b.raw_log_odds()[0, CELL] >= 0.0:
        fuse(b, [NEAR], 0.0)
        n += 1
    assert n == 13  # as the decay policy with nothing faded (test_fusion_log_odds)
    assert not b.void_mask()[0, CELL]  # L = -0.2: free of nothing, void not yet


def test_structure_seen_clear_through_by_two_scans_in_a_row_is_released():
    b = row_grid()
    fuse(b, [HIT] * 20, 0.0)  # a pod stood here since the start
    fuse(b, [PASS], 1.0)  # ends 4.5 m beyond: clear through, once
    assert b.structure_mask()[0, CELL] and state(b) is CellState.OCCUPIED  # 5 - 0.405
    fuse(b, [HIT, PASS], 1.1)  # a hit between: the count starts again
    assert b.structure_mask()[0, CELL] and state(b) is CellState.OCCUPIED
    fuse(b, [NEAR_DEFAULT], 1.2)  # a pass near its end leaves the count as it was
    assert b.structure_mask()[0, CELL] and state(b) is CellState.OCCUPIED
    fuse(b, [PASS], 1.3)  # the second clear pass in a row: what it held is dropped
    assert not b.structure_mask()[0, CELL]
    assert b.raw_log_odds()[0, CELL] == pytest.approx(math.log(0.4 / 0.6), abs=1e-6)
    assert state(b) is CellState.UNKNOWN


def test_a_cell_turns_void_after_8_net_passes_from_the_prior():
    b = row_grid()
    fuse(b, [PASS] * 7, 0.0)
    assert b.raw_log_odds()[0, CELL] == pytest.approx(7 * math.log(0.4 / 0.6), abs=1e-5)
    assert not b.void_mask()[0, CELL]  # -2.838 > -2.944
    fuse(b, [PASS], 0.0)
    assert b.void_mask()[0, CELL]
    assert b.void_mask()[0, :CELL].all()  # the cells before it were passed as often


def test_a_cell_seen_free_many_times_then_hit_by_a_passing_person_clears_in_one_pass():
    b = row_grid()
    fuse(b, [PASS] * 30, 0.0)  # the aisle, driven past
    fuse(b, [HIT], 10.0)  # a person stands in cell 4
    assert state(b) is CellState.OCCUPIED  # at once: safety first
    fuse(b, [PASS], 10.1)  # the person walked on, the next scan sees through
    assert state(b) is CellState.FREE
    assert b.raw_log_odds()[0, CELL] == -5.0


def test_a_person_in_space_seen_free_whom_nobody_sees_again_fades_as_a_transient():
    """A void cell's last ray hit (the person turned away from every unit): held while
    fresh, then faded with the transient half life; void still, so the next pass that
    sees through it clears it as before, and the next hit holds it at once again."""
    b = row_grid()
    half_life = b.sensor_model.transient_half_life
    fuse(b, [PASS] * 30, 0.0)
    fuse(b, [HIT], 10.0)
    assert b.log_odds_at(10.0 + half_life)[0, CELL] == pytest.approx(2.5, abs=1e-5)  # 5 / 2
    # no longer occupied after log2(5 / logit(0.65)) = 3.01 half lives
    assert state(b, 10.0 + 2.95 * half_life) is CellState.OCCUPIED
    assert state(b, 10.0 + 3.05 * half_life) is CellState.UNKNOWN
    assert b.void_mask()[0, CELL]
    fuse(b, [HIT], 60.0)  # seen again: at once
    assert state(b, 60.0) is CellState.OCCUPIED
    fuse(b, [PASS], 61.0)  # seen through: free, and stays free unobserved (void)
    assert state(b, 6000.0) is CellState.FREE


def test_a_rack_face_mapped_on_one_pass_is_lethal_ten_minutes_later_unobserved():
    b = row_grid()
    for k in range(10):  # one pass by the rack: 10 scans in 1 s hit its face
        fuse(b, [HIT], k / 10)
    assert b.structure_mask()[0, CELL]
    assert state(b, 600.0) is CellState.OCCUPIED  # no fade: nobody looked, nothing changed
    decay = BeliefGrid(GridGeometry(12, 1, 1.0), SensorModel(), Policy.DECAY)
    for k in range(10):
        decay.fuse(make_scan([HIT], stamp=k / 10))
    assert CellState(decay.states_at(600.0)[0, CELL]) is CellState.UNKNOWN  # decay forgets


def test_a_cell_hit_by_fewer_scans_in_a_row_is_new_and_fades_as_a_transient():
    b = row_grid()
    half_life = b.sensor_model.transient_half_life
    decay = BeliefGrid(
        GridGeometry(12, 1, 1.0),
        SensorModel(),
        Policy.DECAY,
        DecayParams(half_life_occupied=half_life),
    )
    for grid in (b, decay):
        for k in range(9):  # a person standing 0.9 s where nobody had looked
            grid.fuse(make_scan([HIT], stamp=k / 10))
    assert not b.structure_mask()[0, CELL] and not b.void_mask()[0, CELL]
    held = float(b.log_odds_at(0.8)[0, CELL])  # 9 hits of 0.847, clamped
    assert held == b.sensor_model.clamp_max
    for t in (5.0, 60.0, 600.0):  # decay's rule with the transient half life
        assert b.log_odds_at(t)[0, CELL] == decay.log_odds_at(t)[0, CELL]
    assert b.log_odds_at(0.8 + half_life)[0, CELL] == pytest.approx(held / 2, abs=1e-5)
    # no longer occupied after log2(5 / logit(0.65)) = 3.01 half lives
    assert state(b, 0.8 + 2.95 * half_life) is CellState.OCCUPIED
    assert state(b, 0.8 + 3.05 * half_life) is not CellState.OCCUPIED
    assert state(b, 600.0) is CellState.UNKNOWN


def test_a_pass_near_its_end_neither_resets_the_count_nor_drops_what_a_new_cell_held():
    """Range noise at a face: a beam that lands just beyond the face cell (within
    release_margin of it) passes through it. That is no evidence the cell is empty
    (DUFOMap's shortened ray), so the face's count of hits in a row goes on and only the
    textbook -0.405 comes off; a pass that ends far beyond it does both."""
    b = row_grid()
    fuse(b, [HIT] * 5, 0.0)
    fuse(b, [NEAR_DEFAULT], 0.1)  # ends 0.2 m beyond the cell
    faded = 5 * math.log(0.7 / 0.3) * 2 ** (-0.1 / b.sensor_model.transient_half_life)
    assert b.raw_log_odds()[0, CELL] == pytest.approx(faded - math.log(1.5), abs=1e-5)
    fuse(b, [HIT] * 4, 0.2)
    assert not b.structure_mask()[0, CELL]  # 9 hits so far
    fuse(b, [HIT], 0.3)
    assert b.structure_mask()[0, CELL]  # the 10th: the near pass did not reset the count
    other = row_grid()
    fuse(other, [HIT] * 5, 0.0)
    fuse(other, [PASS], 0.1)  # ends 4.5 m beyond: seen through
    assert other.raw_log_odds()[0, CELL] == pytest.approx(math.log(0.4 / 0.6), abs=1e-6)
    fuse(other, [HIT] * 5, 0.2)
    assert not other.structure_mask()[0, CELL]  # counted from 0 again: 5 of 10


def test_a_new_cell_seen_through_loses_what_it_held_in_one_pass():
    b = row_grid()
    for k in range(9):  # the person of the test above, then the next scan sees through
        b.fuse(make_scan([HIT], stamp=k / 10))
    b.fuse(make_scan([PASS], stamp=0.9))
    assert b.raw_log_odds()[0, CELL] == pytest.approx(math.log(0.4 / 0.6), abs=1e-6)
    assert state(b) is not CellState.OCCUPIED  # decay: 9 * 0.847 - 0.405 = 7.2, clamped 4.6
    for k in range(10, 20):  # a face, 10 scans in a row: structure, passes no longer reset
        b.fuse(make_scan([HIT], stamp=k / 10))
    assert b.structure_mask()[0, CELL]
    b.fuse(make_scan([PASS], stamp=2.0))
    assert state(b) is CellState.OCCUPIED  # 5 - 0.405


def test_a_moved_pod_on_structure_clears_in_two_clear_passes_then_turns_void():
    b = row_grid()
    fuse(b, [HIT] * 20, 0.0)  # a pod stood here since the start
    assert b.structure_mask()[0, CELL]
    passes = 0
    while state(b) is CellState.OCCUPIED:
        fuse(b, [PASS], 1.0)
        passes += 1
    assert passes == 2  # released at the second (decay and sticky: 11 and 13+)
    fuse(b, [PASS] * 7, 1.0)  # l0 - 8 x 0.405 < -2.944: void after 8 passes as new
    assert b.void_mask()[0, CELL]
    fuse(b, [HIT], 2.0)  # a tote set down where the pod stood: transient now
    fuse(b, [PASS], 2.1)
    assert state(b) is CellState.FREE


GEOMETRY = GridGeometry(200, 100, 0.1)
STEP = math.radians(1.0)
FACE_Y = 1.0 + 1e-6  # [m] a rack face along the bottom of row 10


def beams_to_face(x: float, first: float, last: float) -> Scan:
    """A scan from (x, 0.05) with beams 1 degree apart from ``first`` to ``last`` [rad],
    each returning from the face."""
    angles = np.arange(first, last, STEP)
    ranges = (FACE_Y - 0.05) / np.sin(angles)
    return Scan("u1", 0.0, Pose2D(x, 0.05, 0.0), float(angles[0]), STEP, 0.05, 20.0, ranges)


def grazed_face(model: SensorModel) -> tuple[np.ndarray, np.ndarray]:
    """A face mapped square on from below (x 3..12 m, once each), then grazed 200 times at
    5 to 40 degrees from (1.05, 0.05): the face's cells x 4..11 m (occupied, void)."""
    b = BeliefGrid(GEOMETRY, model, Policy.DUAL)
    for x in np.arange(3.0, 12.0, 0.25):
        b.fuse(beams_to_face(float(x), math.radians(80), math.radians(100)))
    for _ in range(200):
        b.fuse(beams_to_face(1.05, math.radians(5), math.radians(40)))
    face = (slice(10, 11), slice(40, 110))
    return b.states_at()[face] == CellState.OCCUPIED, b.void_mask()[face]


def test_a_rack_face_grazed_by_beams_is_not_worn_away():
    occupied, void = grazed_face(SensorModel())
    assert occupied.all() and not void.any()
    # Without the guard of glancing faces the same passes wear it away: the test can fail.
    occupied, void = grazed_face(SensorModel(guard_glancing_faces=False))
    assert not occupied.all() and void.any()


def test_state_arrays_round_trip_and_a_history_is_required():
    b = row_grid()
    fuse(b, [PASS] * 10 + [HIT], 3.0)
    other = row_grid()
    other.copy_state_from(b)
    assert np.array_equal(other.void_mask(), b.void_mask())
    assert np.array_equal(other.raw_log_odds(), b.raw_log_odds())
    with pytest.raises(ValueError, match="the dual policy needs a history array"):
        other.load_state(b.raw_log_odds(), b.last_observed(), 3.0)
    decay = BeliefGrid(GridGeometry(12, 1, 1.0), SensorModel(), Policy.DECAY)
    with pytest.raises(ValueError, match="the decay policy has no history array"):
        decay.load_state(stamp=3.0, **b.state_arrays())


def test_a_slow_recording_confirms_what_stayed_where_it_was_after_a_gap():
    b = row_grid()
    fuse(b, [HIT], 0.0)  # a wall, one scan every 3 s (the Intel lab's log)
    assert not b.structure_mask()[0, CELL]
    fuse(b, [HIT], 1.0)  # within confirm_after (2 s) of the last look: still new
    assert not b.structure_mask()[0, CELL]
    fuse(b, [HIT], 4.0)  # hit again 3 s on, no pass between: it stayed
    assert b.structure_mask()[0, CELL]
    person = row_grid()
    fuse(person, [HIT], 0.0)
    fuse(person, [PASS], 1.0)  # seen through: gone
    fuse(person, [HIT], 4.0)  # something there again: new, not confirmed
    assert not person.structure_mask()[0, CELL]
    trail = row_grid()  # confirm_within 60 s
    fuse(trail, [HIT], 0.0)  # a person crossing, nobody looking after
    fuse(trail, [HIT], 75.0)  # the same line walked again 75 s later: not "stayed"
    assert not trail.structure_mask()[0, CELL]
    fuse(trail, [HIT], 85.0)  # hit again 10 s on, nothing between: within the bound
    assert trail.structure_mask()[0, CELL]


@pytest.mark.parametrize(
    "field, value, reason",
    [
        ("void_threshold", 0.3, "must be below free_threshold (0.25)"),
        ("void_threshold", 0.0, "must be a probability strictly between 0 and 1"),
        ("confirm_hits", 0, "must be a whole number of scans, 1 to 252"),
        ("confirm_hits", 2.5, "must be a whole number of scans, 1 to 252"),
        ("confirm_after", -1.0, "must be positive seconds"),
        ("confirm_after", float("inf"), "must be positive seconds"),
        ("confirm_within", 1.0, "must be seconds, at least confirm_after (2.0)"),
        ("release_margin", 0.0, "must be a positive distance in metres"),
    ],
)
def test_the_dual_settings_refuse_bad_values_naming_them(field, value, reason):
    with pytest.raises(ValueError) as error:
        SensorModel(**{field: value})
    assert str(error.value).startswith(f"{field} {reason}")
