"""The ``fleetmap`` command: one entry point, a subcommand per job (docs/commands.md)."""

from __future__ import annotations

import argparse
import sys

from fleet.bullet import SimulatorMissing, load_pybullet
from mapserver.cli.args import CommandParser
from mapserver.cli.import_cmd import add_import_parser
from mapserver.cli.journal import add_journal_parser
from mapserver.cli.map_build import add_map_parser
from mapserver.cli.serve import add_serve_parsers
from mapserver.cli.zones_cmd import add_zones_parser
from mapserver.version import package_version
from scenarios.cli.evaluate import add_evaluate_parser
from scenarios.cli.export import add_export_parser
from scenarios.cli.plan import add_plan_parser
from scenarios.cli.run import add_run_parsers
from scenarios.cli.sweep import add_sweep_parser
from scenarios.replay.run import run_replay
from scenarios.sweep.compare import add_compare_parser

SIMULATOR_COMMANDS = frozenset({"run", "compare", "sweep"})
"""The subcommands that drive the simulator: checked for PyBullet before anything else."""


def build_parser() -> argparse.ArgumentParser:
    parser = CommandParser(
        prog="fleetmap",
        description="Shared occupancy maps for robot fleets: fuse, serve, simulate, measure.",
    )
    parser.add_argument("--version", action="version", version=f"fleetmap {package_version()}")
    sub = parser.add_subparsers(dest="command", required=True)
    add_map_parser(sub)
    add_serve_parsers(sub)
    add_plan_parser(sub)
    add_run_parsers(sub)
    add_compare_parser(sub)
    sub.choices["replay"].set_defaults(handler=run_replay)  # journals and run replays
    add_sweep_parser(sub)
    add_journal_parser(sub)
    add_export_parser(sub)
    add_import_parser(sub)
    add_evaluate_parser(sub)
    add_zones_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the subcommand; the simulator's commands (``run``, ``compare``, ``sweep``)
    without PyBullet installed print one line naming the extra and exit 2."""
    args = build_parser().parse_args(argv)
    try:
        if args.command in SIMULATOR_COMMANDS:
            load_pybullet()  # before reading any file: runs in worker processes would fail
        return args.handler(args)
    except SimulatorMissing as exc:
        print(f"fleetmap {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
