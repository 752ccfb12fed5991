"""``fleetmap evaluate``: the measures on tiny recordings whose numbers follow from the
sensor model by hand, the files written, the errors, and determinism.

Every recording here is a fixed laser at (0.5, 1.5) looking along +x on a 12 x 3 grid of
1 m cells: a beam of range r ends in column floor(0.5 + r) of row 1 and crosses the
columns before it. Reads are at the scans' own stamps (one scan a second, a read a
second), so no read fades a map between scans.
"""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from conftest import make_scan

from mapserver.core.belief import CellState
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Scan
from mapserver.core.sensor_model import DecayParams, Policy, SensorModel, logit
from mapserver.store.recordings import open_recording
from mapserver.store.scanfile import write_scan_file
from scenarios.cli import evaluate as evaluate_cli
from scenarios.cli.main import main
from scenarios.evaluate.maps import FleetmapMap
from scenarios.evaluate.octomap_peer import octomap_installed
from scenarios.evaluate.run import evaluate

GRID = GridGeometry(12, 3, 1.0)
GRID_ARGS = ["--width", "12", "--height", "3", "--resolution", "1.0", "--origin", "0,0"]
WALL = 8.0  # [m] the wall's return: column 8
PERSON = 3.0  # [m] a person's return: column 3
MODEL = SensorModel()
DECAY = DecayParams()


def laser(ranges: list[float], stamp: float) -> Scan:
    return make_scan(ranges, x=0.5, y=1.5, stamp=stamp)


def recording(tmp_path, ranges_per_scan: list[list[float]]):
    """A JSONL recording of the fixed laser, one scan a second from stamp 0."""
    path = tmp_path / "scans.jsonl"
    write_scan_file(path, [laser(r, float(t)) for t, r in enumerate(ranges_per_scan)])
    return open_recording(path)


def run(rec, policies=tuple(Policy), **kwargs):
    maps = [FleetmapMap(GRID, MODEL, p, DECAY) for p in policies]
    return evaluate(rec, GRID, maps, **kwargs)


def verdicts(evaluation):
    return {v.name: v for v in evaluation.verdicts}


class AllOccupied:
    """A map that holds every cell occupied: it counts every ghost candidate."""

    name = "all-occupied"

    def fuse(self, scan: Scan) -> None:
        pass

    def states_of(self, cells: np.ndarray, stamp: float) -> np.ndarray:
        return np.full(len(cells), CellState.OCCUPIED, dtype=np.uint8)

    def final_states(self, stamp: float) -> np.ndarray:
        return np.full(GRID.shape, CellState.OCCUPIED, dtype=np.uint8)


def test_a_wall_seen_by_a_fixed_laser_is_kept_whole(tmp_path):
    result = verdicts(run(recording(tmp_path, [[WALL]] * 5)))
    for policy in Policy:
        assert result[policy].structure_kept == 1.0  # column 8, occupied, holds all 5
        assert result[policy].occupied_cells == 1
        assert result[policy].ghost_cell_seconds == 0.0  # nothing was ever in the way
        assert result[policy].unknown_share == 0.0  # 5 passes (-2.03) clear columns 0..7


def test_one_pass_leaves_the_floor_unknown_but_binary_clears_it(tmp_path):
    # The floor: columns 0..8. One pass (-0.405) is above the free threshold (-1.099).
    result = verdicts(run(recording(tmp_path, [[WALL]])))
    assert result["decay"].unknown_share == result["sticky"].unknown_share == 8 / 9
    assert result["binary"].unknown_share == 0.0  # a pass clears a cell at once


def person_then_gone(tmp_path, present: int, gone: int):
    """A person at column 3 for ``present`` scans, then the wall for ``gone`` scans."""
    return recording(tmp_path, [[PERSON]] * present + [[WALL]] * gone)


def occupied_reads(policy: Policy, present: int, gone: int) -> int:
    """The reads at which column 3 is still occupied once the person has gone, from the
    sensor model by hand (a hit each person scan, a pass each wall scan, one a second)."""
    l_hit, l_miss = logit(MODEL.p_hit), logit(MODEL.p_miss)
    value, count = 0.0, 0
    for t in range(present + gone):
        if policy is Policy.DECAY and t > 0:  # a second since the last update
            half_life = DECAY.half_life_occupied if value > 0 else DECAY.half_life_free
            value *= 2.0 ** (-1.0 / half_life)
        evidence = l_hit if t < present else l_miss
        if policy is Policy.BINARY:
            value = MODEL.clamp_max if t < present else MODEL.clamp_min
        elif policy is Policy.DECAY:
            value = min(max(value + evidence, MODEL.clamp_min), MODEL.clamp_max)
        else:
            value += evidence
        count += t >= present and value > logit(MODEL.occupied_threshold)
    return count


