"""CARMEN logs written by the tests (``recording_helpers``): FLASER and ROBOTLASER1,
plain and gzip, the laser pose fields, CARMEN's beam geometry and SICK's no-return codes,
and malformed lines named by file:line and field."""

import gzip
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from recording_helpers import Motion, assert_room_map, carmen_lines, fused_room, write_carmen

from mapserver.store.recordings import RecordingError, RecordingOptions, open_recording
from mapserver.store.recordings.carmen_log import carmen_beam_layout, rep117_ranges


@pytest.mark.parametrize("kind", ["FLASER", "ROBOTLASER1"])
@pytest.mark.parametrize("name", ["lab.log", "lab.log.gz", "lab.clf", "lab.gfs.gz"])
def test_a_log_reproduces_the_room_from_the_laser_pose_fields(tmp_path, kind, name):
    path = write_carmen(tmp_path / name, carmen_lines(kind))
    recording = open_recording(path)
    assert recording.scan_count() == 12 and f"CARMEN log, 12 {kind} scans" in recording.describe()
    scans = list(recording)
    motion = Motion()
    for k, scan in enumerate(scans):
        assert scan.stamp == pytest.approx(motion.t0 + 0.5 * k, abs=1e-6)
        x, y, yaw = motion.laser_in_map(scan.stamp)
        assert (scan.pose.x, scan.pose.y, scan.pose.yaw) == pytest.approx((x, y, yaw), abs=1e-8)
    assert {s.unit_id for s in scans} == {"lab"}
    belief, states = fused_room(scans)
    assert_room_map(states, belief.geometry, walls_seen=0.9 if kind == "ROBOTLASER1" else 0)


def test_gzip_is_known_by_its_magic_bytes_and_a_log_by_its_lines(tmp_path):
    path = tmp_path / "recording.txt"
    path.write_bytes(gzip.compress("\n".join(carmen_lines("FLASER", scans=3)).encode()))
    assert len(list(open_recording(path))) == 3


def test_carmen_beam_layouts_follow_readlog():
    deg = math.pi / 180
    assert carmen_beam_layout(181) == (-math.pi / 2, deg)  # -90 .. +90
    assert carmen_beam_layout(180) == (-math.pi / 2, deg)  # -90 .. +89, last beam dropped
    assert carmen_beam_layout(361) == (-math.pi / 2, deg / 2)
    assert carmen_beam_layout(360) == (-math.pi / 2, deg / 2)
    assert carmen_beam_layout(401) == pytest.approx((-50 * deg, deg / 4))  # centred
    assert carmen_beam_layout(91) == pytest.approx((-math.pi / 2, 2 * deg))


def test_sick_max_range_codes_are_no_return_and_zero_is_invalid():
    ranges = rep117_ranges(np.array([81.83, 81.91, 80.0, 79.99, 0.0, 3.5]), 80.0)
    assert ranges[:3].tolist() == [math.inf] * 3
    assert ranges[3] == 79.99 and math.isnan(ranges[4]) and ranges[5] == 3.5
    assert rep117_ranges(np.array([81.83, 29.0]), 100.0).tolist() == [math.inf, 29.0]


def test_robotlaser1_lines_win_over_flaser_lines_of_the_same_log(tmp_path):
    lines = carmen_lines("FLASER", scans=4) + carmen_lines("ROBOTLASER1", scans=3)
    recording = open_recording(write_carmen(tmp_path / "both.log", lines))
    assert recording.scan_count() == 3
    assert [s.beam_count for s in recording] == [361] * 3


def test_out_of_order_stamps_are_put_in_order(tmp_path):
    lines = carmen_lines("FLASER", scans=5)
    lasers = [i for i, line in enumerate(lines) if line.startswith("FLASER")]
    lines[lasers[1]], lines[lasers[2]] = lines[lasers[2]], lines[lasers[1]]
    stamps = [s.stamp for s in open_recording(write_carmen(tmp_path / "x.log", lines))]
    assert stamps == sorted(stamps) and len(stamps) == 5


def test_start_and_end_count_from_the_first_laser_stamp(tmp_path):
    path = write_carmen(tmp_path / "x.log", carmen_lines("FLASER", scans=10))
    scans = list(open_recording(path, RecordingOptions(start=1.0, end=2.0)))
    assert [s.stamp - Motion().t0 for s in scans] == pytest.approx([1.0, 1.5, 2.0])


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda w: w[:3] + ["x"] + w[4:], "FLASER field 'ranges[1]': expected a number, got 'x'"),
        (lambda w: w[:1] + ["1.5"] + w[2:], "FLASER field 'num_readings': expected a count"),
        (lambda w: w[:-5], "FLASER field 'odom_y': missing"),
        (lambda w: w[:1] + ["200"] + w[2:], "FLASER field 'ranges[190]': missing (200 expected)"),
    ],
)
def test_a_malformed_line_is_named_by_file_line_and_field(tmp_path, edit, message):
    lines = carmen_lines("FLASER", scans=2)
    index = max(i for i, line in enumerate(lines) if line.startswith("FLASER"))
    lines[index] = " ".join(edit(lines[index].split()))
    path = write_carmen(tmp_path / "bad.log", lines)
    with pytest.raises(RecordingError) as error:
        list(open_recording(path))
    assert str(error.value).startswith(f"{path}:{index + 1}: ")
    assert message in str(error.value)


def test_a_log_without_laser_lines_says_so(tmp_path):
    path = write_carmen(tmp_path / "odom.log", ["ODOM 0 0 0 0 0 0 1.0 host 1.0"])
    with pytest.raises(RecordingError, match="a CARMEN log without laser messages"):
        open_recording(path).scan_count()


@given(st.lists(st.floats(0.0, 100.0, allow_nan=False), min_size=1, max_size=30))
def test_any_flaser_line_parses_to_its_values(values):
    import tempfile
    from pathlib import Path

    body = " ".join(repr(v) for v in values)
    line = f"FLASER {len(values)} {body} 1.0 2.0 0.5 0 0 0 42.0 host 42.0"
    with tempfile.TemporaryDirectory() as folder:
        (scan,) = open_recording(write_carmen(Path(folder) / "p.log", [line]))
    expected = rep117_ranges(np.array(values), 80.0).astype(np.float32).astype(np.float64)
    np.testing.assert_array_equal(scan.ranges, expected)
    assert (scan.pose.x, scan.pose.y, scan.pose.yaw, scan.stamp) == (1.0, 2.0, 0.5, 42.0)
