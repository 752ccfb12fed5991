"""Stations snap to their nearest lane stretch (``_place_stations``), the candidates
found for all stretches at once in numpy: the same stretch, place and errors as the
loop over every stretch it replaces."""

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from planner.lane_graph import _place_stations, nearest_stretch


def loop_nearest(stations, stretches, positions):
    """The loop over every stretch (``nearest_stretch`` of them all), as
    ``_place_stations`` did before it measured only numpy's candidates."""
    every = range(len(stretches))
    return {sid: nearest_stretch(*stations[sid], stretches, positions, every) for sid in stations}


@settings(max_examples=80, deadline=None)
@given(
    stations=st.dictionaries(
        st.from_regex(r"s[0-9]{1,3}", fullmatch=True),
        st.tuples(st.floats(0.0, 32.0), st.floats(0.0, 32.0)),
        max_size=8,
    )
)
def test_each_station_goes_where_the_loop_over_every_stretch_puts_it(stations):
    # a 7 x 7 lane grid, 5 m apart: stretches between neighbouring junctions
    positions = {f"j{i}_{j}": (5.0 * i + 1.83, 5.0 * j + 1.83) for i in range(7) for j in range(7)}
    stretches = [(f"j{i}_{j}", f"j{i + 1}_{j}", "h") for i in range(6) for j in range(7)]
    stretches += [(f"j{i}_{j}", f"j{i}_{j + 1}", "v") for i in range(7) for j in range(6)]
    expected = loop_nearest(stations, stretches, dict(positions))
    placed = dict(positions)
    try:
        stops = _place_stations(stations, stretches, placed, snap_m=1.0)
    except ValueError as exc:
        # too far from every lane, or on a node: the loop's nearest says the same
        sid = str(exc).split("'")[1]
        gap, index, t = expected[sid]
        a, b, _ = stretches[index]
        length = math.dist(positions[a], positions[b])
        assert gap > 1.0 or min(t, length - t) < 1e-6 or "falls on another node" in str(exc)
        return
    for sid, (gap, index, t) in expected.items():
        assert gap <= 1.0
        assert (t, sid) in stops[index]
