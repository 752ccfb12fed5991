"""The recording interface on scan files, the grid sized from the data, and ``map build``
without a grid."""

import json

import numpy as np
import pytest
import yaml
from conftest import make_scan

from mapserver.core.scan import Scan
from mapserver.store.recordings import RecordingError, RecordingOptions, open_recording
from mapserver.store.recordings.grid_fit import MAX_FITTED_CELLS, fit_grid
from mapserver.store.scanfile import write_scan_file
from scenarios.cli.main import main


def test_a_scan_file_streams_its_scans_again_on_each_pass(tmp_path):
    path = tmp_path / "s.jsonl"
    write_scan_file(path, [make_scan([5.0], stamp=float(i)) for i in range(4)])
    recording = open_recording(path)
    assert recording.scan_count() == 4
    assert [s.stamp for s in recording] == [0.0, 1.0, 2.0, 3.0]
    assert [s.stamp for s in recording] == [0.0, 1.0, 2.0, 3.0]


def test_start_and_end_count_from_the_first_stamp_and_unit_id_relabels(tmp_path):
    path = tmp_path / "s.jsonl"
    write_scan_file(path, [make_scan([5.0], stamp=100.0 + i) for i in range(6)])
    options = RecordingOptions(start=1.0, end=3.0, unit_id="lab")
    scans = list(open_recording(path, options))
    assert [s.stamp for s in scans] == [101.0, 102.0, 103.0]
    assert {s.unit_id for s in scans} == {"lab"}


@pytest.mark.parametrize(
    "options, message",
    [
        (dict(start=-1.0), "--start must be seconds >= 0, got -1.0"),
        (dict(end=float("nan")), "--end must be seconds >= 0, got nan"),
        (dict(start=5.0, end=2.0), "--end (2.0 s) is before --start (5.0 s)"),
    ],
)
def test_bad_time_windows_are_named(options, message):
    with pytest.raises(RecordingError) as error:
        RecordingOptions(**options)
    assert str(error.value) == message


def test_unknown_paths_and_formats_are_named(tmp_path):
    with pytest.raises(RecordingError, match="nope.bin: no such file or folder"):
        open_recording(tmp_path / "nope.bin")
    (tmp_path / "x.bin").write_bytes(b"\0")
    with pytest.raises(RecordingError, match=r"x.bin: not a recording fleetmap reads \(it reads: "):
        open_recording(tmp_path / "x.bin")


def test_the_fitted_grid_holds_every_pose_and_return_plus_the_margin():
    # A sensor at (-3, 2) facing +x with returns at 4 m (0 rad) and 2 m (pi/2): ends at
    # (1, 2) and (-3, 4); a no-return beam (inf) reaches nothing and sizes nothing.
    scan = make_scan([4.0, 2.0, float("inf")], x=-3.0, y=2.0, angle_increment=np.pi / 2)
    grid = fit_grid([scan], resolution=0.5, margin=1.0)
    assert (grid.origin_x, grid.origin_y) == (-4.0, 1.0)
    assert (grid.width, grid.height) == (12, 8)  # x from -4 to 2, y from 1 to 5


def test_a_grid_too_large_to_fit_is_refused_naming_the_flags():
    far = make_scan([1.0], x=0.0, y=0.0), make_scan([1.0], x=1e5, y=1e5)
    with pytest.raises(RecordingError) as error:
        fit_grid(far, resolution=0.05)
    assert f"more than {MAX_FITTED_CELLS:,}" in str(error.value)
    assert "--width, --height and --origin" in str(error.value)
    with pytest.raises(RecordingError, match="no scans to size the grid from"):
        fit_grid([], resolution=0.05)


def test_map_build_without_a_grid_sizes_it_from_the_data(tmp_path, capsys):
    path = tmp_path / "s.jsonl"
    write_scan_file(path, [make_scan([5.0], x=-12.0, y=-25.0, stamp=float(i)) for i in range(3)])
    out = tmp_path / "map"
    assert main(["map", "build", str(path), "--resolution", "0.5", "--out", str(out)]) == 0
    meta = yaml.safe_load((out / "map.yaml").read_text())
    assert meta["origin"][:2] == [-14.0, -27.0]  # 2 m margin, whole cells
    assert meta["resolution"] == 0.5
    captured = capsys.readouterr()
    assert "fused 3/3 scans (100 %)" in captured.err  # the last progress line, always
    assert "origin -14,-27" in captured.out


def test_map_build_with_half_a_grid_names_the_missing_flag(tmp_path, capsys):
    path = tmp_path / "s.jsonl"
    write_scan_file(path, [make_scan([5.0])])
    assert main(["map", "build", str(path), "--width", "10"]) == 2
    assert "--height is missing: give both --width and --height, or neither" in (
        capsys.readouterr().err
    )


def test_scans_keep_their_fields_through_a_relabel(tmp_path):
    path = tmp_path / "s.jsonl"
    scan = make_scan([5.0, float("inf")], stamp=7.0)
    write_scan_file(path, [scan])
    (read,) = open_recording(path, RecordingOptions(unit_id="other"))
    assert isinstance(read, Scan)
    assert json.dumps({**scan.to_dict(), "unit_id": "other"}, sort_keys=True) == json.dumps(
        read.to_dict(), sort_keys=True
    )
