"""Recordings with known geometry, written by the tests: ROS 2 bags (MCAP, sqlite3), ROS 1
bags (both through ``rosbags``' writers) and CARMEN logs, of a laser moving in a
rectangular room whose walls are the lines x = 0, x = ROOM_W, y = 0, y = ROOM_H [m].

The laser's true pose at any stamp is ``Motion.laser_in_map(t)``: the base moves at
constant velocity in ``odom`` (so interpolating /tf between samples is exact), ``odom``
sits at a fixed pose in ``map``, the laser at a fixed mount on the base. Ranges are exact
distances to the walls (``room_ranges``).
"""

from __future__ import annotations

import gzip
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mapserver.core.belief import BeliefGrid, CellState
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Scan

ROOM_W, ROOM_H = 8.0, 6.0  # [m]
T0 = 1_700_000_000.25  # [s] the first scan's stamp (epoch, as a real robot stamps)
BEAMS = 360
ANGLE_MIN = -math.pi
ANGLE_INCREMENT = 2 * math.pi / BEAMS


def compose(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple:
    """Planar pose b (in a's frame) expressed in a's parent: (x, y, yaw)."""
    ax, ay, ayaw = a
    bx, by, byaw = b
    c, s = math.cos(ayaw), math.sin(ayaw)
    return (ax + c * bx - s * by, ay + s * bx + c * by, ayaw + byaw)


@dataclass(frozen=True)
class Motion:
    """map -> odom fixed, odom -> base_link at constant velocity from ``t0``, base_link ->
    laser fixed (``mount``)."""

    map_odom: tuple[float, float, float] = (0.5, -0.25, 0.1)
    start: tuple[float, float, float] = (1.5, 2.0, 0.0)
    velocity: tuple[float, float, float] = (0.5, 0.2, 0.4)  # [m/s, m/s, rad/s]
    mount: tuple[float, float, float] = (0.2, 0.05, 0.0)
    t0: float = T0

    def base_in_odom(self, t: float) -> tuple[float, float, float]:
        dt = t - self.t0
        return tuple(p + v * dt for p, v in zip(self.start, self.velocity, strict=True))

    def base_in_map(self, t: float) -> tuple[float, float, float]:
        return compose(self.map_odom, self.base_in_odom(t))

    def laser_in_map(self, t: float) -> tuple[float, float, float]:
        return compose(self.base_in_map(t), self.mount)


def room_ranges(pose: tuple[float, float, float], angles: np.ndarray) -> np.ndarray:
    """Exact distances [m] from ``pose`` along beams at ``angles`` (sensor frame) to the
    room's walls."""
    x, y, yaw = pose
    a = yaw + angles
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(c > 1e-12, (ROOM_W - x) / c, np.where(c < -1e-12, -x / c, np.inf))
        ty = np.where(s > 1e-12, (ROOM_H - y) / s, np.where(s < -1e-12, -y / s, np.inf))
    return np.minimum(tx, ty)


def beam_angles(count: int = BEAMS, angle_min: float = ANGLE_MIN, step: float = ANGLE_INCREMENT):
    return angle_min + step * np.arange(count)


# ------------------------------------------------------------------------------ bags


@dataclass
class BagSpec:
    """What ``write_bag`` writes. ``storage``: ``mcap`` or ``sqlite3`` (ROS 2), ``ros1``.

    - ``scans`` LaserScans 0.1 s apart from ``motion.t0`` on each of ``scan_topics`` in
      frame ``laser_frame``; ``ranges`` overrides the exact ranges (a function of the
      scan's index and its exact ranges);
    - ``tf``: odom -> base_link at 20 Hz (samples between the scans) and map -> odom at
      2 Hz on /tf, from 0.1 s before the first scan to 0.1 s after the last;
      ``static``: base_link -> laser on /tf_static; ``map_frame``: the name of ``map``;
    - ``pose_topic``: (topic, type) of the base's pose in ``map`` at 20 Hz, with
      ``covariance`` (var x, var y, var yaw) for the types that carry one;
    - ``extra``: more (topic, type) connections, no messages.
    """

    storage: str = "mcap"
    scans: int = 20
    scan_topics: Sequence[str] = ("/scan",)
    laser_frame: str = "laser"
    tf: bool = True
    static: bool = True
    map_frame: str = "map"
    pose_topic: tuple[str, str] | None = None
    covariance: tuple[float, float, float] = (0.04, 0.09, 0.01)
    extra: Sequence[tuple[str, str]] = ()
    motion: Motion = field(default_factory=Motion)
    ranges: Callable[[int, np.ndarray], np.ndarray] | None = None

    def scan_stamps(self) -> list[float]:
        return [self.motion.t0 + 0.1 * k for k in range(self.scans)]


class _Messages:
    """Messages of one typestore (ROS 1 headers carry a ``seq``)."""

    def __init__(self, ros1: bool) -> None:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        self.ros1 = ros1
        self.store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
        if "tf2_msgs/msg/TFMessage" not in self.store.types:
            self.store.register(
                get_types_from_msg(
                    "geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"
                )  # fmt: skip
            )
        self.t = self.store.types

    def serialize(self, msg) -> bytes:
        if self.ros1:
            return self.store.serialize_ros1(msg, msg.__msgtype__)
        return self.store.serialize_cdr(msg, msg.__msgtype__)

    def header(self, stamp: float, frame: str):
        sec = math.floor(stamp)
        time = self.t["builtin_interfaces/msg/Time"](sec=sec, nanosec=round((stamp - sec) * 1e9))
        if self.ros1:
            return self.t["std_msgs/msg/Header"](seq=0, stamp=time, frame_id=frame)
        return self.t["std_msgs/msg/Header"](stamp=time, frame_id=frame)

    def pose_parts(self, pose: tuple[float, float, float]):
        x, y, yaw = pose
        q = self.t["geometry_msgs/msg/Quaternion"](
            x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)
        )
        return x, y, q

    def transform(self, stamp: float, parent: str, child: str, pose: tuple[float, float, float]):
        x, y, q = self.pose_parts(pose)
        v = self.t["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.0)
        return self.t["geometry_msgs/msg/TransformStamped"](
            header=self.header(stamp, parent), child_frame_id=child,
            transform=self.t["geometry_msgs/msg/Transform"](translation=v, rotation=q),
        )  # fmt: skip

    def tf(self, transforms: list):
        return self.t["tf2_msgs/msg/TFMessage"](transforms=transforms)

    def scan(self, stamp: float, frame: str, ranges: np.ndarray, range_max: float = 20.0):
        return self.t["sensor_msgs/msg/LaserScan"](
            header=self.header(stamp, frame), angle_min=ANGLE_MIN,
            angle_max=ANGLE_MIN + (BEAMS - 1) * ANGLE_INCREMENT, angle_increment=ANGLE_INCREMENT,
            time_increment=0.0, scan_time=0.1, range_min=0.1, range_max=range_max,
            ranges=np.asarray(ranges, dtype=np.float32), intensities=np.zeros(0, np.float32),
        )  # fmt: skip

    def pose_message(self, kind: str, stamp: float, pose, child: str, covariance) -> object:
        x, y, q = self.pose_parts(pose)
        p = self.t["geometry_msgs/msg/Pose"](
            position=self.t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0), orientation=q
        )
        cov = np.zeros(36)
        cov[0], cov[7], cov[35] = covariance
        with_cov = self.t["geometry_msgs/msg/PoseWithCovariance"](pose=p, covariance=cov)
        header = self.header(stamp, "map")
        if kind == "geometry_msgs/msg/PoseStamped":
            return self.t[kind](header=header, pose=p)
        if kind == "geometry_msgs/msg/PoseWithCovarianceStamped":
            return self.t[kind](header=header, pose=with_cov)
        twist = self.t["geometry_msgs/msg/TwistWithCovariance"](
            twist=self.t["geometry_msgs/msg/Twist"](
                linear=self.t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                angular=self.t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
            ),
            covariance=np.zeros(36),
        )
        return self.t[kind](header=header, child_frame_id=child, pose=with_cov, twist=twist)


