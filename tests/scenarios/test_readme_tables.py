"""The README's tables come from a command (``scenarios.sweep.readme_tables``): its blocks
are read and rewritten in place, and the README quotes what the command prints for its
smallest block (the test scenario ``tiny``, one seed, two policies: two short runs)."""

from __future__ import annotations

from pathlib import Path

import pytest

from scenarios.sweep.parallel import RunResult
from scenarios.sweep.readme_tables import (
    README,
    ReadmeError,
    block_markdown,
    blocks,
    main,
    results_from,
    rewrite,
)
from scenarios.sweep.sweep_file import expand

TEXT = """# A readme

<!-- compare:begin small: a.yaml b.yaml --seeds 2 --policies dual,binary -->
old table
<!-- compare:end small -->
after
"""


def test_a_block_names_its_compare_and_is_rewritten_in_place(tmp_path: Path) -> None:
    (block,) = blocks(TEXT, tmp_path)
    assert block.name == "small"
    assert [p.name for p in block.sweep.scenarios] == ["a.yaml", "b.yaml"]
    assert block.sweep.policies == ("dual", "binary") and block.sweep.seeds == (0, 1)
    assert TEXT[block.start : block.end] == "old table\n"
    assert rewrite(TEXT, block, "new\n") == TEXT.replace("old table\n", "new\n")


def test_a_block_without_its_end_or_with_bad_arguments_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ReadmeError, match="compare:end small"):
        blocks(TEXT.replace("<!-- compare:end small -->", ""), tmp_path)
    with pytest.raises(ReadmeError, match="bad compare arguments"):
        blocks(TEXT.replace("dual,binary", "dual,greedy"), tmp_path)


def test_the_markdown_is_a_table_per_scenario_under_its_name(tmp_path: Path) -> None:
    (block,) = blocks(TEXT, tmp_path)
    runs = expand(block.sweep)
    metrics = {"phantom_freeze_seconds": 2.0, "time_to_clear_s": []}
    results = [RunResult(r, "ok", tmp_path, {**metrics, "tasks_completed": r.seed}) for r in runs]
    text = block_markdown(block, results)
    first, second = text.split("\n\n`b`:\n\n")
    assert first.startswith("`a`:\n\n| policy | runs | phantom freezes | phantom s |")
    assert "| dual | 2 | - | 2.0 ± 0.0 |" in first
    assert "| 0.5 ± 6.4 |" in second and "| - |" in second  # tasks; nothing removed
    assert text.endswith("| dual vs binary | |" + " ~ |" * 12 + "\n")  # 12 headline columns


def test_runs_are_read_from_an_earlier_compare_or_named_missing(tmp_path: Path) -> None:
    (block,) = blocks(TEXT, tmp_path)
    runs = expand(block.sweep)
    folder = tmp_path / runs[0].folder()
    folder.mkdir(parents=True)
    (folder / "metrics.json").write_text('{"collisions": 1}')
    results = results_from(tmp_path, runs)
    assert results[0].status == "ok" and results[0].metrics == {"collisions": 1}
    assert {r.status for r in results[1:]} == {"error"}
    assert "metrics.json: no such file" in results[1].error


def test_the_readme_quotes_what_the_command_prints_for_tiny(capsys) -> None:
    text = README.read_text()
    (tiny,) = [b for b in blocks(text, README.parent) if b.name == "tiny"]
    assert main([str(README), "--block", "tiny", "--workers", "2"]) == 0
    printed = capsys.readouterr().out
    assert printed == text[tiny.start : tiny.end], (
        "README.md's tiny table is stale: python -m scenarios.sweep.readme_tables "
        "--block tiny --write"
    )
