"""``fleetmap evaluate RECORDING``: a verdict on a recording without ground truth
(docs/evaluate.md): the recording fused under each policy (and OctoMap, when installed)
in one pass, measured, and written as ``report.md``, ``report.csv`` and ``evaluate.png``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mapserver.cli.map_build import (
    add_grid_args,
    add_sensor_model_args,
    grid_from_args,
    sensor_model_from_args,
)
from mapserver.cli.progress import ScanProgress
from mapserver.cli.recording_args import add_recording_args, recording_options_from_args
from mapserver.core.sensor_model import Policy
from mapserver.store.atomic import staged_files
from mapserver.store.recordings import open_recording
from scenarios.cli.sweep import positive_float
from scenarios.evaluate.maps import FleetmapMap, MapUnderTest, parse_policies
from scenarios.evaluate.octomap_peer import (
    INSTALL_HINT,
    PEER_NAME,
    OctoMapPeer,
    PeerMissing,
    octomap_installed,
)
from scenarios.evaluate.picture import write_picture
from scenarios.evaluate.report import csv_text, markdown_report, markdown_table, summary
from scenarios.evaluate.run import evaluate

OUTPUTS = ("report.md", "report.csv", "evaluate.png")
DEFAULT_POLICIES = ",".join(p.value for p in Policy)


def _policies(text: str) -> list[Policy]:
    """argparse type for ``--policies``: comma-separated policy names."""
    try:
        return parse_policies(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _cells(text: str) -> int:
    """argparse type for ``--ghost-margin``: a whole number of cells >= 0."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a whole number of cells >= 0, got {text!r}")
    return value


def add_evaluate_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``evaluate``."""
    parser = subparsers.add_parser(
        "evaluate",
        help="a verdict on a recording: each policy's (and OctoMap's) structure kept, "
        "ghost trails, unknown floor and speed",
        description="Fuse a recording under each policy (and OctoMap's classic update when "
        "pyoctomap is installed) in one pass and measure each map without ground truth: "
        "structure kept, ghost cell-seconds, unknown share of the floor seen, occupied "
        "cells, fusion speed (docs/evaluate.md). Writes report.md, report.csv and "
        "evaluate.png.",
    )
    parser.add_argument(
        "recording", type=Path, help="ROS 1 or 2 bag, CARMEN log or scan file (docs/recordings.md)"
    )
    parser.add_argument(
        "--policies",
        type=_policies,
        default=DEFAULT_POLICIES,
        help="comma-separated policies to fuse under",
    )
    parser.add_argument(
        "--peer",
        choices=(PEER_NAME, "none"),
        default=None,
        help="the peer map beside fleetmap's (default: octomap when pyoctomap is installed, "
        "else none)",
    )
    parser.add_argument("--out", type=Path, default=Path("out/evaluate"), help="output folder")
    parser.add_argument(
        "--read-every",
        type=positive_float,
        default=1.0,
        help="[s] of recording time between ghost reads",
    )
    parser.add_argument(
        "--ghost-margin",
        type=_cells,
        default=2,
        help="[cells] a cell is seen through when more than this short of a return",
    )
    add_grid_args(parser)
    add_recording_args(parser)
    add_sensor_model_args(parser)
    parser.set_defaults(handler=run_evaluate)


def with_peer(choice: str | None) -> bool:
    """Whether to run the OctoMap peer: asked for (PeerMissing when pyoctomap is not
    installed), refused, or by default when installed (a note on stderr when not)."""
    if choice == "none":
        return False
    if octomap_installed():
        return True
    if choice == PEER_NAME:
        raise PeerMissing(f"--peer octomap needs pyoctomap, which is not installed: {INSTALL_HINT}")
    print(
        f"fleetmap evaluate: note: no OctoMap peer, pyoctomap is not installed ({INSTALL_HINT})",
        file=sys.stderr,
    )
    return False


def run_evaluate(args: argparse.Namespace) -> int:
    """Check, open, measure in one pass, then write the three files together; exit 2 on
    bad input with nothing written."""
    try:
        model, decay = sensor_model_from_args(args)
        recording = open_recording(args.recording, recording_options_from_args(args))
        geometry = grid_from_args(args, recording)
        peer = with_peer(args.peer)  # its note only once the input is known good
        maps: list[MapUnderTest] = [FleetmapMap(geometry, model, p, decay) for p in args.policies]
        if peer:
            maps.append(OctoMapPeer(geometry, model))
        progress = ScanProgress("evaluated")
        try:
            evaluation = evaluate(
                recording, geometry, maps, args.read_every, args.ghost_margin,
                progress, total=recording.scan_count(),
            )  # fmt: skip
        finally:
            progress.finish()
    except (ValueError, PeerMissing) as exc:  # RecordingError, ScanFileError, FieldError
        print(f"fleetmap evaluate: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"fleetmap evaluate: error: cannot read {args.recording}: {exc}", file=sys.stderr)
        return 2
    source = str(args.recording)
    try:
        with staged_files(args.out, OUTPUTS) as staging:
            (staging / "report.md").write_text(markdown_report(evaluation, source))
            (staging / "report.csv").write_text(csv_text(evaluation.verdicts))
            write_picture(evaluation, staging / "evaluate.png")
    except OSError as exc:
        print(f"fleetmap evaluate: error: --out {args.out}: cannot write ({exc})", file=sys.stderr)
        return 2
    print(summary(evaluation, source))
    print()
    print(markdown_table(evaluation.verdicts), end="")
    print()
    print("outputs: " + ", ".join(str(args.out / name) for name in OUTPUTS))
    return 0
