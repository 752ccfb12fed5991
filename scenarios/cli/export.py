"""``fleetmap export ros2 RUN_DIR [--out FILE]``: a run as a rosbag2 MCAP
(``scenarios.replay.ros2_bag``), for ``ros2 bag info``/``play`` and Foxglove."""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

from scenarios.replay.mcap import REPLAY_FILENAME, ReplayFileError
from scenarios.replay.ros2_bag import ROS2_FILENAME, export_ros2
from scenarios.replay.run import replay_file_of


def add_export_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``export`` and its one format, ``ros2``."""
    export = subparsers.add_parser(
        "export", help="write a run in another format", description="Write a run in another format."
    )
    formats = export.add_subparsers(dest="format", required=True)
    ros2 = formats.add_parser(
        "ros2",
        help="a run as a rosbag2 MCAP (sensor_msgs, nav_msgs, tf2_msgs)",
        description="Write a run's scans, poses (/tf), plans, map and costmap as a rosbag2 "
        "MCAP (profile ros2, ros2msg schemas, CDR messages, sim time), read from the run's "
        f"{REPLAY_FILENAME}; open it with 'ros2 bag info FILE', 'ros2 bag play FILE' or "
        "Foxglove.",
    )
    ros2.add_argument(
        "run_dir",
        type=Path,
        metavar="RUN_DIR",
        help=f"a run's output folder (or its {REPLAY_FILENAME})",
    )
    ros2.add_argument(
        "--out", type=Path, help=f"the bag file to write (default: RUN_DIR/{ROS2_FILENAME})"
    )
    ros2.set_defaults(handler=run_export_ros2)


def run_export_ros2(args: argparse.Namespace) -> int:
    """The ``export ros2`` handler: 0 written, 2 on a bad RUN_DIR or --out."""
    replay = replay_file_of(args.run_dir)
    if replay is None:
        what = "no such file or folder" if not args.run_dir.exists() else f"no {REPLAY_FILENAME}"
        return _error(f"RUN_DIR {str(args.run_dir)!r} is not a run folder ({what})")
    out = args.out if args.out is not None else replay.parent / ROS2_FILENAME
    if out.resolve() == replay.resolve():
        return _error(f"--out {str(out)!r} is the run's replay itself; name another file")
    try:
        counts = export_ros2(replay, out)
    except ReplayFileError as exc:
        return _error(str(exc))
    except OSError as exc:
        return _error(f"--out {str(out)!r}: cannot write ({exc.strerror or exc})")
    print(f"wrote {out}: {_summary(counts)}")
    return 0


def _summary(counts: Counter[str]) -> str:
    """``N messages on K topics: /costmap 4, /map 4, ...`` (topics sorted)."""
    topics = ", ".join(f"{topic} {n}" for topic, n in sorted(counts.items()))
    return f"{sum(counts.values())} messages on {len(counts)} topics: {topics}"


def _error(message: str) -> int:
    print(f"fleetmap export: error: {message}", file=sys.stderr)
    return 2
