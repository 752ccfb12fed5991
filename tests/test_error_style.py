"""Every command's errors in one style: ``fleetmap CMD: error: WHAT (FIX)`` on one line of
stderr, exit status 2, for usage and input errors alike: a busy port (naming ``--port``),
a missing file or folder, a grid that differs from the scenario's (both grids in words
and the settings to change), a bad environment variable (its name). No traceback, no
Python repr, no blank line, no prefix twice.

Each command runs in this process (``scenarios.cli.main.main``) but for ``run --server``,
which needs a real server with another grid (``ServerProcess``: 300 x 200 cells of 0.1 m).
"""

from __future__ import annotations

import re
import socket
from pathlib import Path

import pytest
from server_helpers import ServerProcess

from scenarios.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "scenarios" / "tiny.yaml"
STYLE = re.compile(r"fleetmap (?P<command>[a-z0-9 ]+): error: (?P<what>\S.*?)(?P<fix> \(.+\)|\?)")
"""One error line: the command, what is wrong, then the fix in parentheses or a question
(``did you mean 'count'?``)."""
REPR = re.compile(r"\b[A-Z][A-Za-z]+\([a-z_]+=")  # GridGeometry(width=...


def check_style(command: str, status: int, err: str) -> str:
    """The one error line of ``err`` after it is checked; ``status`` must be 2."""
    assert status == 2, err
    lines = err.splitlines()
    assert len(lines) == 1, lines  # one line: no blank line first, no second message
    found = STYLE.fullmatch(lines[0])
    assert found, lines[0]
    assert found.group("command") == command
    assert lines[0].count("fleetmap ") == 1 and lines[0].count("error:") == 1
    assert "Traceback" not in err and not REPR.search(err), err
    return lines[0]


@pytest.fixture
def files(tmp_path):
    """A scenario with a typo, a folder with nothing in it, and the names of missing ones."""
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: bad\nunits:\n  cont: 3\n")
    (tmp_path / "empty").mkdir()
    return tmp_path


CASES = [  # (id, argv with {tmp}, the command in the message, a part of the message)
    ("run-missing", ["run", "{tmp}/nosuch.yaml"], "run", "nosuch.yaml: scenario: cannot read"),
    ("run-typo", ["run", "{tmp}/bad.yaml"], "run", "units.cont: is not a field of units"),
    ("compare-typo", ["compare", "{tmp}/bad.yaml"], "compare", "bad.yaml:3: units.cont"),
    ("compare-missing", ["compare", "{tmp}/nosuch.yaml"], "compare", "no such scenario file"),
    ("compare-policy", ["compare", str(TINY), "--policies", "fast"], "compare", "'fast' is not"),
    ("sweep-missing", ["sweep", "{tmp}/nosuch.yaml"], "sweep", "sweep: cannot read the file"),
    ("sweep-typo", ["sweep", "{tmp}/bad.yaml"], "sweep", "name: is not a field of sweep"),
    ("replay-missing", ["replay", "{tmp}/nosuch"], "replay", "nosuch: no such file or folder"),
    ("replay-empty", ["replay", "{tmp}/empty"], "replay", "holds neither a server's journal"),
    ("map-build-missing", ["map", "build", "{tmp}/no.jsonl"], "map build", "no such file"),
    (
        "plan-missing",
        ["plan", "{tmp}/m.yaml", "--start", "0,0", "--goal", "1,1"],
        "plan",
        "map YAML",
    ),
    ("journal-missing", ["journal", "check", "{tmp}/nosuch"], "journal check", "no journal there"),
    ("export-missing", ["export", "ros2", "{tmp}/nosuch"], "export", "is not a run folder"),
    (
        "import-missing",
        ["import", "{tmp}/no.jsonl", "--server", "http://127.0.0.1:9"],
        "import",
        "no.jsonl: no such file",
    ),  # fmt: skip
    ("evaluate-missing", ["evaluate", "{tmp}/no.jsonl", "--out", "{tmp}/o"], "evaluate", "no such"),
    ("serve-config", ["serve", "--config", "{tmp}/nosuch.yaml"], "serve", "cannot read the file"),
    (
        "zones-count",
        ["zones", "--width", "10", "--height", "10", "--zones", "0"],
        "zones",
        "--zones: must be a whole number in [1, 64], got 0",
    ),
    (
        "run-zones-server",
        ["run", str(TINY), "--zones", "2", "--server", "http://127.0.0.1:9"],
        "run",
        "--zones: a run against --server uses that one server",
    ),
]


