"""``fleetmap sweep SWEEP.yaml [--workers N] [--ray ADDRESS] [--out DIR]``: many runs in
parallel (``scenarios.sweep.sweep_file`` for the file, ``scenarios.sweep.parallel`` for the pool or
Ray, ``scenarios.sweep.results`` for ``results.csv`` and ``tradeoff.png``,
``scenarios.sweep.pareto`` for ``pareto.csv``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_sweep_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``sweep``."""
    sweep = subparsers.add_parser(
        "sweep",
        help="run many scenario x policy x parameter x seed runs in parallel",
        description="Run every combination of a sweep file's scenarios, policies, parameter "
        "grid and seeds in parallel; writes DIR/results.csv (one row per run), "
        "DIR/tradeoff.png, DIR/pareto.csv (the settings no other setting beats on phantom "
        "freeze seconds, forgotten cells and stale-free plans, averaged over seeds) and "
        "each run's outputs under DIR.",
    )
    sweep.add_argument("sweep", type=Path, help="sweep YAML (see docs/scenarios.md)")
    sweep.add_argument(
        "--workers", type=positive_int, default=None, help="parallel runs (default: CPU count)"
    )
    sweep.add_argument(
        "--ray",
        metavar="ADDRESS",
        help="run on the Ray cluster at ADDRESS ('local' starts one; needs fleetmap[ray])",
    )
    sweep.add_argument("--out", type=Path, default=Path("out/sweep"), help="output folder")
    add_progress_argument(sweep)
    sweep.set_defaults(handler=run_sweep_command)


def run_sweep_command(args: argparse.Namespace) -> int:
    """The ``sweep`` handler: 0 when every run succeeded, 1 when some failed, 2 when the
    sweep could not start (bad file, Ray missing)."""
    from scenarios.sweep.parallel import MissingExtraError, import_ray, run_sweep
    from scenarios.sweep.pareto import PARETO_FILENAME, write_pareto
    from scenarios.sweep.progress import RunProgress
    from scenarios.sweep.results import PLOT_FILENAME, RESULTS_FILENAME, write_csv, write_plot
    from scenarios.sweep.sweep_file import ScenarioError, expand, load_sweep

    try:
        if args.ray is not None:
            import_ray()
        sweep = load_sweep(args.sweep)
    except (ScenarioError, MissingExtraError) as exc:
        print(f"fleetmap sweep: error: {exc}", file=sys.stderr)
        return 2
    runs = expand(sweep)
    where = f"Ray at {args.ray}" if args.ray is not None else "local processes"
    print(f"fleetmap sweep: {len(runs)} runs on {where}", file=sys.stderr, flush=True)
    try:
        progress = RunProgress(len(runs), every_s=args.progress_every)
        results = run_sweep(
            runs, args.out, args.workers, args.ray, on_result=progress, on_wait=progress.tick
        )
    except MissingExtraError as exc:
        print(f"fleetmap sweep: error: {exc}", file=sys.stderr)
        return 2
    write_csv(sweep, results, args.out / RESULTS_FILENAME)
    write_plot(sweep, results, args.out / PLOT_FILENAME)
    front = write_pareto(sweep, results, args.out / PARETO_FILENAME)
    failed = sum(r.status != "ok" for r in results)
    print(f"{len(results) - failed}/{len(results)} runs ok; "
          f"{args.out / RESULTS_FILENAME}, {args.out / PLOT_FILENAME}, "
          f"{args.out / PARETO_FILENAME} ({front} non-dominated settings)")  # fmt: skip
    return 1 if failed else 0


def add_progress_argument(parser: argparse.ArgumentParser) -> None:
    """``--progress-every SECONDS``: the longest silence between progress lines."""
    from scenarios.sweep.progress import DEFAULT_EVERY_S

    parser.add_argument("--progress-every", type=positive_float, default=DEFAULT_EVERY_S,
                        metavar="SECONDS", help="print a progress line at least this often "
                        f"while runs go on (default: {DEFAULT_EVERY_S:g})")  # fmt: skip


def positive_float(text: str) -> float:
    """An argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number > 0, got {text!r}") from None
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a number > 0, got {value:g}")
    return value


def positive_int(text: str) -> int:
    """An argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {value}")
    return value
