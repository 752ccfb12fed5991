"""``fleetmap map build``: files written, figures printed, bad input refused whole."""

import argparse
import dataclasses
import json
import math
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml
from conftest import make_scan

import mapserver.store.offline as offline
from mapserver.cli.args import add_dataclass_args, field_docs
from mapserver.cli.map_build import sensor_model_from_args
from mapserver.core import fusion_kernel
from mapserver.core.belief import BeliefGrid, load_fusion_kernels
from mapserver.core.geometry import GridGeometry
from mapserver.core.sensor_model import DecayParams, SensorModel
from mapserver.store.scanfile import write_scan_file
from scenarios.cli.main import build_parser, main

ARGS = ["--width", "12", "--height", "3", "--resolution", "1.0", "--origin", "0,0"]


@pytest.fixture
def scan_file(tmp_path):
    path = tmp_path / "scans.jsonl"
    # From cell (0, 1) along +x: cells 0..4 free, cell 5 occupied (hit 3 times), rest unknown.
    write_scan_file(path, [make_scan([5.0], y=1.5, stamp=float(i)) for i in range(3)])
    return path


def read_pgm(path):
    data = path.read_bytes()
    header = data.split(b"\n", 3)
    width, height = (int(v) for v in header[1].split())
    return np.frombuffer(header[3], dtype=np.uint8).reshape(height, width)


def test_map_build_writes_ros_map_files_and_prints_figures(scan_file, tmp_path, capsys):
    out = tmp_path / "map"
    assert main(["map", "build", str(scan_file), *ARGS, "--out", str(out), "--json"]) == 0
    figures = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert figures["scans"] == 3 and figures["cells_updated"] == 18
    assert figures["fusion_s"] > 0
    meta = yaml.safe_load((out / "map.yaml").read_text())
    assert meta["image"] == "map.pgm" and meta["resolution"] == 1.0 and meta["mode"] == "trinary"
    pgm = read_pgm(out / "map.pgm")
    middle = pgm[1]  # image rows run top-down: the map's row 1 is the middle one either way
    assert middle[:5].tolist() == [254] * 5  # three passes: free
    assert middle[5] == 0  # occupied
    assert middle[6:].tolist() == [205] * 6  # never observed: unknown
    assert np.all(pgm[[0, 2]] == 205)
    logodds = np.load(out / "logodds.npy")
    assert logodds.dtype == np.float32 and logodds.shape == (3, 12)
    assert logodds[1, 5] > 2.0 and logodds[1, 0] < -1.0 and logodds[0, 0] == 0.0


def test_the_kernel_load_is_timed_apart_from_the_fusion(scan_file, tmp_path, capsys, monkeypatch):
    real = offline.load_fusion_kernels

    def slow_load(policies):  # a cold numba cache: seconds before the first scan fuses
        time.sleep(0.3)
        return real(policies) + 0.3

    monkeypatch.setattr(offline, "load_fusion_kernels", slow_load)
    out = tmp_path / "map"
    assert main(["map", "build", str(scan_file), *ARGS, "--out", str(out), "--json"]) == 0
    figures = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert figures["kernel_load_s"] >= 0.3
    assert 0 < figures["fusion_s"] < 0.3  # three one-beam scans, the load excluded
    assert figures["scans_per_s"] == pytest.approx(3 / figures["fusion_s"])


def test_loaded_kernels_serve_every_grid_without_compiling_again():
    load_fusion_kernels()
    signatures = len(fusion_kernel.fuse_batch.signatures)
    # Integers where floats are usual: still the one signature.
    grid = BeliefGrid(GridGeometry(4, 3, 1, origin_x=0, origin_y=-1), SensorModel(clamp_min=-4))
    grid.fuse(make_scan([2.0], y=0.5))
    assert len(fusion_kernel.fuse_batch.signatures) == signatures
    assert load_fusion_kernels() < 0.25  # loaded already: nothing to do but one tiny scan


def test_the_policy_flag_selects_the_policy(scan_file, tmp_path):
    out = tmp_path / "map"
    assert (
        main(["map", "build", str(scan_file), *ARGS, "--out", str(out), "--policy", "binary"]) == 0
    )
    assert np.load(out / "logodds.npy")[1, 5] == 5.0


