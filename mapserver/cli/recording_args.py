"""The flags that say how to read a recording, shared by ``map build``, ``import`` and
``evaluate`` (docs/recordings.md)."""

from __future__ import annotations

import argparse

from mapserver.core.scan import Pose2D
from mapserver.store.recordings import RecordingOptions


def pose_triple(text: str) -> Pose2D:
    """argparse type for ``X,Y,YAW`` [m, m, rad] (negative values as written)."""
    try:
        x, y, yaw = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected X,Y,YAW in metres and radians, got {text!r}"
        ) from None
    return Pose2D(x, y, yaw)


def add_recording_args(parser: argparse.ArgumentParser) -> None:
    """Register the recording flags in their own group."""
    d = RecordingOptions()
    group = parser.add_argument_group("reading the recording (docs/recordings.md)")
    group.add_argument(
        "--topic", default=d.topic, help="LaserScan topic of a bag (default: its only one)"
    )
    group.add_argument(
        "--fixed-frame",
        default=d.fixed_frame,
        help=f"frame the map is built in; /tf is followed from it (default: {d.fixed_frame})",
    )
    group.add_argument(
        "--pose-topic",
        default=d.pose_topic,
        help="take the sensor's poses from this Odometry, PoseStamped or "
        "PoseWithCovarianceStamped topic instead of /tf",
    )
    group.add_argument(
        "--fixed-sensor",
        type=pose_triple,
        default=d.fixed_sensor,
        metavar="X,Y,YAW",
        help="the sensor stood still at this pose (a recording without poses)",
    )
    group.add_argument(
        "--start", type=float, default=d.start, help="[s] skip scans before this, from the first"
    )
    group.add_argument(
        "--end", type=float, default=d.end, help="[s] stop after this, from the first message"
    )
    group.add_argument(
        "--unit-id", default=d.unit_id, help="unit id of the scans (default: the file's name)"
    )


def recording_options_from_args(args: argparse.Namespace) -> RecordingOptions:
    """The options the flags give; RecordingError names a bad one."""
    return RecordingOptions(
        topic=args.topic,
        fixed_frame=args.fixed_frame,
        pose_topic=args.pose_topic,
        fixed_sensor=args.fixed_sensor,
        start=args.start,
        end=args.end,
        unit_id=args.unit_id,
    )
