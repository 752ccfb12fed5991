"""Progress lines for long work when the output is a pipe (``scenarios.sweep.progress``):
units with a hand-set clock, then ``fleetmap compare`` and ``fleetmap run`` as
subprocesses whose output is a pipe."""

import io
import re
import subprocess
import sys
from pathlib import Path

import pytest
from scenario_helpers import tiny5

from scenarios.sweep.parallel import RunResult
from scenarios.sweep.progress import RunProgress, SimProgress, TerminalBar, elapsed
from scenarios.sweep.sweep_file import SweepRun

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "scenarios" / "tiny.yaml"
FLEETMAP = [sys.executable, "-m", "scenarios.cli.main"]


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


@pytest.mark.parametrize(
    ("seconds", "text"),
    [(0.4, "0 s"), (59.9, "59 s"), (80, "1 m 20 s"), (3599, "59 m 59 s"), (7500, "2 h 05 m")],
)
def test_elapsed_reads_as_seconds_minutes_or_hours(seconds, text):
    assert elapsed(seconds) == text


def test_a_sweep_prints_each_run_and_a_heartbeat_only_after_a_silence():
    clock, out = Clock(), io.StringIO()
    progress = RunProgress(3, out, every_s=10.0, clock=clock)
    clock.now += 9.5
    progress.tick()
    assert out.getvalue() == ""
    clock.now += 0.5
    progress.tick()
    progress.tick()  # the line just printed restarts the silence
    run = SweepRun(TINY, "tiny", "decay", 0)
    clock.now += 5
    progress(RunResult(run, "ok", Path("x"), wall_seconds=15.04))
    clock.now += 9
    progress.tick()
    clock.now += 70
    progress(RunResult(run, "error", Path("x"), error="RuntimeError: boom", wall_seconds=2))
    clock.now += 10
    progress.tick()
    assert out.getvalue().splitlines() == [
        "... 0/3 runs done, 10 s",
        "[1/3] tiny/decay/seed0 ok (15.0 s)",
        "[2/3] tiny/decay/seed0 FAILED: RuntimeError: boom (2.0 s)",
        "... 2/3 runs done, 1 m 44 s",
    ]


def test_a_run_prints_its_simulated_time_now_and_then_and_at_the_end():
    clock, out = Clock(), io.StringIO()
    progress = SimProgress("tiny", out, every_s=10.0, clock=clock)
    for step in range(1, 201):  # 20 s simulated at 0.1 s, 0.25 s of wall time a step
        clock.now += 0.25
        progress(step * 0.1, 20.0)
    assert out.getvalue().splitlines() == [
        "tiny: 4/20 s simulated, 10 s",
        "tiny: 8/20 s simulated, 20 s",
        "tiny: 12/20 s simulated, 30 s",
        "tiny: 16/20 s simulated, 40 s",
        "tiny: 20/20 s simulated, 50 s",
    ]


def test_compare_into_a_pipe_shows_a_heartbeat_each_run_and_where_its_outputs_went(tmp_path):
    out, scenario = tmp_path / "cmp", tiny5(tmp_path, duration=4.0)
    done = subprocess.run(
        [*FLEETMAP, "compare", str(scenario), "--seeds", "1", "--policies", "decay",
         "--out", str(out), "--workers", "1", "--progress-every", "0.5"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("fleetmap compare: 1 runs")
    # a worker process takes seconds to start: the first line after that is a heartbeat
    assert re.fullmatch(r"\.\.\. 0/1 runs done, \d+ s", lines[1]), lines[:3]
    assert any(re.fullmatch(r"\[1/1\] tiny5/decay/seed0 ok \(\d+\.\d s\)", x) for x in lines)
    assert lines[-1] == (
        f"outputs: {out / 'compare.csv'} (one row per run), {out / 'compare.md'} (the "
        f"tables), each run's in {out}/<scenario>/<policy>/seed<k>"
    )
    assert (out / "compare.md").is_file() and (out / "tiny5" / "decay" / "seed0").is_dir()


def test_run_into_a_pipe_says_how_far_it_got(tmp_path):
    scenario = tiny5(tmp_path, duration=4.0)
    done = subprocess.run([*FLEETMAP, "run", str(scenario), "--out", str(tmp_path / "run")],
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stderr
    said = [x for x in done.stderr.splitlines() if x.startswith("tiny5: ")]
    assert said and re.fullmatch(r"tiny5: 4/4 s simulated, \d+( m \d\d)? s", said[-1]), said
    assert done.stdout.splitlines()[-1] == f"outputs in {tmp_path / 'run'}"


def test_the_last_step_reports_the_whole_duration_so_the_last_line_is_always_printed():
    """Sim time summed in 0.1 s steps ends a hair short of 180 s; the last progress call
    still says 180/180 (moved_pod printed no last line before)."""
    from types import SimpleNamespace

    from scenarios.run.observers import ProgressReport

    clock, out = Clock(), io.StringIO()
    report = ProgressReport(SimProgress("moved_pod", out, every_s=10.0, clock=clock))
    now = 0.0
    for _ in range(1800):
        now += 0.1
        clock.now += 0.001  # far less than every_s: only the last line is due
        done = now >= 180.0 - 1e-9  # Episode.done's tolerance
        report.observe(SimpleNamespace(done=done, report=SimpleNamespace(now=now),
                                       setup=SimpleNamespace(duration=180.0)))  # fmt: skip
    assert now < 180.0  # 179.99999999997: the sum never reaches it
    assert out.getvalue().splitlines() == ["moved_pod: 180/180 s simulated, 1 s"]


def test_a_terminal_bar_ends_its_line_at_the_end_and_says_when_one_is_open():
    out = io.StringIO()
    bar = TerminalBar("tiny", 10, out)
    assert not bar.line_open
    bar(5.0, 20.0)
    assert bar.line_open and out.getvalue() == "\rtiny [##        ]    5.0/20 s"
    bar(20.0, 20.0)
    assert not bar.line_open and out.getvalue().endswith("\rtiny [##########]   20.0/20 s\n")