def bag_messages(spec: BagSpec, m: _Messages) -> list[tuple[str, float, object]]:
    """(topic, log time [s], message) of the bag, in log-time order; each message is
    logged at its stamp (a scan thus before the /tf sample after it)."""
    motion = spec.motion
    stamps = spec.scan_stamps()
    out: list[tuple[str, float, object]] = []
    angles = beam_angles()
    for k, t in enumerate(stamps):
        ranges = room_ranges(motion.laser_in_map(t), angles)
        if spec.ranges is not None:
            ranges = spec.ranges(k, ranges)
        for topic in spec.scan_topics:
            out.append((topic, t, m.scan(t, spec.laser_frame, ranges)))
    begin, end = stamps[0] - 0.1, stamps[-1] + 0.1
    samples = np.arange(begin + 0.025, end + 0.05, 0.05)
    if spec.tf:
        for t in samples:
            base = m.transform(t, "odom", "base_link", motion.base_in_odom(t))
            out.append(("/tf", t, m.tf([base])))
        for t in np.arange(begin, end + 0.5, 0.5):
            out.append(("/tf", t, m.tf([m.transform(t, spec.map_frame, "odom", motion.map_odom)])))
    if spec.static:
        mount = m.transform(begin, "base_link", spec.laser_frame, motion.mount)
        out.append(("/tf_static", begin - 0.01, m.tf([mount])))
    if spec.pose_topic is not None:
        topic, kind = spec.pose_topic
        for t in samples:
            pose = motion.base_in_map(t)
            out.append((topic, t, m.pose_message(kind, t, pose, "base_link", spec.covariance)))
    out.sort(key=lambda item: item[1])
    return out


