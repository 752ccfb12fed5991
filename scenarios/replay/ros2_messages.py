"""ROS 2 messages (as dicts for ``ros2_msgdefs``' types) from what a run recorded.

Times are the run's sim time as integer nanoseconds [ns], written as
``builtin_interfaces/Time`` (``sec``, ``nanosec``). Positions [m], angles [rad], all in
the one ``map`` frame (REP 105's fixed world frame); a unit ``u1``'s body frame is
``u1/base_link``, where its LiDAR sits (the sim's LiDAR is centred on the unit, so the
scans are in ``u1/base_link`` and no ``/tf_static`` mount is needed).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Final

import numpy as np

from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Scan
from scenarios.replay.foxglove_messages import FRAME_ID, NS_PER_S, pose

Message = dict[str, Any]

BASE_LINK: Final = "base_link"


def base_link(unit_id: str) -> str:
    """The body frame of unit ``unit_id``: ``<unit_id>/base_link``."""
    return f"{unit_id}/{BASE_LINK}"


def ros_time(ns: int) -> Message:
    """Integer nanoseconds as a ``builtin_interfaces/Time``."""
    return {"sec": ns // NS_PER_S, "nanosec": ns % NS_PER_S}


def header(ns: int, frame_id: str = FRAME_ID) -> Message:
    return {"stamp": ros_time(ns), "frame_id": frame_id}


def laser_scan(ns: int, scan: Scan) -> Message:
    """A ``sensor_msgs/LaserScan`` in the unit's ``base_link``: beam i at ``angle_min + i *
    angle_increment`` [rad]; ranges as float32 with REP 117's classes as they are (+inf no
    return, NaN invalid); no intensities; ``time_increment`` and ``scan_time`` 0 (the
    sim's scan is instantaneous)."""
    n = scan.beam_count
    return {
        "header": header(ns, base_link(scan.unit_id)),
        "angle_min": scan.angle_min,
        "angle_max": scan.angle_min + (n - 1) * scan.angle_increment,
        "angle_increment": scan.angle_increment,
        "time_increment": 0.0,
        "scan_time": 0.0,
        "range_min": scan.range_min,
        "range_max": scan.range_max,
        "ranges": np.asarray(scan.ranges, dtype=np.float32).tolist(),
        "intensities": [],
    }


def tf_message(ns: int, scan: Scan) -> Message:
    """A ``tf2_msgs/TFMessage``: ``map`` -> ``<unit>/base_link`` at the pose the unit sent
    with ``scan`` (the pose its scan was fused at), turned by yaw about +z."""
    p = pose(scan.pose.x, scan.pose.y, yaw=scan.pose.yaw)
    transform = {"translation": p["position"], "rotation": p["orientation"]}
    stamped = {"header": header(ns), "child_frame_id": base_link(scan.unit_id)}
    return {"transforms": [{**stamped, "transform": transform}]}


def occupancy_grid(ns: int, geometry: GridGeometry, values: np.ndarray) -> Message:
    """A ``nav_msgs/OccupancyGrid`` of int8 ``values`` (height, width), row 0 at the
    origin's y (as the grids here), cells ``resolution`` [m], origin unrotated."""
    data = np.ascontiguousarray(values, dtype=np.int8)
    if data.shape != geometry.shape:
        raise ValueError(f"grid has shape {data.shape}, the map is {geometry.shape}")
    info = {
        "map_load_time": ros_time(ns),
        "resolution": geometry.resolution,
        "width": geometry.width,
        "height": geometry.height,
        "origin": pose(geometry.origin_x, geometry.origin_y),
    }
    return {"header": header(ns), "info": info, "data": data.ravel().tolist()}


def path(ns: int, poses: Sequence[Mapping[str, Any]]) -> Message:
    """A ``nav_msgs/Path`` of ``geometry_msgs/Pose`` dicts (position, orientation), each
    stamped ``ns`` in ``map``; no poses clears the path."""
    stamped = [{"header": header(ns), "pose": p} for p in poses]
    return {"header": header(ns), "poses": stamped}
