"""``ZoneLayout``: strips, borders, which zones a scan goes to, and stitching."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from mapserver.client.zones import MAX_ZONES, ZoneLayout
from mapserver.core.errors import FieldError
from mapserver.core.geometry import GridGeometry
from mapserver.service.settings import load_settings
from scenarios.cli.main import main


@st.composite
def layouts(draw):
    width = draw(st.integers(1, 600))
    resolution = draw(st.sampled_from([0.05, 0.1, 0.25]))
    origin = draw(st.floats(-50, 50, allow_nan=False))
    site = GridGeometry(width, draw(st.integers(1, 5)), resolution, origin, -3.0)
    zones = draw(st.integers(1, min(width, 9)))
    range_m = draw(st.floats(0, 30))
    margin_m = draw(st.floats(0, 2))
    return ZoneLayout.strips(site, zones, range_m, margin_m), range_m


@given(layouts())
@settings(max_examples=200, deadline=None)
def test_the_cores_cut_the_site_and_every_grid_holds_its_core_on_site_cells(case):
    layout, _ = case
    site = layout.site
    assert layout.cuts[0] == 0 and layout.cuts[-1] == site.width
    assert all(b > a for a, b in zip(layout.cuts, layout.cuts[1:], strict=False))
    for k in range(layout.zones):
        first, end = layout.grid_columns(k)
        core = layout.core(k)
        assert 0 <= first <= core[0] < core[1] <= end <= site.width
        zone = layout.geometry(k)
        assert (zone.width, zone.height, zone.resolution) == (
            end - first,
            site.height,
            site.resolution,
        )
        assert zone.origin_x == site.origin_x + first * site.resolution
        assert zone.origin_y == site.origin_y


@given(layouts(), st.floats(0, 1), st.floats(0, 1), st.floats(-math.pi, math.pi))
@settings(max_examples=300, deadline=None)
def test_a_scan_goes_to_every_zone_whose_band_it_can_observe_and_stands_on_its_grid(
    case, where, reach, bearing
):
    layout, range_m = case
    site = layout.site
    x = site.origin_x + where * site.width * site.resolution * 0.999999
    seen = x + reach * range_m * math.cos(bearing)  # a point the LiDAR can observe
    col = math.floor((seen - site.origin_x) / site.resolution)
    posts = layout.posts_to(x)
    assert layout.home(x) in posts
    first, end = layout.core(layout.home(x))
    assert first <= math.floor((x - site.origin_x) / site.resolution) < end
    for k in range(layout.zones):
        band = (layout.core(k)[0] - layout.margin_cells, layout.core(k)[1] + layout.margin_cells)
        if band[0] <= col < band[1]:
            assert k in posts, (k, x, seen)
    for k in posts:
        assert layout.geometry(k).contains_point(x, site.origin_y)
    many = layout.posts_to_many(np.array([x]))[0]
    assert np.flatnonzero(many).tolist() == posts
    assert layout.homes(np.array([x])).tolist() == [layout.home(x)]


@given(layouts(), st.integers(0, 2**32 - 1))
@settings(max_examples=100, deadline=None)
def test_stitching_the_zones_slices_of_a_site_array_gives_it_back(case, seed):
    layout, _ = case
    site = np.random.default_rng(seed).integers(0, 255, layout.site.shape, dtype=np.uint8)
    parts = [site[:, slice(*layout.grid_columns(k))] for k in range(layout.zones)]
    np.testing.assert_array_equal(layout.stitch(parts), site)


def test_the_default_strips_of_the_thousand_unit_floor():
    site = GridGeometry(4000, 2000, 0.1)
    layout = ZoneLayout.strips(site, 4, 20.0, 0.55)
    assert layout.cuts == (0, 1000, 2000, 3000, 4000)
    assert layout.margin_cells == 6  # 0.55 m: 5.5 cells, and one to spare
    assert layout.reach_m == pytest.approx(20.1)
    assert layout.border_cells == 202 + 6
    assert [layout.grid_columns(k) for k in range(4)] == [
        (0, 1208), (792, 2208), (1792, 3208), (2792, 4000),
    ]  # fmt: skip
    assert layout.home(-5.0) == 0 and layout.home(399.99) == 3 and layout.home(1e9) == 3


@pytest.mark.parametrize(
    ("zones", "range_m", "margin_m", "field"),
    [
        (0, 20.0, 0.5, "zones"),
        (MAX_ZONES + 1, 20.0, 0.5, "zones"),
        (11, 20.0, 0.5, "zones"),  # more zones than the site's 10 columns
        (True, 20.0, 0.5, "zones"),
        (2, -1.0, 0.5, "range_m"),
        (2, math.inf, 0.5, "range_m"),
        (2, 20.0, math.nan, "margin_m"),
    ],
)
def test_bad_strips_are_refused_naming_the_field_and_value(zones, range_m, margin_m, field):
    with pytest.raises(FieldError) as caught:
        ZoneLayout.strips(GridGeometry(10, 10, 0.1), zones, range_m, margin_m)
    assert caught.value.field == field


def test_a_layout_whose_border_cannot_hold_its_reach_is_refused():
    with pytest.raises(FieldError, match="border_cells.*at least 52 cells"):
        ZoneLayout(GridGeometry(300, 10, 0.1), (0, 150, 300), 5.0, 1, 40)
    with pytest.raises(FieldError, match="cuts"):
        ZoneLayout(GridGeometry(300, 10, 0.1), (0, 150, 150, 300), 5.0, 1, 60)


# ---------------------------------------------------------------- the layout as files


@given(layouts())
@settings(max_examples=100, deadline=None)
def test_a_layout_reads_back_from_its_dict_and_its_yaml(case):
    layout, _ = case
    assert ZoneLayout.from_dict(layout.to_dict()) == layout
    assert ZoneLayout.from_dict(yaml.safe_load(yaml.safe_dump(layout.to_dict()))) == layout


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"cuts": None}, "cuts"),
        ({"cuts": [0, 1.5, 300]}, "cuts"),
        ({"site": {"width": 300}}, "site"),
        ({"site": "big"}, "site"),
        ({"reach_m": "far"}, "reach_m"),
        ({"margin_cells": -1}, "margin_cells"),
        ({"border_cells": 3}, "border_cells"),
    ],
)
def test_a_bad_layout_dict_is_refused_naming_the_field(change, field):
    good = ZoneLayout.strips(GridGeometry(300, 10, 0.1), 2, 5.0, 0.55).to_dict()
    with pytest.raises(FieldError) as caught:
        ZoneLayout.from_dict({**good, **change})
    assert caught.value.field == field
    with pytest.raises(FieldError, match="reach_m is missing"):
        ZoneLayout.from_dict({k: v for k, v in good.items() if k != "reach_m"})


def test_fleetmap_zones_writes_a_serve_config_per_zone_and_the_layout(tmp_path, capsys):
    out = tmp_path / "zones"
    argv = ["zones", "--width", "4000", "--height", "2000", "--resolution", "0.1",
            "--origin", "-10,-5", "--zones", "4", "--out", str(out), "--json"]  # fmt: skip
    assert main(argv) == 0
    printed = capsys.readouterr().out.splitlines()
    layout = ZoneLayout.from_dict(json.loads(printed[-1]))
    assert layout == ZoneLayout.strips(GridGeometry(4000, 2000, 0.1, -10.0, -5.0), 4, 20.0, 0.55)
    assert "   1              90 to 190          69.2 to 210.8    1416 x 2000" in printed
    assert ZoneLayout.from_dict(yaml.safe_load((out / "zones.yaml").read_text())) == layout
    for k in range(4):  # each file is a server config whose grid is the zone's
        settings = load_settings(out / f"zone-{k}.yaml", {"data_dir": tmp_path / f"d{k}"})
        assert settings.geometry() == layout.geometry(k)


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--zones", "0"], "--zones: must be a whole number in [1, 64], got 0"),
        (["--zones", "2", "--range", "-1"], "--range: must be finite metres >= 0, got -1.0"),
        (["--zones", "2", "--resolution", "0"], "--resolution: must be positive metres"),
        (["--zones", "2", "--inflation-radius", "nan"], "--inflation-radius: must be finite"),
        (["--zones", "99"], "--zones: must be a whole number in [1, 64], got 99"),
    ],
)
def test_fleetmap_zones_refuses_a_bad_value_naming_the_option(tmp_path, capsys, flags, message):
    out = tmp_path / "zones"
    assert main(["zones", "--width", "50", "--height", "20", *flags, "--out", str(out)]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"fleetmap zones: error: {message}")
    assert line.endswith("(see --help)")
    assert not out.exists()