def test_a_person_gone_leaves_ghost_seconds_as_the_sensor_model_says(tmp_path):
    evaluation = run(person_then_gone(tmp_path, present=10, gone=30))
    result = verdicts(evaluation)
    # Sticky: 10 hits (+8.47) take 19 passes (-0.405 each) to fall below +0.619.
    assert occupied_reads(Policy.STICKY, 10, 30) == 19
    # Decay: clamped at +5 and fading a little each second, 9 passes suffice.
    assert occupied_reads(Policy.DECAY, 10, 30) == 9
    # Dual: 10 hits in a row make the cell structure (confirm_hits), clamped at +5 with no
    # fade; the passes end well beyond it (release_margin), so the first leaves it seen
    # through once (5 - 0.405, still occupied: one ghost read) and the second releases it.
    expected = {"sticky": 19.0, "decay": 9.0, "binary": 0.0, "dual": 1.0}  # 1 cell, 1 s/read
    assert {name: v.ghost_cell_seconds for name, v in result.items()} == expected
    assert evaluation.ghosts["sticky"].counts == [0] * 10 + [1] * 19 + [0] * 11
    assert evaluation.ghosts["sticky"].stamps == [float(t) for t in range(40)]
    for policy in Policy:  # the wall holds 30 of the 40 returns; column 3 is cleared
        assert result[policy].structure_kept == 0.75
        assert result[policy].unknown_share == 0.0


def test_ghosts_scale_with_the_read_interval(tmp_path):
    rec = person_then_gone(tmp_path, present=10, gone=30)
    halves = run(rec, policies=[Policy.STICKY], read_every=0.5)
    # Reads at 0, 0.5, ..., 39: each scan is current for two reads (the last for one).
    assert len(halves.ghosts["sticky"].stamps) == 79
    assert halves.verdicts[0].ghost_cell_seconds == 19 * 2 * 0.5


def test_only_cells_a_return_hit_before_count_and_the_margin_spares_the_wall(tmp_path):
    # A person at column 6, two cells short of the wall at column 8, then the wall.
    rec = recording(tmp_path, [[6.0]] * 2 + [[WALL]] * 3)
    spared = evaluate(rec, GRID, [AllOccupied()], margin=2)
    # Seen through: columns 0..5 (more than 2 cells short of column 8), never hit.
    assert spared.verdicts[0].ghost_cell_seconds == 0.0
    counted = evaluate(rec, GRID, [AllOccupied()], margin=1)
    # Column 6 is seen through with a 1-cell margin: a ghost at the three wall reads.
    assert counted.ghosts["all-occupied"].counts == [0, 0, 1, 1, 1]
    assert counted.verdicts[0].structure_kept == 1.0
    assert counted.verdicts[0].occupied_cells == GRID.size


def test_a_cell_the_same_scan_hits_is_not_seen_through(tmp_path):
    # Beam 0 passes column 3 on its way to the wall; beam 1 (0.01 rad on) hits it.
    path = tmp_path / "scans.jsonl"
    write_scan_file(path, [laser([WALL, PERSON], float(t)) for t in range(3)])
    evaluation = evaluate(open_recording(path), GRID, [AllOccupied()])
    assert evaluation.ghosts["all-occupied"].counts == [0, 0, 0]
    assert evaluation.returns == 6


def test_unknown_share_counts_only_the_floor_the_returns_saw(tmp_path):
    # A wall beam along row 1, then a no-return beam along row 0. One pass leaves columns
    # 0..7 of row 1 unknown; decay clears the no-return beam's first metre (columns 0, 1
    # of row 0) weakly, unknown too, but that beam proves no floor: 8 of 9 cells, not 10
    # of 11.
    path = tmp_path / "scans.jsonl"
    write_scan_file(path, [make_scan([WALL], x=0.5, y=1.5), make_scan([math.inf], x=0.5, y=0.5)])
    evaluation = run(open_recording(path), policies=[Policy.DECAY])
    assert evaluation.verdicts[0].unknown_share == 8 / 9
    assert evaluation.returns == 1 and evaluation.verdicts[0].structure_kept == 1.0


def test_the_same_recording_gives_the_same_numbers(tmp_path):
    rec = person_then_gone(tmp_path, present=4, gone=6)
    first, second = run(rec), run(rec)  # the recording is read again from the start
    strip = [{**v.as_row(), "scans_per_s": None} for v in first.verdicts]
    assert strip == [{**v.as_row(), "scans_per_s": None} for v in second.verdicts]
    for name in first.finals:
        assert np.array_equal(first.finals[name], second.finals[name])


# ------------------------------------------------------------------------------ the CLI
def people_file(tmp_path):
    path = tmp_path / "people.jsonl"
    write_scan_file(path, [laser([PERSON if t < 10 else WALL], float(t)) for t in range(40)])
    return path


