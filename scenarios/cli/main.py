"""The ``fleetmap`` command: one entry point, a subcommand per job (docs/commands.md)."""

from __future__ import annotations

import argparse
import sys

from mapserver.cli.journal import add_journal_parser
from mapserver.cli.map_build import add_map_parser
from mapserver.cli.serve import add_serve_parsers
from scenarios.cli.export import add_export_parser
from scenarios.cli.plan import add_plan_parser
from scenarios.cli.run import add_run_parsers
from scenarios.cli.sweep import add_sweep_parser
from scenarios.replay.run import run_replay
from scenarios.sweep.compare import add_compare_parser


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fleetmap",
        description="Shared occupancy maps for robot fleets: fuse, serve, simulate, measure.",
    )
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
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.handler(args)


if __name__ == "__main__":
    sys.exit(main())
