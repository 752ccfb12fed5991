"""The beam trace's one traversal: a CLEAR prefix and the FREE rest of a return's line
marked in one pass (``_trace_prefixed``) equal the two traces they replace, on a
reference Bresenham line written here."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mapserver.core import fusion_kernel as kernel

WIDTH, HEIGHT = 12, 9


def bresenham(c0: int, r0: int, c1: int, r1: int) -> list[tuple[int, int]]:
    """The cells from (c0, r0) to (c1, r1), both ends included: one per step along the
    major axis, a minor step whenever the error term (starting at half the major
    extent) goes negative."""
    dc, dr = c1 - c0, r1 - r0
    step_c, step_r = (1 if dc > 0 else -1), (1 if dr > 0 else -1)
    major, minor = max(abs(dc), abs(dr)), min(abs(dc), abs(dr))
    c, r, err = c0, r0, major >> 1
    cells = []
    for _ in range(major + 1):
        cells.append((c, r))
        err -= minor
        minor_step = err < 0
        if minor_step:
            err += major
        if abs(dc) >= abs(dr):
            c += step_c
            r += step_r if minor_step else 0
        else:
            r += step_r
            c += step_c if minor_step else 0
    return cells


cells_strategy = st.tuples(st.integers(0, WIDTH - 1), st.integers(0, HEIGHT - 1))


@settings(max_examples=300, deadline=None)
@given(
    cells_strategy, cells_strategy, st.data(),
    st.sampled_from([kernel.MARK_NO_RETURN, kernel.MARK_FREE]),
    st.lists(st.integers(kernel.MARK_NONE, kernel.MARK_HIT), min_size=WIDTH * HEIGHT,
             max_size=WIDTH * HEIGHT),
)  # fmt: skip
def test_one_traversal_marks_what_the_two_traces_marked(start, end, data, mark, before):
    line = bresenham(*start, *end)
    count = data.draw(st.integers(0, len(line)))
    prefix = data.draw(st.integers(0, len(line) - 1))
    expected = np.array(before, dtype=np.uint8)
    for i, (c, r) in enumerate(line):
        strongest = max(
            mark if i < count else kernel.MARK_NONE,
            kernel.MARK_CLEAR if i < prefix else kernel.MARK_NONE,
        )
        expected[r * WIDTH + c] = max(expected[r * WIDTH + c], strongest)
    marks = np.array(before, dtype=np.uint8)
    kernel._trace_prefixed(marks, WIDTH, *start, *end, count, mark, prefix, kernel.MARK_CLEAR)
    assert np.array_equal(marks, expected)


@settings(max_examples=200, deadline=None)
@given(cells_strategy, cells_strategy, st.booleans(), st.integers(-1, WIDTH + HEIGHT))
def test_a_line_count_is_the_cells_traced(start, end, include_last, max_cells):
    line = bresenham(*start, *end)
    count = len(line) if include_last else len(line) - 1
    if max_cells >= 0:
        count = min(count, max_cells)
    assert kernel._line_count(*start, *end, include_last, max_cells) == count
    marks = np.zeros(WIDTH * HEIGHT, dtype=np.uint8)
    kernel._trace(marks, WIDTH, *start, *end, include_last, kernel.MARK_FREE, max_cells)
    traced = {(i % WIDTH, i // WIDTH) for i in np.flatnonzero(marks)}
    assert traced == set(line[:count])