def test_the_command_writes_the_table_and_the_picture(tmp_path, capsys):
    out = tmp_path / "verdict"
    argv = ["evaluate", str(people_file(tmp_path)), *GRID_ARGS, "--out", str(out)]
    assert main([*argv, "--peer", "none"]) == 0
    printed = capsys.readouterr().out
    assert "| sticky | 0.750 | 19 | 0.000 | 1 |" in printed
    assert f"outputs: {out / 'report.md'}, {out / 'report.csv'}, {out / 'evaluate.png'}" in printed
    rows = list(csv.DictReader((out / "report.csv").open()))
    assert [r["map"] for r in rows] == ["decay", "binary", "sticky", "dual"]
    assert [float(r["ghost_cell_seconds"]) for r in rows] == [9.0, 0.0, 19.0, 1.0]
    assert float(rows[0]["scans_per_s"]) > 0
    assert "| decay | 0.750 | 9 | 0.000 | 1 |" in (out / "report.md").read_text()
    assert (out / "evaluate.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in out.iterdir()) == ["evaluate.png", "report.csv", "report.md"]


def test_the_command_runs_the_policies_asked_for_in_order(tmp_path):
    out = tmp_path / "verdict"
    argv = ["evaluate", str(people_file(tmp_path)), *GRID_ARGS, "--out", str(out)]
    assert main([*argv, "--policies", "sticky,decay,sticky", "--peer", "none"]) == 0
    rows = list(csv.DictReader((out / "report.csv").open()))
    assert [r["map"] for r in rows] == ["sticky", "decay"]


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (
            ["--policies", "decay,fast"],
            "argument --policies: policy must be one of decay, binary, sticky, dual, got 'fast'",
        ),
        (["--peer", "gmapping"], "argument --peer: invalid choice: 'gmapping'"),
        (["--read-every", "0"], "argument --read-every: must be a number > 0, got 0"),
        (["--ghost-margin", "-1"], "argument --ghost-margin: must be a whole number of cells"),
    ],
)
def test_bad_flags_are_refused_before_anything_is_read(tmp_path, capsys, flags, message):
    out = tmp_path / "verdict"
    with pytest.raises(SystemExit) as exit_:
        main(["evaluate", str(people_file(tmp_path)), "--out", str(out), *flags])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "fleetmap evaluate: error: " + message in err
    assert not out.exists()


def test_a_bad_recording_writes_nothing(tmp_path, capsys):
    path = people_file(tmp_path)
    path.write_text(path.read_text() + '{"unit_id": "u1"}\n')  # a bad last line
    out = tmp_path / "verdict"
    assert main(["evaluate", str(path), *GRID_ARGS, "--out", str(out), "--peer", "none"]) == 2
    err = capsys.readouterr().err
    assert f"fleetmap evaluate: error: {path}:41: stamp" in err
    assert not out.exists()
    missing = tmp_path / "nothing.jsonl"
    assert main(["evaluate", str(missing), "--out", str(out), "--peer", "none"]) == 2
    assert f"fleetmap evaluate: error: {missing}: no such file or folder" in capsys.readouterr().err
    assert not out.exists()


def test_a_failed_write_leaves_the_last_verdict_whole(tmp_path, capsys, monkeypatch):
    out = tmp_path / "verdict"
    argv = ["evaluate", str(people_file(tmp_path)), *GRID_ARGS, "--out", str(out), "--peer", "none"]
    assert main(argv) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def full_disk(evaluation, path):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(evaluate_cli, "write_picture", full_disk)
    assert main([*argv, "--policies", "sticky"]) == 2
    assert "fleetmap evaluate: error: --out " in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # no staging left


def test_octomap_asked_for_but_not_installed_names_the_extra(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(__import__("sys").modules, "pyoctomap", None)  # import fails
    out = tmp_path / "verdict"
    argv = ["evaluate", str(people_file(tmp_path)), *GRID_ARGS, "--out", str(out)]
    assert main([*argv, "--peer", "octomap"]) == 2
    assert capsys.readouterr().err == (
        "fleetmap evaluate: error: --peer octomap needs pyoctomap, which is not installed: "
        "pip install 'fleetmap[bench]'\n"
    )
    assert not out.exists()
    assert main(argv) == 0  # by default: a note, and the policies alone
    captured = capsys.readouterr()
    assert "fleetmap evaluate: note: no OctoMap peer, pyoctomap is not installed" in captured.err
    rows = list(csv.DictReader((out / "report.csv").open()))
    assert [r["map"] for r in rows] == ["decay", "binary", "sticky", "dual"]


@pytest.mark.skipif(not octomap_installed(), reason="pyoctomap (the bench extra) not installed")
def test_octomap_peer_matches_clamped_log_odds_on_an_axis_beam(tmp_path, capsys):
    out = tmp_path / "verdict"
    argv = ["evaluate", str(people_file(tmp_path)), *GRID_ARGS, "--out", str(out)]
    assert main(argv) == 0  # the peer runs by default when installed
    rows = {r["map"]: r for r in csv.DictReader((out / "report.csv").open())}
    # 10 hits clamp at +5 (no fading): (5 - 0.619) / 0.405 -> 10 passes keep it occupied.
    assert float(rows["octomap"]["ghost_cell_seconds"]) == 10.0
    assert float(rows["octomap"]["structure_kept"]) == 0.75
    assert float(rows["octomap"]["unknown_share"]) == 0.0
    assert int(rows["octomap"]["occupied_cells"]) == 1
