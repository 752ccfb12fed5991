"""The README's external planner (``docs/examples/external_planner.py``), run as a user
would: a separate process against a real map server on loopback; and the README shows
its code as it is."""

import importlib.util
import inspect
import json
import shutil
import subprocess
import sys
from pathlib import Path

import httpx
import pytest
from server_helpers import ServerProcess, scan_body

from mapserver.client import MapClient
from scenarios.run.embedded_server import EmbeddedServer, free_port

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "docs" / "examples" / "external_planner.py"


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    process = ServerProcess(tmp_path_factory.mktemp("planner") / "data")
    with httpx.Client(base_url=process.url) as http:
        for stamp in (1.0, 2.0, 3.0):  # a wall of returns at x = 8 m, seen from (5, 5)
            MapClient(http).post_scan(scan_body(stamp=stamp))
    yield process
    process.stop()


def run(server, start: str, goal: str) -> tuple[int, dict]:
    done = subprocess.run(
        [sys.executable, str(EXAMPLE), server.url, start, goal],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.stderr == "", done.stderr
    return done.returncode, json.loads(done.stdout)


def test_the_external_planner_finds_a_clear_route_through_known_free_cells(server):
    status, reply = run(server, "5.55,5.05", "7.05,5.95")
    assert status == 0 and reply["found"] is True and reply["blocked"] is False
    assert reply["path"][0] == pytest.approx([5.55, 5.05]) and reply["map_version"] == 3
    assert reply["path"][-1] == pytest.approx([7.05, 5.95])
    assert reply["length_m"] == pytest.approx(1.5 + 0.9)  # 4-connected: dx + dy


def test_the_external_planner_reports_no_route_through_the_wall(server):
    status, reply = run(server, "5.55,5.05", "9.05,5.05")
    assert status == 1 and reply == {"found": False, "map_version": 3}


def test_the_readme_shows_the_examples_plan_function_as_it_is():
    spec = importlib.util.spec_from_file_location("external_planner", EXAMPLE)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    assert inspect.getsource(example.plan) in (ROOT / "README.md").read_text()


def run_failing(*args: str) -> list[str]:
    """The example's stderr lines for ``args``, which it must refuse with exit status 2."""
    done = subprocess.run([sys.executable, str(EXAMPLE), *args],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 2 and done.stdout == "", done
    assert "Traceback" not in done.stderr
    return done.stderr.splitlines()


USAGE = "usage: external_planner.py [-h] url START_X,START_Y GOAL_X,GOAL_Y [token]"


@pytest.mark.parametrize(
    ("args", "error"),
    [
        ((), "the following arguments are required: url, START_X,START_Y, GOAL_X,GOAL_Y"),
        (("http://127.0.0.1:8700", "5,5"), "the following arguments are required: GOAL_X,GOAL_Y"),
        (("http://127.0.0.1:8700", "5;5", "7,5"),
         "argument START_X,START_Y: expected X,Y in metres, got '5;5'"),
        (("localhost:8700", "5,5", "7,5"),
         "argument url: expected http://HOST:PORT, got 'localhost:8700'"),
    ],
)  # fmt: skip
def test_the_external_planner_prints_its_usage_for_bad_arguments(args, error):
    assert run_failing(*args) == [USAGE, f"external_planner.py: error: {error}"]


def test_the_external_planner_names_a_point_off_the_map_in_one_line(server):
    (line,) = run_failing(server.url, "5,5", "500,5")
    assert line.startswith("external_planner.py: error: ") and "500" in line


def test_the_external_planner_says_in_one_line_when_no_server_answers():
    (line,) = run_failing(f"http://127.0.0.1:{free_port()}", "5,5", "7,5")
    assert line.startswith("external_planner.py: error: GET /v1/costmap: map server unavailable")


def readme_block(heading: str) -> str:
    """The first ``sh`` code block after ``heading`` in the README."""
    text = (ROOT / "README.md").read_text()
    after = text[text.index(heading) :]
    return after[after.index("```sh\n") + 6 :].split("\n```", 1)[0]


@pytest.mark.skipif(shutil.which("curl") is None, reason="curl is not installed")
def test_the_readmes_curl_lines_map_a_wall_and_read_it_back_occupied(tmp_path):
    """The README's HTTP API lines, as written, on a fresh ``fleetmap serve`` (the
    default grid): each reply is one line here (``curl`` wrapped to end it)."""
    block = readme_block("### The HTTP API")
    server = EmbeddedServer(tmp_path / "data")  # no settings: the default grid
    try:
        script = 'curl() { command curl --fail-with-body "$@"; echo; }\nset -e\n' + block
        script = script.replace("localhost:8700", server.url.removeprefix("http://"))
        done = subprocess.run(["bash", "-c", script], cwd=tmp_path, capture_output=True,
                              text=True, timeout=120)  # fmt: skip
    finally:
        server.stop()
    assert done.returncode == 0, done.stderr
    replies = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    acks, cells, segments, plan, meta, updates = (
        replies[:3],
        replies[3],
        replies[4],
        replies[5],
        replies[6],
        replies[7],
    )
    assert acks == [{"seq": k, "map_version": k} for k in (1, 2, 3)]
    wall, floor = cells["cells"]
    assert (wall["state"], wall["cost"], floor["state"], floor["cost"]) == (
        "occupied",
        254,
        "free",
        0,
    )
    clear, blocked = segments["segments"]
    assert (clear["blocked"], blocked["blocked"]) == (False, True)
    assert blocked["first_blocked"][0] == pytest.approx(13.2, abs=0.6)  # at the wall, inflated
    assert plan["found"] is True
    assert (meta["width"], meta["height"], meta["version"]) == (2000, 1000, 3)
    assert updates["version"] == 3
    assert (tmp_path / "costs.bin").stat().st_size == 2000 * 1000
    assert (tmp_path / "occ.bin").stat().st_size == 2000 * 1000
    assert (tmp_path / "costs.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