def test_a_bad_line_names_its_number_and_field_and_writes_nothing(scan_file, tmp_path, capsys):
    lines = scan_file.read_text().splitlines()
    bad = json.loads(lines[1])
    bad["pose"]["x"] = math.nan
    lines[1] = json.dumps(bad)
    scan_file.write_text("\n".join(lines) + "\n")
    out = tmp_path / "map"
    assert main(["map", "build", str(scan_file), *ARGS, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{scan_file}:2: pose.x" in err and "nan" in err
    assert not out.exists()


def test_bad_sensor_model_flags_are_refused_before_any_work(scan_file, tmp_path, capsys):
    out = tmp_path / "map"
    assert main(["map", "build", str(scan_file), *ARGS, "--out", str(out), "--p-hit", "0.4"]) == 2
    assert "p_hit must be greater than the prior" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--p-miss-no-return", "0.6"], "p_miss_no_return must be between p_miss"),
        (["--no-return-range", "-1"], "no_return_range must be a positive range"),
    ],
)
def test_bad_no_return_flags_name_their_field(scan_file, tmp_path, capsys, flags, message):
    out = tmp_path / "map"
    assert main(["map", "build", str(scan_file), *ARGS, "--out", str(out), *flags]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_no_return_flags_set_the_no_return_evidence(tmp_path):
    path = tmp_path / "scans.jsonl"
    write_scan_file(path, [make_scan([math.inf], y=1.5, range_max=10.0)])  # from x = 0.5
    out = tmp_path / "map"
    flags = ["--p-miss-no-return", "0.42", "--no-return-range", "4"]
    assert main(["map", "build", str(path), *ARGS, "--out", str(out), *flags]) == 0
    row = np.load(out / "logodds.npy")[1]
    assert row[:5] == pytest.approx([math.log(0.42 / 0.58)] * 5)  # cells 0..4, to x = 4.5
    assert np.all(row[5:] == 0.0)
    uncapped = ["--no-return-range", "none"]
    assert main(["map", "build", str(path), *ARGS, "--out", str(out), *uncapped]) == 0
    assert np.count_nonzero(np.load(out / "logodds.npy")[1]) == 11  # to range_max: x = 10.5


def test_the_fill_flag_turns_the_fill_between_beams_off(tmp_path):
    # Two returns at 10 m, 0.2 rad apart, from (0.5, 1.5): 2 m apart there, so a fill ray
    # along row 1 from 1 m / 0.2 rad = 5 m out to a cell short of their face.
    path = tmp_path / "scans.jsonl"
    write_scan_file(path, [make_scan([10.0, 10.0], y=1.5, angle_min=-0.1, angle_increment=0.2)])
    out = tmp_path / "map"
    assert main(["map", "build", str(path), *ARGS, "--out", str(out)]) == 0
    filled = np.load(out / "logodds.npy")[1]
    assert filled[6:10] == pytest.approx([math.log(0.4 / 0.6)] * 4)  # x 6..9.45: the fill's
    assert filled[10] == 0.0  # the face's cell
    assert (
        main(["map", "build", str(path), *ARGS, "--out", str(out), "--no-fill-between-beams"]) == 0
    )
    assert np.all(np.load(out / "logodds.npy")[1][6:] == 0.0)


def test_a_missing_scan_file_is_a_clear_error(tmp_path, capsys):
    assert main(["map", "build", str(tmp_path / "nope.jsonl"), *ARGS]) == 2
    assert "nope.jsonl: no such file or folder" in capsys.readouterr().err


def test_the_console_command_runs_map_build(scan_file, tmp_path):
    out = tmp_path / "map"
    proc = subprocess.run(
        [sys.executable, "-m", "scenarios.cli.main", "map", "build", str(scan_file), *ARGS,
         "--out", str(out), "--json"],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    assert json.loads(proc.stdout.splitlines()[-1])["scans"] == 3
    assert sorted(p.name for p in out.iterdir()) == ["logodds.npy", "map.pgm", "map.yaml"]


def map_build_parser():
    """The ``map build`` subparser of the ``fleetmap`` command."""
    for action in build_parser()._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices["map"]._actions:
                if isinstance(sub, argparse._SubParsersAction):
                    return sub.choices["build"]
    raise AssertionError("no map build")


def flag(name):
    return "--" + name.replace("_", "-")


@pytest.mark.parametrize("domain", [SensorModel, DecayParams])
def test_every_model_field_has_a_map_build_flag_with_its_default(domain):
    actions = {a.dest: a for a in map_build_parser()._actions}
    for field in dataclasses.fields(domain):
        action = actions.get(field.name)
        assert action is not None, f"{domain.__name__}.{field.name} has no map build flag"
        assert flag(field.name) in action.option_strings
        assert action.default == field.default
        assert action.help  # from the field's docstring entry


def test_map_build_help_shows_each_flags_default():
    text = map_build_parser().format_help()
    blocks = {}  # each option's first line's flag -> its whole entry, joined
    for line in text.splitlines():
        if line.startswith("  -"):
            name = line.split()[0].rstrip(",")
            blocks[name] = []
        if blocks:
            blocks[name].append(line.strip())
    for field in [*dataclasses.fields(SensorModel), *dataclasses.fields(DecayParams)]:
        entry = " ".join(blocks[flag(field.name)])
        assert entry.endswith(f"(default: {field.default})"), entry
    assert " ".join(blocks["--confirm-hits"]).startswith("--confirm-hits CONFIRM_HITS under dual")
    assert "--no-return-range NO_RETURN_RANGE|none" in text
    assert "--fill-between-beams, --no-fill-between-beams" in text


@pytest.mark.parametrize(
    "flags, field, value",
    [
        (["--confirm-hits", "5"], "confirm_hits", 5),
        (["--confirm-after", "0.5"], "confirm_after", 0.5),
        (["--void-threshold", "0.1"], "void_threshold", 0.1),
        (["--prior", "0.45"], "prior", 0.45),
        (["--clamp-min", "-4"], "clamp_min", -4.0),
        (["--no-return-range", "None"], "no_return_range", None),
        (["--no-guard-glancing-faces"], "guard_glancing_faces", False),
        (["--fade-bound", "0.1"], "fade_bound", 0.1),
        (["--half-life-free", "60"], "half_life_free", 60.0),
    ],
)
def test_a_flag_value_reaches_the_model(flags, field, value):
    args = build_parser().parse_args(["map", "build", "scans.jsonl", *flags])
    model, decay = sensor_model_from_args(args)
    got = getattr(decay if field in DecayParams.__dataclass_fields__ else model, field)
    assert got == value and type(got) is type(value)
    defaults = sensor_model_from_args(build_parser().parse_args(["map", "build", "s.jsonl"]))
    assert defaults == (SensorModel(), DecayParams())


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--confirm-hits", "2.5"], "argument --confirm-hits: invalid int value: '2.5'"),
        (["--p-hit", "high"], "argument --p-hit: invalid float value: 'high'"),
        (["--no-return-range", "far"], "argument --no-return-range: expected metres or 'none'"),
        (["--fill-between-beams", "yes"], "unrecognized arguments: yes"),
    ],
)
def test_a_bad_flag_value_is_a_usage_error_naming_the_flag(scan_file, flags, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["map", "build", str(scan_file), *ARGS, *flags])
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err