def write_bag(path: Path, spec: BagSpec | None = None) -> Path:
    """Write the bag ``spec`` describes at ``path`` (a folder for ROS 2, a ``.bag`` file
    for ROS 1); returns ``path``."""
    spec = spec or BagSpec()
    m = _Messages(ros1=spec.storage == "ros1")
    messages = bag_messages(spec, m)
    types = {topic: msg.__msgtype__ for topic, _, msg in messages}
    types.update(dict(spec.extra))
    for topic in spec.scan_topics:
        types.setdefault(topic, "sensor_msgs/msg/LaserScan")
    if spec.storage == "ros1":
        from rosbags.rosbag1 import Writer as Writer1

        writer = Writer1(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if spec.storage == "mcap" else StoragePlugin.SQLITE3
        writer = Writer(path, version=9, storage_plugin=plugin)
    with writer:
        connections = {
            topic: writer.add_connection(topic, kind, typestore=m.store)
            for topic, kind in sorted(types.items())
        }
        for topic, t, msg in messages:
            writer.write(connections[topic], round(t * 1e9), m.serialize(msg))
    return path


# ---------------------------------------------------------------------------- CARMEN


def carmen_lines(kind: str = "FLASER", scans: int = 12, motion: Motion | None = None) -> list[str]:
    """A CARMEN log's lines (with PARAM and ODOM lines to skip) of a laser moving
    in the room: FLASER with 181 beams (CARMEN: -90 .. +90 deg, 1 deg apart) or
    ROBOTLASER1 with 361 beams over 360 deg from -pi; ``0.0`` beams are invalid and
    the laser's pose fields carry the true pose (the odometry fields are wrong on purpose)."""
    motion = motion or Motion()
    lines = ["# CARMEN logfile", "PARAM robot_frontlaser_offset 0.0 nohost 0"]
    for k in range(scans):
        t = motion.t0 + 0.5 * k
        pose = motion.laser_in_map(t)
        lines.append(f"ODOM 9 9 9 0 0 0 {t:.6f} host {t:.6f}")
        if kind == "FLASER":
            ranges = room_ranges(pose, beam_angles(181, -math.pi / 2, math.pi / 180))
            body = " ".join(f"{r:.6f}" for r in ranges)
            wrong_odometry = "7 7 0"
            lines.append(
                f"FLASER 181 {body} {pose[0]:.9f} {pose[1]:.9f} {pose[2]:.9f} "
                f"{wrong_odometry} {t:.6f} host {t:.6f}"
            )
        else:
            ranges = room_ranges(pose, beam_angles(361, -math.pi, math.pi / 180))
            body = " ".join(f"{r:.6f}" for r in ranges)
            lines.append(
                f"ROBOTLASER1 0 {-math.pi:.12f} {2 * math.pi:.12f} {math.pi / 180:.12f} 30.0 "
                f"0.01 0 361 {body} 2 5 5 {pose[0]:.9f} {pose[1]:.9f} {pose[2]:.9f} "
                f"7 7 0 0 0 0 0 0 {t:.6f} host {t:.6f}"
            )
    return lines


def write_carmen(path: Path, lines: list[str]) -> Path:
    """Write ``lines`` as a log, gzipped when ``path`` ends in ``.gz``."""
    text = "\n".join(lines) + "\n"
    if path.suffix == ".gz":
        path.write_bytes(gzip.compress(text.encode()))
    else:
        path.write_text(text)
    return path


# ------------------------------------------------------------------------------ maps


def room_grid(resolution: float = 0.1, margin: float = 1.0) -> GridGeometry:
    cells_w = round((ROOM_W + 2 * margin) / resolution)
    cells_h = round((ROOM_H + 2 * margin) / resolution)
    return GridGeometry(cells_w, cells_h, resolution, -margin, -margin)


def fused_room(scans: Sequence[Scan], resolution: float = 0.1) -> tuple[BeliefGrid, np.ndarray]:
    """The room's belief after ``scans`` (binary policy: no fading) and its states
    (height, width)."""
    belief = BeliefGrid(room_grid(resolution), policy="binary")
    for scan in scans:
        belief.fuse(scan)
    return belief, belief.states_at().reshape(belief.geometry.shape)


def wall_distance(geometry: GridGeometry) -> np.ndarray:
    """Each cell centre's distance [m] to the nearest wall line (height, width)."""
    cols, rows = np.meshgrid(np.arange(geometry.width), np.arange(geometry.height))
    x = geometry.origin_x + (cols + 0.5) * geometry.resolution
    y = geometry.origin_y + (rows + 0.5) * geometry.resolution
    inside = (x >= 0) & (x <= ROOM_W) & (y >= 0) & (y <= ROOM_H)
    d = np.minimum.reduce([np.abs(x), np.abs(x - ROOM_W), np.abs(y), np.abs(y - ROOM_H)])
    return np.where(inside, d, -d)


def assert_room_map(states: np.ndarray, geometry: GridGeometry, walls_seen: float = 0.9) -> None:
    """The map of the room: every occupied cell within one cell's diagonal of a wall,
    the cells more than two cells inside the walls free (at least 95 %, none occupied),
    nothing beyond the walls known, and at least ``walls_seen`` of each wall's length
    held occupied (cells along the wall with an occupied cell beside the line)."""
    d = wall_distance(geometry)
    near = geometry.resolution * math.sqrt(2)
    occupied = states == CellState.OCCUPIED
    assert occupied.any()
    assert np.all(np.abs(d[occupied]) <= near), "an occupied cell off the walls"
    interior = d > 2 * geometry.resolution
    assert not occupied[interior].any()
    assert (states[interior] == CellState.FREE).mean() >= 0.95
    assert np.all(states[d < -near] == CellState.UNKNOWN), "a cell beyond the walls known"
    if walls_seen:
        band = occupied & (np.abs(d) <= near)
        res, ox, oy = geometry.resolution, geometry.origin_x, geometry.origin_y
        x0, x1 = round(-ox / res), round((ROOM_W - ox) / res)  # wall columns
        y0, y1 = round(-oy / res), round((ROOM_H - oy) / res)  # wall rows
        for name, line in (
            ("x = 0", band[y0 + 2 : y1 - 2, x0 - 2 : x0 + 2].any(axis=1)),
            ("x = W", band[y0 + 2 : y1 - 2, x1 - 2 : x1 + 2].any(axis=1)),
            ("y = 0", band[y0 - 2 : y0 + 2, x0 + 2 : x1 - 2].any(axis=0)),
            ("y = H", band[y1 - 2 : y1 + 2, x0 + 2 : x1 - 2].any(axis=0)),
        ):
            assert line.mean() >= walls_seen, f"wall {name}: {line.mean():.2f} seen occupied"
