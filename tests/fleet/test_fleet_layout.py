"""Warehouse layouts: built from boxworld or from a scenario mapping, validated."""

import math

import numpy as np
import pytest

from fleet.boxworld import warehouse_layout
from fleet.layout import DEFAULT_HEIGHT_M, Kind, Layout, LayoutError, Obstacle, Station
from fleet.shapes import Box, Cylinder, wrap_angle


def small_dict(**extra):
    data = {
        "floor": {"width": 10.0, "height": 6.0},
        "obstacles": [
            {"id": "rack-a", "kind": "rack", "box": {"x": 5, "y": 3, "size_x": 4, "size_y": 1}},
            {"id": "bob", "kind": "person", "cylinder": {"x": 2, "y": 2, "radius": 0.25}},
        ],
        "stations": [{"id": "pick-1", "x": 1.0, "y": 5.0}],
    }
    data.update(extra)
    return data


def test_a_boxworld_warehouse_becomes_walls_racks_and_pallets_with_ids_and_lanes():
    warehouse = warehouse_layout(30.0, 20.0, seed=3, cross_aisle_every_m=10.0)
    layout = Layout.from_warehouse(warehouse)
    kinds = [o.kind for o in layout.obstacles]
    assert kinds.count(Kind.WALL) == 4 and kinds.count(Kind.RACK) > 0
    assert layout.obstacle("wall-1").kind is Kind.WALL
    assert layout.obstacle("rack-1").height == DEFAULT_HEIGHT_M[Kind.RACK]
    assert layout.lane_x == warehouse.lane_x and layout.lane_y == warehouse.lane_y
    for obstacle, (xmin, ymin, xmax, ymax) in zip(
        layout.obstacles, warehouse.world.boxes, strict=True
    ):
        assert obstacle.shape.bounds() == pytest.approx((xmin, ymin, xmax, ymax))


def test_a_mapping_round_trips_through_to_dict():
    layout = Layout.from_dict(small_dict())
    assert layout.obstacle("bob").shape == Cylinder(2, 2, 0.25)
    assert layout.obstacle("bob").height == DEFAULT_HEIGHT_M[Kind.PERSON]
    assert layout.stations == (Station("pick-1", 1.0, 5.0),)
    assert Layout.from_dict(layout.to_dict()) == layout


def test_a_warehouse_mapping_adds_extra_obstacles_to_the_generated_ones():
    data = {
        "warehouse": {"width_m": 30.0, "height_m": 20.0, "seed": 3},
        "obstacles": [
            {"id": "tote-1", "kind": "tote", "box": {"x": 2, "y": 5, "size_x": 0.6, "size_y": 0.4}}
        ],
    }
    layout = Layout.from_dict(data)
    generated = Layout.from_warehouse(warehouse_layout(30.0, 20.0, seed=3))
    assert layout.obstacles[:-1] == generated.obstacles
    assert layout.obstacles[-1].id == "tote-1" and layout.lane_x == generated.lane_x


def one(kind="rack", shape="box", height=None, **fields):
    """A one-obstacle change to the small layout (a unit box at (1, 1) unless told)."""
    geometry = {"x": 1, "y": 1, **({"size_x": 1, "size_y": 1} if shape == "box" else {})}
    geometry.update(fields)
    item = {"id": "o", "kind": kind, shape: geometry}
    if height is not None:
        item["height"] = height
    return {"obstacles": [item]}


@pytest.mark.parametrize(
    ("change", "field", "value"),
    [
        ({"floor": {"width": -1, "height": 6}}, "width", -1),
        ({"floor": {"width": 10}}, "floor.height", None),
        ({"lanes": {"x": [1.0, "a"]}}, "lanes.x[1]", "a"),
        ({"colour": "red"}, "colour", "red"),
        (one(size_x=0), "obstacles[0].box.size_x", 0),
        (one(kind="shelf"), "obstacles[0].kind", "shelf"),
        (one(x=9.9), "obstacles[0]", None),
        (one("person", "cylinder", height=-2, radius=0.2), "obstacles[0].height", -2),
        (one("person", "cylinder", radius=0.2, yaw=1.0), "obstacles[0].cylinder.yaw", 1.0),
        ({"obstacles": [{"id": "p", "kind": "person"}]}, "obstacles[0]", None),
        ({"stations": [{"id": "s", "x": 5.0, "y": 3.0}]}, "stations[0]", (5.0, 3.0)),
    ],
)
def test_errors_name_the_field_and_the_bad_value(change, field, value):
    data = small_dict(**change)
    with pytest.raises(LayoutError) as caught:
        Layout.from_dict(data)
    assert caught.value.field == field
    if value is not None:
        assert caught.value.value == value
        assert repr(value) in str(caught.value)


def test_duplicate_ids_are_refused():
    data = small_dict()
    data["obstacles"].append(dict(data["obstacles"][0]))
    with pytest.raises(LayoutError, match=r"obstacles\[2\].id: duplicates"):
        Layout.from_dict(data)


def test_box_and_cylinder_footprints_contain_their_boundary_and_measure_distance():
    box = Box(1.0, 2.0, 2.0, 1.0, yaw=math.pi / 2)  # turned: 1 m along x, 2 m along y
    assert box.bounds() == pytest.approx((0.5, 1.0, 1.5, 3.0))
    assert box.contains(1.5, 3.0) and box.contains(1.0, 2.9) and not box.contains(1.6, 2.0)
    assert float(box.distance(2.5, 2.0)) == pytest.approx(1.0)
    assert float(box.distance(1.0, 2.0)) == 0.0
    circle = Cylinder(0.0, 0.0, 0.5)
    assert circle.contains(np.array([0.5, 0.6]), 0.0).tolist() == [True, False]
    assert float(circle.distance(3.0, 4.0)) == pytest.approx(4.5)
    assert Obstacle("b", Kind.POD, box).moved(4.0, 4.0, 0.0).shape == Box(4.0, 4.0, 2.0, 1.0)


def test_wrap_angle_stays_in_minus_pi_to_pi():
    values = np.linspace(-20, 20, 101)
    wrapped = np.array([wrap_angle(float(v)) for v in values])
    assert np.all((wrapped >= -math.pi) & (wrapped < math.pi))
    assert np.allclose(np.cos(wrapped), np.cos(values)) and np.allclose(
        np.sin(wrapped), np.sin(values)
    )
