"""One ``Scan`` from a recorded laser reading and the sensor's pose in the map plane.

Readers hand over the reading as the sensor wrote it (angles in the sensor's frame,
possibly clockwise, possibly from a sensor hung upside down) and get back a ``Scan``
whose beams turn counter-clockwise in the map, validated by ``Scan.from_dict`` (REP 117
ranges: ``+inf`` no return, NaN dropped, ranges rounded to float32 as everywhere).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mapserver.core.scan import PoseStd, Scan, ScanError
from mapserver.store.recordings.base import RecordingError
from mapserver.store.recordings.tf_buffer import PlanarPose


def counter_clockwise(
    angle_min: float, angle_increment: float, ranges: np.ndarray, mirrored: bool
) -> tuple[float, float, np.ndarray]:
    """The beams as seen from above the map, turning counter-clockwise: (angle_min
    [rad] from the sensor's heading, angle_increment > 0 [rad], ranges [m]).

    A sensor upside down (``mirrored``) sweeps clockwise in the map, so its beam at
    angle a points at heading - a; a negative increment (a laser that scans clockwise)
    is the same sweep read from its other end. Either way the ranges are reversed and
    the first angle is that of the last beam."""
    if mirrored:
        angle_min, angle_increment = -angle_min, -angle_increment
    if angle_increment < 0:
        angle_min += (len(ranges) - 1) * angle_increment
        angle_increment = -angle_increment
        ranges = ranges[::-1]
    return angle_min, angle_increment, ranges


def build_scan(
    source: Path | str,
    unit_id: str,
    stamp: float,
    pose: PlanarPose,
    angle_min: float,
    angle_increment: float,
    range_min: float,
    range_max: float,
    ranges: np.ndarray,
    pose_std: PoseStd | None = None,
) -> Scan:
    """The validated ``Scan`` of one reading at ``stamp`` [s] taken at ``pose``;
    RecordingError naming ``source``, the stamp and the field when it is not a valid scan
    (a zero angle increment, range_max <= range_min, ...)."""
    angle_min, angle_increment, ranges = counter_clockwise(
        angle_min, angle_increment, np.asarray(ranges, dtype=np.float64), pose.mirrored
    )
    body = {
        "unit_id": unit_id,
        "stamp": stamp,
        "pose": {"x": pose.x, "y": pose.y, "yaw": pose.yaw},
        "angle_min": angle_min,
        "angle_increment": angle_increment,
        "range_min": range_min,
        "range_max": range_max,
        "ranges": ranges,
    }
    if pose_std is not None:
        body["pose_std"] = {"xy": pose_std.xy, "yaw": pose_std.yaw}
    try:
        return Scan.from_dict(body)
    except ScanError as exc:
        raise RecordingError(f"{source}: the scan at stamp {stamp:.6f} s: {exc}") from None
