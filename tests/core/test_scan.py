"""Scan validation (docs/http-api.md 2.1) and REP 117 classification."""

import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mapserver.core.scan import (
    BEAM_INVALID,
    BEAM_NO_RETURN,
    BEAM_RETURN,
    Scan,
    ScanError,
    classify_ranges,
)
from mapserver.store.scanfile import ScanFileError, parse_scan_lines


def valid() -> dict:
    return {
        "unit_id": "u1",
        "stamp": 12.3,
        "frame": "map",
        "pose": {"x": 1.0, "y": 2.0, "yaw": 0.1},
        "pose_std": {"xy": 0.02, "yaw": 0.01},
        "angle_min": -3.14159,
        "angle_increment": 0.01745,
        "range_min": 0.05,
        "range_max": 20.0,
        "ranges": [1.2, 1.25, 21.0, None],
    }


def test_the_contract_example_parses():
    scan = Scan.from_dict(valid())
    assert scan.beam_count == 4
    assert scan.pose.yaw == 0.1 and scan.pose_std.xy == 0.02
    assert math.isnan(scan.ranges[3])
    assert scan.beam_classes().tolist() == [BEAM_RETURN, BEAM_RETURN, BEAM_NO_RETURN, BEAM_INVALID]


def test_rep_117_range_classes():
    ranges = np.array([0.01, 0.05, 3.0, 20.0, 20.01, math.inf, math.nan, -1.0, -math.inf])
    assert classify_ranges(ranges, 0.05, 20.0).tolist() == [
        BEAM_INVALID, BEAM_RETURN, BEAM_RETURN, BEAM_RETURN, BEAM_NO_RETURN,
        BEAM_NO_RETURN, BEAM_INVALID, BEAM_INVALID, BEAM_INVALID,
    ]  # fmt: skip


def with_field(path: str, value):
    data = valid()
    target = data
    *parents, leaf = path.split(".")
    for p in parents:
        target = target[p]
    if value is KeyError:
        del target[leaf]
    else:
        target[leaf] = value
    return data


@pytest.mark.parametrize(
    "path, value, field",
    [
        ("pose.x", math.nan, "pose.x"),
        ("pose.yaw", math.inf, "pose.yaw"),
        ("pose", KeyError, "pose"),
        ("stamp", "12", "stamp"),
        ("stamp", True, "stamp"),
        ("frame", "odom", "frame"),
        ("unit_id", "", "unit_id"),
        ("angle_increment", -0.01, "angle_increment"),
        ("angle_increment", 0.0, "angle_increment"),
        ("range_max", 0.01, "range_max"),
        ("range_min", -1.0, "range_min"),
        ("ranges", [], "ranges"),
        ("ranges", "1,2,3", "ranges"),
        ("ranges", [1.0, "x", 2.0], "ranges[1]"),
        ("ranges", [1.0, True], "ranges[1]"),
        ("pose_std.xy", -0.1, "pose_std.xy"),
        ("pose_std.xy", 1e200, "pose_std.xy"),  # its square overflowed the fusion
        ("pose_std.yaw", 1e4, "pose_std.yaw"),
    ],
)
def test_each_bad_field_is_named_with_its_value(path, value, field):
    with pytest.raises(ScanError) as info:
        Scan.from_dict(with_field(path, value))
    assert info.value.field == field
    assert str(info.value).startswith(f"{field}: ")


def test_beam_count_limit():
    data = with_field("ranges", [1.0] * 11)
    with pytest.raises(ScanError, match="at most 10 beams"):
        Scan.from_dict(data, max_beams=10)


json_values = st.recursive(
    st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner),
    max_leaves=12,
)


@given(st.dictionaries(st.sampled_from(list(valid())), json_values))
def test_arbitrary_json_is_either_a_scan_or_a_scan_error(fields):
    data = {**valid(), **fields}
    try:
        scan = Scan.from_dict(data)
    except ScanError as exc:
        assert exc.field.split(".")[0].split("[")[0] in valid() | {"scan": None}
    else:
        assert scan.range_max > scan.range_min and scan.angle_increment > 0


@given(
    ranges=st.lists(st.one_of(st.none(), st.floats(0, 30), st.just(math.inf)), min_size=1),
    stamp=st.floats(-1e9, 1e9),
)
def test_to_dict_round_trips_through_json(ranges, stamp):
    data = {**valid(), "ranges": ranges, "stamp": stamp}
    scan = Scan.from_dict(data)
    again = Scan.from_dict(json.loads(json.dumps(scan.to_dict())))
    assert again.to_dict() == scan.to_dict()
    assert np.array_equal(again.ranges, scan.ranges, equal_nan=True)


def test_scan_lines_name_the_line_and_field():
    lines = [json.dumps(valid()), "", json.dumps(with_field("pose.x", None))]
    with pytest.raises(ScanFileError, match=r"scans.jsonl:3: pose.x") as info:
        list(parse_scan_lines(lines, "scans.jsonl"))
    assert info.value.line == 3 and info.value.field == "pose.x"
    with pytest.raises(ScanFileError, match=r":1: json: not valid JSON"):
        list(parse_scan_lines(["{oops"], "scans.jsonl"))


def test_ranges_that_span_more_than_one_turn_are_refused():
    data = {**valid(), "angle_increment": 0.1, "ranges": [1.0] * 64}  # 63 steps = 6.3 rad
    with pytest.raises(ScanError, match="ranges: must fit in one turn") as info:
        Scan.from_dict(data)
    assert info.value.field == "ranges"
    assert Scan.from_dict({**data, "ranges": [1.0] * 63}).beam_count == 63
