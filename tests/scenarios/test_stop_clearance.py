"""Stops and starts clear of the layout's obstacles, checked for all points at once
(``first_offenders``): the same offender, in the same order, as a loop over every
obstacle for every point."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.layout import Kind, Layout, Obstacle
from fleet.shapes import Box, Cylinder
from scenarios.spec.layout import first_offenders
from scenarios.spec.scenario import load_scenario

coord = st.floats(5.0, 25.0, allow_nan=False)  # shapes stay on the 30 m x 30 m floor
anywhere = st.floats(0.0, 30.0, allow_nan=False)
boxes = st.builds(
    lambda x, y, sx, sy, yaw: Box(x, y, sx, sy, yaw),
    coord, coord, st.floats(0.1, 4.0), st.floats(0.1, 4.0), st.floats(-math.pi, math.pi),
)  # fmt: skip
cylinders = st.builds(lambda x, y, r: Cylinder(x, y, r), coord, coord, st.floats(0.05, 2.0))


def brute_force(layout: Layout, point, clearance: float):
    """The loop ``first_offenders`` replaces: the first obstacle within reach, in order."""
    for obstacle in layout.obstacles:
        gap = float(obstacle.shape.distance(*point))
        if gap <= clearance:
            return obstacle, gap
    return None


@settings(max_examples=60, deadline=None)
@given(
    shapes=st.lists(st.one_of(boxes, cylinders), max_size=12),
    points=st.lists(st.tuples(anywhere, anywhere), max_size=15),
    clearance=st.floats(0.0, 1.5),
)
def test_the_first_offender_of_each_point_is_the_loops(shapes, points, clearance):
    obstacles = tuple(Obstacle(f"o{i}", Kind.POD, s) for i, s in enumerate(shapes))
    layout = Layout(30.0, 30.0, obstacles)
    assert first_offenders(layout, points, clearance) == [
        brute_force(layout, p, clearance) for p in points
    ]


def test_no_points_no_offenders():
    assert first_offenders(Layout(5.0, 5.0, ()), [], 0.5) == []


def test_a_thousand_units_and_their_stops_load_in_seconds_not_minutes():
    """thousand_units: 1,000 starts and 737 stops against 3,041 obstacles (the checks were
    a loop per point and obstacle: half a minute on this machine)."""
    scenario = load_scenario("scenarios/thousand_units.yaml")
    assert scenario.units.count == 1000 and len(scenario.unit_specs()) == 1000
    assert len(scenario.layout.obstacles) == 3041 and len(scenario.stops()) == 737
    specs = scenario.unit_specs()
    assert len({(s.start.x, s.start.y) for s in specs}) == 1000


@pytest.mark.parametrize("clearance", [0.0, 0.45])
def test_a_point_inside_an_obstacle_names_the_first_obstacle_in_layout_order(clearance):
    a = Obstacle("a", Kind.RACK, Box(5.0, 5.0, 2.0, 2.0))
    b = Obstacle("b", Kind.POD, Box(5.0, 5.0, 1.0, 1.0))
    found = first_offenders(Layout(10.0, 10.0, (a, b)), [(5.0, 5.0), (9.0, 9.0)], clearance)
    assert found == [(a, 0.0), None]
