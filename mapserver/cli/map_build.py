"""``fleetmap map build``: fuse a recording offline and write the map files."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from mapserver.cli.args import add_dataclass_args, dataclass_from_args, xy_pair
from mapserver.cli.progress import ScanProgress
from mapserver.cli.recording_args import add_recording_args, recording_options_from_args
from mapserver.core.belief import BeliefGrid
from mapserver.core.geometry import GridGeometry
from mapserver.core.sensor_model import DEFAULT_POLICY, DecayParams, Policy, SensorModel
from mapserver.store.offline import fuse_all, write_map_outputs
from mapserver.store.recordings import Recording, open_recording
from mapserver.store.recordings.grid_fit import fit_grid


def add_sensor_model_args(parser: argparse.ArgumentParser) -> argparse._ArgumentGroup:
    """The sensor-model and decay flags shared by ``map build`` and ``evaluate``, one per
    field of ``SensorModel`` and ``DecayParams`` (``add_dataclass_args``: a new field
    brings its flag); returns their group (``map build`` adds ``--policy`` to it)."""
    group = parser.add_argument_group("sensor model and policy")
    for domain in (SensorModel, DecayParams):
        add_dataclass_args(group, domain)
    return group


def sensor_model_from_args(args: argparse.Namespace) -> tuple[SensorModel, DecayParams]:
    """Build the validated model objects; ValueError names the bad flag's field."""
    return dataclass_from_args(SensorModel, args), dataclass_from_args(DecayParams, args)


def add_grid_args(parser: argparse.ArgumentParser) -> None:
    """``--width``, ``--height``, ``--resolution``, ``--origin``: the grid, or (without
    width and height) one sized from the data; read by ``grid_from_args``."""
    parser.add_argument("--width", type=int, help="[cells] (default: sized from the data)")
    parser.add_argument("--height", type=int, help="[cells] (default: sized from the data)")
    parser.add_argument("--resolution", type=float, default=0.05, help="[m/cell]")
    parser.add_argument(
        "--origin",
        type=xy_pair,
        default=None,
        help="X,Y [m] of cell (0,0)'s corner (default: 0,0 with --width/--height, "
        "else sized from the data)",
    )


def add_map_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``map build``."""
    map_parser = subparsers.add_parser("map", help="offline map tools")
    map_sub = map_parser.add_subparsers(dest="map_command", required=True)
    build = map_sub.add_parser(
        "build",
        help="fuse a recording (ROS bag, CARMEN log, scan JSONL) into map.yaml + map.pgm "
        "+ logodds.npy",
        description="Fuse a recording offline; writes ROS map_server files and log-odds. "
        "Without --width/--height the grid is sized from the data (docs/recordings.md).",
    )
    build.add_argument(
        "recording", type=Path, help="ROS 1 or 2 bag, CARMEN log or scan file (docs/recordings.md)"
    )
    add_grid_args(build)
    build.add_argument("--out", type=Path, default=Path("."), help="output folder")
    build.add_argument("--json", action="store_true", help="print the figures as JSON last")
    add_recording_args(build)
    add_sensor_model_args(build).add_argument(
        "--policy",
        choices=[p.value for p in Policy],
        default=DEFAULT_POLICY.value,
        help="how evidence accumulates and ages",
    )
    build.set_defaults(handler=run_map_build)


def grid_from_args(args: argparse.Namespace, recording: Recording) -> GridGeometry:
    """The grid the flags choose, or one sized from the recording (a first pass over it)
    when neither --width nor --height is given; ValueError names a missing one."""
    if args.width is None and args.height is None:
        if args.origin is not None:
            raise ValueError("--origin needs --width and --height (or neither, to size from data)")
        return fit_grid(recording, args.resolution)
    if args.width is None or args.height is None:
        missing = "--width" if args.width is None else "--height"
        raise ValueError(f"{missing} is missing: give both --width and --height, or neither")
    return GridGeometry(args.width, args.height, args.resolution, *(args.origin or (0.0, 0.0)))


def run_map_build(args: argparse.Namespace) -> int:
    """Open, validate, fuse, write; returns the exit code (2 for bad input: nothing written)."""
    try:
        model, decay = sensor_model_from_args(args)
        policy = Policy.parse(args.policy)
        recording = open_recording(args.recording, recording_options_from_args(args))
        geometry = grid_from_args(args, recording)
        belief = BeliefGrid(geometry, model, policy, decay)
        progress = ScanProgress("fused")
        stats = fuse_all(belief, recording, progress, total=recording.scan_count())
        progress.finish()
    except ValueError as exc:  # RecordingError, ScanFileError, FieldError: all ValueErrors
        print(f"fleetmap map build: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"fleetmap map build: error: cannot read {args.recording}: {exc}", file=sys.stderr)
        return 2
    yaml_path = write_map_outputs(belief, args.out)
    if args.json:
        print(json.dumps(stats.as_dict()))
    else:
        print(
            f"fused {stats.scans} scans ({stats.cells_updated} cell updates) in "
            f"{stats.fusion_s:.3f} s = {stats.scans_per_s:.0f} scans/s (kernel load "
            f"{stats.kernel_load_s:.3f} s apart) into {geometry.width} x {geometry.height} "
            f"cells at {geometry.resolution} m, origin {geometry.origin_x:g},"
            f"{geometry.origin_y:g}; wrote {yaml_path}"
        )
    return 0
