"""``fleetmap compare SCENARIO... [--seeds N] [--policies P,...] [--out DIR] [--workers N]``
(docs/commands.md): every scenario x policy x seed, run in parallel by the sweep's
runner (``scenarios.sweep.parallel``), then one table per scenario
(``scenarios.sweep.compare_table``).

Seeds are 0 .. N-1. Outputs: ``DIR/compare.csv`` (one row per run, the columns of a
sweep's results.csv), ``DIR/compare.md`` (the tables, also printed) and each run's own
outputs in ``DIR/<scenario>/<policy>/seed<k>``. Progress lines go to stdout, flushed, as
runs finish, with a heartbeat between them (``--progress-every``; ``progress``). Exit
status: 0 when every run succeeded, 1 when some failed (they are listed; the others are
still in the tables), 2 when nothing could start (a bad scenario file or policy).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mapserver.core.sensor_model import Policy
from scenarios.sweep.sweep_file import DEFAULT_POLICIES as SWEEP_POLICIES

__all__ = ["CSV_FILENAME", "MD_FILENAME", "add_compare_parser", "parse_policies", "run_compare"]

CSV_FILENAME = "compare.csv"
MD_FILENAME = "compare.md"
DEFAULT_SEEDS = 5
DEFAULT_POLICIES = ",".join(SWEEP_POLICIES)
"""The policies compared unless told (``sweep_file.DEFAULT_POLICIES``)."""


def add_compare_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``compare``."""
    from scenarios.cli.sweep import add_progress_argument, positive_int

    compare = subparsers.add_parser(
        "compare",
        help="run scenarios under several policies and seeds; one table per scenario",
        description="Run every scenario x policy x seed in parallel and print, per "
        "scenario, each headline metric's mean and 95 % interval over seeds per policy; "
        "writes DIR/compare.csv (one row per run) and DIR/compare.md (the tables).",
    )
    compare.add_argument("scenarios", type=Path, nargs="+", metavar="SCENARIO",
                         help="scenario YAML files")  # fmt: skip
    compare.add_argument("--seeds", type=positive_int, default=DEFAULT_SEEDS,
                         help=f"seeds 0..N-1 per policy (default: {DEFAULT_SEEDS})")  # fmt: skip
    compare.add_argument("--policies", default=DEFAULT_POLICIES,
                         help=f"comma-separated (default: {DEFAULT_POLICIES})")  # fmt: skip
    compare.add_argument("--out", type=Path, default=Path("out/compare"), help="output folder")
    compare.add_argument("--workers", type=positive_int, default=None,
                         help="parallel runs (default: CPU count)")  # fmt: skip
    add_progress_argument(compare)
    compare.set_defaults(handler=run_compare)


def parse_policies(text: str) -> tuple[str, ...]:
    """``decay,binary`` -> ``("decay", "binary")``; ValueError naming a bad, repeated or
    missing policy."""
    names = [p.strip() for p in text.split(",") if p.strip()]
    if not names:
        raise ValueError(f"--policies: must name at least one policy, got {text!r}")
    out: list[str] = []
    for name in names:
        try:
            policy = Policy.parse(name).value
        except (ValueError, TypeError, AttributeError):
            choices = ", ".join(p.value for p in Policy)
            raise ValueError(
                f"--policies: {name!r} is not a policy (choose from {choices})"
            ) from None
        if policy in out:
            raise ValueError(f"--policies: {name!r} is listed twice")
        out.append(policy)
    return tuple(out)


def run_compare(args: argparse.Namespace) -> int:
    """The ``compare`` handler (module docstring for the exit status)."""
    from mapserver.store.atomic import atomic_output
    from scenarios.spec.scenario import load_scenario
    from scenarios.sweep.compare_table import compare_markdown
    from scenarios.sweep.parallel import run_sweep
    from scenarios.sweep.progress import RunProgress
    from scenarios.sweep.results import write_csv
    from scenarios.sweep.sweep_file import ScenarioError, Sweep, expand

    try:
        policies = parse_policies(args.policies)
        paths = _scenario_paths(args.scenarios)
        for name in args.scenarios:  # its own error names the file, line and field
            load_scenario(name)
        sweep = Sweep(paths, policies, tuple(range(args.seeds)), source="fleetmap compare")
    except (ScenarioError, ValueError) as exc:
        print(f"fleetmap compare: error: {exc}", file=sys.stderr)
        return 2
    runs = expand(sweep)
    print(f"fleetmap compare: {len(runs)} runs ({len(paths)} scenario(s) x {len(policies)} "
          f"policies x {args.seeds} seed(s)) in local processes", flush=True)  # fmt: skip
    progress = RunProgress(len(runs), sys.stdout, args.progress_every)
    results = run_sweep(runs, args.out, args.workers, on_result=progress, on_wait=progress.tick)
    out = Path(args.out)
    write_csv(sweep, results, out / CSV_FILENAME)
    text = compare_markdown(results, [p.stem for p in paths], policies, args.seeds)
    with atomic_output(out / MD_FILENAME) as f:
        f.write(text.encode())
    print()
    print(text, end="")
    print(f"\noutputs: {out / CSV_FILENAME} (one row per run), {out / MD_FILENAME} (the "
          f"tables), each run's in {out}/<scenario>/<policy>/seed<k>", flush=True)  # fmt: skip
    failed = [r for r in results if r.status != "ok"]
    if failed:
        print(f"fleetmap compare: error: {len(failed)} of {len(results)} runs failed:",
              file=sys.stderr)  # fmt: skip
        for result in failed:
            print(f"  {result.run.label()}: {result.error}", file=sys.stderr)
        return 1
    return 0


def _scenario_paths(names: list[Path]) -> tuple[Path, ...]:
    """The scenario files, resolved; ValueError for a missing file or a repeated stem
    (each scenario's runs go in a folder named by its stem)."""
    paths: list[Path] = []
    for name in names:
        path = Path(name).resolve()
        if not path.is_file():
            raise ValueError(
                f"{name}: no such scenario file (give a scenario YAML: scenarios/*.yaml)"
            )
        if any(p.stem == path.stem for p in paths):
            raise ValueError(f"{name}: another scenario has the file name {path.stem!r}")
        paths.append(path)
    return tuple(paths)