SIM_COMMANDS = {"run", "compare", "sweep"}
"""Commands that load the simulator before reading their input: without PyBullet their
one error line is the simulator's (tests/conftest.py skips ``sim`` tests there)."""


@pytest.mark.parametrize(
    ("argv", "command", "part"),
    [
        pytest.param(*c[1:], id=c[0], marks=[pytest.mark.sim] if c[2] in SIM_COMMANDS else [])
        for c in CASES
    ],
)
def test_each_commands_input_errors_are_one_line_in_the_style(files, capsys, argv, command, part):
    status = main([a.format(tmp=files) for a in argv])
    line = check_style(command, status, capsys.readouterr().err)
    assert part in line


def test_a_usage_error_ends_in_the_same_style(capsys):
    with pytest.raises(SystemExit) as done:
        main(["run", str(TINY), "--seed", "many"])
    err = capsys.readouterr().err
    assert done.value.code == 2
    last = err.splitlines()[-1]  # argparse's usage lines come first
    assert last == "fleetmap run: error: argument --seed: invalid int value: 'many'"


def test_a_busy_port_names_port_and_the_fix(tmp_path, capsys):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        status = main(["serve", "--port", str(port), "--data-dir", str(tmp_path / "d")])
    line = check_style("serve", status, capsys.readouterr().err)
    assert line == (
        f"fleetmap serve: error: --port {port}: cannot listen on 127.0.0.1:{port}: another "
        "program listens there (stop it, or choose another --port; --port 0 picks a free one)"
    )
    assert not (tmp_path / "d").exists()  # nothing was opened


@pytest.mark.parametrize(
    ("variable", "value", "expected"),
    [
        ("FLEETMAP_PORT", "abc", "port: Input should be a valid integer, unable to parse "
         "string as an integer, got 'abc' (set by the environment variable FLEETMAP_PORT: "
         "correct or unset it)"),
        ("fleetmap_sensor_model__p_hit", "1.5", "sensor_model.p_hit: must be a probability "
         "strictly between 0 and 1, got 1.5 (set by the environment variable "
         "fleetmap_sensor_model__p_hit: correct or unset it)"),
        ("FLEETMAP_TOKENS", '[{"tok', "FLEETMAP_TOKENS: not valid JSON"),
    ],
)  # fmt: skip
def test_an_environment_variable_in_error_is_named(
    tmp_path, capsys, monkeypatch, variable, value, expected
):
    monkeypatch.setenv(variable, value)
    status = main(["serve", "--data-dir", str(tmp_path / "d")])
    line = check_style("serve", status, capsys.readouterr().err)
    assert line.startswith(f"fleetmap serve: error: {expected}")


def test_a_flag_beats_a_bad_variable_and_is_not_blamed_on_it(tmp_path, monkeypatch):
    from mapserver.service.settings import load_settings

    monkeypatch.setenv("FLEETMAP_PORT", "abc")
    assert load_settings(None, {"port": 8123, "data_dir": tmp_path}).port == 8123


@pytest.mark.sim
def test_run_against_a_server_with_another_grid_says_both_grids_and_the_settings(tmp_path, capsys):
    server = ServerProcess(tmp_path / "data")  # 300 x 200 cells of 0.1 m
    try:
        status = main(["run", str(TINY), "--server", server.url, "--out", str(tmp_path / "o")])
    finally:
        server.stop()
    line = check_style("run", status, capsys.readouterr().err)
    assert line == (
        "fleetmap run: error: --server: its grid is 300 x 200 cells of 0.1 m (30 x 20 m) from "
        "(0, 0), the scenario's 120 x 80 cells of 0.1 m (12 x 8 m) from (0, 0) (start the "
        "server with grid.width: 120, grid.height: 80 in its --config, or "
        "FLEETMAP_GRID__WIDTH=120 FLEETMAP_GRID__HEIGHT=80, and no --map; or run without "
        "--server)"
    )
    assert not (tmp_path / "o" / "metrics.json").exists()


def test_an_address_not_of_this_machine_names_host():
    from mapserver.cli.listen import ListenError, listen

    with pytest.raises(ListenError) as refused:
        listen("192.0.2.1", 8700)  # TEST-NET-1 (RFC 5737): never a local address
    assert str(refused.value) == (
        "--host 192.0.2.1: cannot listen on 192.0.2.1:8700: not an address of this machine "
        "(choose another --host)"
    )
