"""``fleetmap run``: one scenario, its metrics as a table (or JSON); ``fleetmap compare``
is ``scenarios.sweep.compare``."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from mapserver.core.errors import FleetmapError
from mapserver.core.sensor_model import Policy
from scenarios.score.metric_registry import View, shown_in

METRICS_FILE = "metrics.json"
FOXGLOVE_PORT = 8765  # Foxglove's default WebSocket port (scenarios.replay.live)


def add_run_parsers(subparsers: argparse._SubParsersAction) -> None:
    """Register ``run``."""
    run = subparsers.add_parser(
        "run",
        help="run one scenario end to end",
        description="Run a scenario: simulated units, the shared map, planners; writes "
        "metrics.json, freezes.json, trips.json, collisions.json, report.png and replay.mcap "
        "to --out.",
    )
    run.add_argument("scenario", type=Path, help="scenario YAML (see docs/scenarios.md)")
    run.add_argument("--policy", choices=[p.value for p in Policy],
                     help="override the map policy (default: the scenario's)")  # fmt: skip
    run.add_argument("--seed", type=int, help="override the scenario's seed (default: its own)")
    run.add_argument(
        "--zones", type=int, metavar="N",
        help="serve the floor with N map servers of its own, strips with overlapping "
        "borders (map_server.zones, docs/scaling.md; default: the scenario's)",
    )  # fmt: skip
    run.add_argument("--server", help="URL of a running map server (default: start one)")
    run.add_argument("--out", type=Path, default=Path("out/run"), help="output folder")
    run.add_argument("--json", action="store_true", help="print metrics JSON as the last line")
    run.add_argument(
        "--foxglove", action="store_true",
        help=f"stream the run live to Foxglove on ws://127.0.0.1:{FOXGLOVE_PORT}; needs the "
        "'foxglove' extra",
    )  # fmt: skip
    run.add_argument(
        "--foxglove-port", type=_port, metavar="PORT",
        help=f"the live stream's port instead of {FOXGLOVE_PORT} (0: a free port); implies "
        "--foxglove",
    )  # fmt: skip
    run.set_defaults(handler=run_one)


def run_one(args: argparse.Namespace) -> int:
    from scenarios.run.execute import ScenarioError, execute

    if args.zones is not None and args.server is not None:
        print("fleetmap run: error: --zones: a run against --server uses that one server "
              "(give one of them)", file=sys.stderr)  # fmt: skip
        return 2
    overrides = None if args.zones is None else {"map_server.zones": args.zones}
    progress = _progress_bar(args.scenario.stem)
    try:
        live = _live(_foxglove_port(args))
        try:
            metrics = execute(
                args.scenario, args.policy, args.seed, args.server, args.out,
                progress=progress, announce=_say, overrides=overrides,
                observers=[] if live is None else [live],
            )  # fmt: skip
        finally:
            if live is not None:
                live.stop()
    except (ScenarioError, ValueError, OSError, FleetmapError) as exc:
        if progress.line_open:  # the error starts a line of its own, never a blank one
            print(file=sys.stderr)
        print(f"fleetmap run: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(metrics))
    else:
        print(format_table([metrics]))
        print(f"outputs in {args.out}")
    return 0


def _foxglove_port(args: argparse.Namespace) -> int | None:
    """The live stream's port: ``--foxglove-port``, else the default with ``--foxglove``,
    else None (no stream)."""
    if args.foxglove_port is not None:
        return args.foxglove_port
    return FOXGLOVE_PORT if args.foxglove else None


def _live(port: int | None):
    """The live Foxglove stream of ``--foxglove`` (None without it), listening already."""
    if port is None:
        return None
    from scenarios.replay.live import FoxgloveLive

    live = FoxgloveLive(port)
    _say(f"Foxglove: {live.url} (open in Foxglove: Open connection)")
    return live


def _port(text: str) -> int:
    """A TCP port, 0 to 65535 (0: a free one)."""
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"PORT must be an integer 0-65535, got {text!r}") from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"PORT must be an integer 0-65535, got {port}")
    return port


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def format_table(rows: list[dict]) -> str:
    """A plain-text table of the metric registry's ``fleetmap run`` columns."""
    columns = shown_in(View.RUN_TABLE)
    cells = [[m.header for m in columns]]
    for row in rows:
        cells.append([_cell(m.stored(row), m.fixed) for m in columns])
    widths = [max(len(r[i]) for r in cells) for i in range(len(columns))]
    lines = ["  ".join(c.rjust(w) for c, w in zip(r, widths, strict=True)) for r in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _cell(value: object, fixed) -> str:
    """``value`` in the table, floats written by ``fixed`` (the metric's decimals)."""
    if isinstance(value, float):
        return fixed(value)
    if value is None:
        return "-"
    if isinstance(value, list):
        return ",".join("never" if v is None else fixed(v) for v in value) or "-"
    return str(value)


def _progress_bar(label: str):
    """A one-line progress bar on stderr when it is a terminal (``TerminalBar``), else a
    line now and then (``SimProgress``)."""
    from scenarios.sweep.progress import SimProgress, TerminalBar

    if not sys.stderr.isatty():
        return SimProgress(label)
    width = max(10, min(40, os.get_terminal_size(sys.stderr.fileno()).columns - 40))
    return TerminalBar(label, width)
