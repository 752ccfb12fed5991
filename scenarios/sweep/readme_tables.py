"""The README's comparison tables, printed or rewritten in place by a command.

The README quotes ``fleetmap compare`` tables between two markers that name the block and
hold the compare arguments that produce it::

    <!-- compare:begin NAME: SCENARIO... [--seeds N] [--policies P,...] -->
    `tiny`:

    | policy | runs | phantom freezes | ... |
    ...
    <!-- compare:end NAME -->

Between them, per scenario in the order given: a line ``` `NAME`: ```, a blank line, the
table of ``fleetmap compare`` (``scenarios.sweep.compare_table.table_lines``), scenarios
separated by a blank line.

``python -m scenarios.sweep.readme_tables [README.md] [--block NAME] [--from DIR]
[--out DIR] [--workers N] [--write]`` makes each block's Markdown (every block, or the one
named): it runs the block's compare (scenario x policy x seed, on the sweep's process
pool, outputs in ``--out``, a temporary folder by default), or with ``--from DIR`` reads
the runs of an earlier ``fleetmap compare --out DIR`` with the same arguments
(``DIR/<scenario>/<policy>/seed<k>/metrics.json``). It prints the Markdown; with
``--write`` it also puts it between the block's markers. Exit status 0; 1 when a run
failed or is missing; 2 for a README without the block or with bad arguments in it.
"""

from __future__ import annotations

import argparse
import json
import re
import shlex
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from mapserver.core.errors import FleetmapError
from scenarios.doc_blocks import marked_blocks
from scenarios.sweep.compare import DEFAULT_POLICIES, parse_policies
from scenarios.sweep.compare_table import runs_by_policy, table_lines
from scenarios.sweep.parallel import RunResult
from scenarios.sweep.sweep_file import Sweep, SweepRun, expand

__all__ = ["Block", "blocks", "block_markdown", "main", "results_from", "rewrite"]

README = Path(__file__).resolve().parents[2] / "README.md"
BEGIN = re.compile(r"^<!-- compare:begin (?P<name>[\w.-]+): (?P<args>.*?) -->$", re.M)
END = "<!-- compare:end {name} -->"


class ReadmeError(FleetmapError, ValueError):
    """A README block that cannot be read: missing, unterminated or with bad arguments."""


@dataclass(frozen=True)
class Block:
    """A block of the README: its ``name``, the compare ``sweep`` its arguments ask for
    (scenario paths resolved against the README's folder), and where its text lies
    (``start``, ``end``: character offsets of the Markdown between the markers)."""

    name: str
    sweep: Sweep
    start: int
    end: int


def blocks(text: str, root: Path) -> list[Block]:
    """Every block of README ``text`` (module docstring); scenario paths relative to
    ``root``. ReadmeError for a block without its end marker or with bad arguments."""
    try:
        marked = marked_blocks(text, BEGIN, END)
    except ValueError as exc:
        raise ReadmeError(f"README block: {exc}") from None
    return [Block(m["name"], _sweep(m["name"], m["args"], root), a, b) for m, a, b in marked]


def _sweep(name: str, args: str, root: Path) -> Sweep:
    parser = argparse.ArgumentParser(prog=f"README block {name}", add_help=False)
    parser.add_argument("scenarios", nargs="+")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--policies", default=DEFAULT_POLICIES)
    try:
        parsed = parser.parse_args(shlex.split(args))
        policies = parse_policies(parsed.policies)
    except (SystemExit, ValueError) as exc:
        raise ReadmeError(f"README block {name!r}: bad compare arguments {args!r}") from exc
    paths = tuple((root / s).resolve() for s in parsed.scenarios)
    return Sweep(paths, policies, tuple(range(parsed.seeds)), source=f"README block {name}")


def results_from(out: Path, runs: Sequence[SweepRun]) -> list[RunResult]:
    """The runs of an earlier compare in ``out`` (their metrics.json); a missing one is a
    failed result naming the file."""
    results = []
    for run in runs:
        folder = Path(out) / run.folder()
        path = folder / "metrics.json"
        if path.is_file():
            results.append(RunResult(run, "ok", folder, json.loads(path.read_text())))
        else:
            results.append(RunResult(run, "error", folder, error=f"{path}: no such file"))
    return results


def block_markdown(block: Block, results: Sequence[RunResult]) -> str:
    """The Markdown between ``block``'s markers (module docstring), ending in a newline."""
    parts = []
    for path in block.sweep.scenarios:
        by_policy = runs_by_policy(results, path.stem, block.sweep.policies)
        parts.append("\n".join([f"`{path.stem}`:", "", *table_lines(by_policy)]))
    return "\n\n".join(parts) + "\n"


def rewrite(text: str, block: Block, markdown: str) -> str:
    """README ``text`` with ``markdown`` between ``block``'s markers."""
    return text[: block.start] + markdown + text[block.end :]


def main(argv: Sequence[str] | None = None) -> int:
    """The command (module docstring)."""
    parser = argparse.ArgumentParser(
        prog="python -m scenarios.sweep.readme_tables",
        description="Print (or --write) the README's fleetmap compare tables.",
    )
    parser.add_argument("readme", nargs="?", type=Path, default=README)
    parser.add_argument("--block", help="only this block (default: every block)")
    parser.add_argument("--from", dest="source", type=Path, help="an earlier compare's --out")
    parser.add_argument("--out", type=Path, help="where the runs go (default: a temp folder)")
    parser.add_argument("--workers", type=int, default=None, help="parallel runs")
    parser.add_argument("--write", action="store_true", help="rewrite the README in place")
    args = parser.parse_args(argv)
    text = args.readme.read_text()
    try:
        chosen = [b for b in blocks(text, args.readme.parent) if args.block in (None, b.name)]
        if not chosen:
            raise ReadmeError(f"{args.readme}: no compare block {args.block or ''}".rstrip())
    except ReadmeError as exc:
        print(f"readme_tables: error: {exc}", file=sys.stderr)
        return 2
    status = 0
    made = []
    for block in chosen:
        results = _results(block, args)
        failed = [r for r in results if r.status != "ok"]
        for result in failed:
            print(f"readme_tables: {result.run.label()}: {result.error}", file=sys.stderr)
            status = 1
        markdown = block_markdown(block, results)
        print(markdown, end="", flush=True)
        made.append((block, markdown, not failed))
    for block, markdown, ok in reversed(made):  # from the end: earlier offsets stay valid
        if args.write and ok:
            text = rewrite(text, block, markdown)
    if args.write:
        args.readme.write_text(text)
    return status


def _results(block: Block, args: argparse.Namespace) -> list[RunResult]:
    runs = expand(block.sweep)
    if args.source is not None:
        return results_from(args.source, runs)
    from scenarios.sweep.parallel import run_sweep

    if args.out is not None:
        return run_sweep(runs, args.out, args.workers)
    with tempfile.TemporaryDirectory(prefix="fleetmap-readme-") as out:
        return run_sweep(runs, Path(out), args.workers)


if __name__ == "__main__":
    sys.exit(main())