def test_a_flag_the_model_refuses_names_its_field(scan_file, tmp_path, capsys):
    out = tmp_path / "map"
    bad_hits = ["--confirm-hits", "0"]
    assert main(["map", "build", str(scan_file), *ARGS, "--out", str(out), *bad_hits]) == 2
    assert "confirm_hits must be a whole number of scans, 1 to 252" in capsys.readouterr().err
    bad_bound = ["--fade-bound", "1"]
    assert main(["map", "build", str(scan_file), *ARGS, "--out", str(out), *bad_bound]) == 2
    assert "decay.fade_bound must be below the thresholds' distance" in capsys.readouterr().err
    assert not out.exists()


def test_a_field_without_a_docstring_entry_gets_no_flag_but_an_error():
    @dataclasses.dataclass(frozen=True)
    class Rule:
        """A rule.

        low, high: [m] the ``band``, *inclusive*.
        count: scans, continued
            on a second line.
        """

        low: float = 0.0
        high: float = 1.0
        count: int = 3
        strict: bool = False

    assert field_docs(Rule) == {
        "low": "[m] the band, inclusive.",
        "high": "[m] the band, inclusive.",
        "count": "scans, continued on a second line.",
    }
    with pytest.raises(TypeError, match="Rule.strict: a flag needs a docstring entry"):
        add_dataclass_args(argparse.ArgumentParser(), Rule)
