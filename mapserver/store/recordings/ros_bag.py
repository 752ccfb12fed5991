"""ROS bags (ROS 2: a folder with metadata.yaml, or a bare ``.db3`` / ``.mcap`` file;
ROS 1: ``.bag``) as a recording, through ``rosbags``'s AnyReader (pure Python, no ROS).

What is read (docs/recordings.md "ROS bags"):

- scans: ``sensor_msgs/msg/LaserScan`` on ``options.topic``, or the bag's only LaserScan
  topic; ``header.stamp`` (sec + nanosec) is the scan's stamp [s], ``header.frame_id`` its
  sensor frame. Ranges stay as recorded: ``+inf`` is no return, NaN and values below
  ``range_min`` are dropped, values above ``range_max`` are no return (REP 117).
- poses, one of:

  - ``/tf`` and ``/tf_static`` (``TfPoses``): the chain from ``options.fixed_frame``
    (``map``) through e.g. ``odom`` and ``base_link`` to the scan's frame, each moving
    link interpolated at the scan's stamp (``tf_buffer``);
  - ``options.pose_topic`` (``TopicPoses``): ``nav_msgs/msg/Odometry``,
    ``geometry_msgs/msg/PoseStamped`` or ``PoseWithCovarianceStamped``, the pose of the
    robot (Odometry's ``child_frame_id``; for the others the highest frame the scan's
    frame hangs from in ``/tf_static``, or the laser itself when there is none) in the
    message's ``header.frame_id``, composed with ``/tf_static`` down to the laser;
    a covariance gives the scan's ``pose_std``;
  - ``options.fixed_sensor`` (``FixedPose``): every scan taken there.

The bag is streamed: ``/tf_static`` is read first (a short pass over that topic), then
scans, ``/tf`` and the pose topic together in the bag's time order. A scan may be
recorded before the transform after its stamp; it waits (at most ``WAIT_S`` of the
recording's stamps, at most ``MAX_PENDING`` scans) until transforms bracket its stamp,
then is placed (or, that failing, placed with transforms up to ``TOLERANCE_S`` away, or
skipped). Skipped scans are counted in a warning at the end; when no scan at all could be
placed the reason is a RecordingError naming the frames and a stamp.
"""

from __future__ import annotations

import logging
import math
from collections import Counter, deque
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mapserver.core.scan import MAX_POSE_STD, PoseStd, Scan
from mapserver.store.recordings.base import Recording, RecordingError, RecordingOptions
from mapserver.store.recordings.scan_build import build_scan
from mapserver.store.recordings.stamp_order import StampOrder
from mapserver.store.recordings.tf_buffer import (
    PlanarPose,
    TfBuffer,
    TfLookupError,
    TiltError,
    Transform,
    planar_pose,
    strip_frame,
)

log = logging.getLogger(__name__)

LASER_SCAN = "sensor_msgs/msg/LaserScan"
TF_TYPES = frozenset({"tf2_msgs/msg/TFMessage", "tf/msg/tfMessage"})
POSE_TYPES = frozenset(
    {"nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped",
     "geometry_msgs/msg/PoseWithCovarianceStamped"}
)  # fmt: skip
TF_TOPIC, TF_STATIC_TOPIC = "/tf", "/tf_static"

WAIT_S = 2.0
"""[s] of recording time a scan waits for the transforms after its stamp."""
MAX_PENDING = 2_000
"""Most scans held waiting (a bound on memory whatever the stamps do)."""
TOLERANCE_S = 0.05
"""[s] how far outside a moving link's transforms a scan may be and still be placed
(with the nearest transform), once waiting is over: tf2 allows none, but a bag often
ends (or starts) a few milliseconds past its last (first) transform."""
HISTORY_S = 30.0
"""[s] of transforms kept per moving link."""
READ_AHEAD_S = 5.0
"""[s] of messages read before ``--start`` (transforms to interpolate the first scans)."""


def is_ros2_folder(path: Path) -> bool:
    return path.is_dir() and (path / "metadata.yaml").is_file()


def is_bag_file(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() in (".bag", ".db3", ".mcap")


def seconds(stamp: Any) -> float:
    """A ``builtin_interfaces/Time`` (sec + nanosec) as float seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


def _transform(translation: Any, rotation: Any) -> Transform:
    return Transform(
        (translation.x, translation.y, translation.z),
        (rotation.x, rotation.y, rotation.z, rotation.w),
    )


def pose_std_from_covariance(covariance: np.ndarray) -> PoseStd | None:
    """``pose_std`` from a row-major 6 x 6 pose covariance (x, y, z, roll, pitch, yaw):
    xy = sqrt of the mean of var(x) and var(y) [m], yaw = sqrt(var(yaw)) [rad]; None when
    it is all zero or holds a negative variance (ROS's "unknown")."""
    c = np.asarray(covariance, dtype=np.float64)
    variances = (c[0], c[7], c[35])
    if not all(math.isfinite(v) and v >= 0 for v in variances) or not any(variances):
        return None
    xy = min(math.sqrt((c[0] + c[7]) / 2), MAX_POSE_STD)
    return PoseStd(xy=xy, yaw=min(math.sqrt(c[35]), MAX_POSE_STD))


@dataclass
class Reading:
    """A LaserScan message, waiting for its pose."""

    stamp: float
    frame: str
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: np.ndarray


class TfPoses:
    """Sensor poses from /tf and /tf_static: the chain from ``fixed_frame``."""

    waits = True  # a scan waits for poses stamped after it

    def __init__(self, fixed_frame: str) -> None:
        self.fixed_frame = strip_frame(fixed_frame)
        self.tf = TfBuffer(HISTORY_S)

    def add_static(self, msg: Any) -> None:
        self._add(msg, static=True)

    def add(self, topic: str, msg: Any) -> None:
        self._add(msg, static=False)

    def _add(self, msg: Any, static: bool) -> None:
        for t in msg.transforms:
            transform = _transform(t.transform.translation, t.transform.rotation)
            self.tf.add(t.header.frame_id, t.child_frame_id, seconds(t.header.stamp),
                        transform, static)  # fmt: skip

    def place(self, reading: Reading, tolerance: float) -> tuple[Transform, PoseStd | None]:
        return self.tf.lookup(self.fixed_frame, reading.frame, reading.stamp, tolerance), None

    def hint(self) -> str:
        roots = self.tf.roots()
        if self.fixed_frame in self.tf.frames():
            return ""
        return (
            f"; the fixed frame {self.fixed_frame!r} is in no transform; the bag's root "
            f"frames are: {', '.join(roots) or 'none'} (choose one with --fixed-frame)"
        )


class TopicPoses(TfPoses):
    """Sensor poses from a pose topic, composed with /tf_static down to the laser."""

    POSE_FRAME = "<pose topic>"

    def __init__(self, msgtype: str) -> None:
        super().__init__("map")
        self.msgtype = msgtype
        self.poses = TfBuffer(HISTORY_S)
        self.parent: str | None = None
        self.child: str | None = None
        self.stds: deque[tuple[float, PoseStd | None]] = deque(maxlen=4096)

    def add(self, topic: str, msg: Any) -> None:
        stamp = seconds(msg.header.stamp)
        pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
        self.parent = strip_frame(msg.header.frame_id)
        self.child = strip_frame(getattr(msg, "child_frame_id", "")) or None
        self.poses.add(self.parent, self.POSE_FRAME, stamp,
                       _transform(pose.position, pose.orientation), static=False)  # fmt: skip
        covariance = getattr(msg.pose, "covariance", None)
        std = None if covariance is None else pose_std_from_covariance(covariance)
        self.stds.append((stamp, std))

    def place(self, reading: Reading, tolerance: float) -> tuple[Transform, PoseStd | None]:
        if self.parent is None:
            raise TfLookupError(
                "ahead", "<pose topic>", reading.frame, reading.stamp,
                f"no pose message yet at stamp {reading.stamp:.6f} s",
            )  # fmt: skip
        pose = self.poses.lookup(self.parent, self.POSE_FRAME, reading.stamp, tolerance)
        base = self.child or self.tf.static_root(reading.frame)
        mount = self.tf.lookup(base, reading.frame, reading.stamp)
        return pose.compose(mount), self._std_at(reading.stamp)

    def _std_at(self, stamp: float) -> PoseStd | None:
        """The covariance of the last pose at or before ``stamp`` (the first one before
        any)."""
        chosen = self.stds[0][1] if self.stds else None
        for when, std in self.stds:
            if when > stamp:
                break
            chosen = std
        return chosen

    def hint(self) -> str:
        return ""


class FixedPose(TfPoses):
    """Every scan taken at the one pose the user gave."""

    waits = False

    def __init__(self, x: float, y: float, yaw: float) -> None:
        super().__init__("map")
        self.pose = PlanarPose(x, y, yaw, mirrored=False)

    def place(self, reading: Reading, tolerance: float) -> tuple[PlanarPose, PoseStd | None]:
        return self.pose, None

    def hint(self) -> str:
        return ""


class RosBagRecording(Recording):
    """A ROS 1 or ROS 2 bag's LaserScans placed in the map frame (module docstring).
    Opening reads the bag's index only; errors about topics and poses are raised here."""

    def __init__(self, path: Path, options: RecordingOptions) -> None:
        super().__init__(path, options)
        with self._reader() as reader:
            topics = {name: info.msgtype for name, info in reader.topics.items()}
            counts = {name: info.msgcount for name, info in reader.topics.items()}
            self._span_s = (reader.end_time - reader.start_time) / 1e9
        self.ros1 = self.path.suffix.lower() == ".bag"
        self.scan_topic = self._scan_topic(topics)
        self._scan_total = counts[self.scan_topic]
        self.tf_topics = [t for t in (TF_TOPIC, TF_STATIC_TOPIC) if topics.get(t) in TF_TYPES]
        self.pose_type = self._pose_type(topics)

    # -- opening

    def _reader(self) -> Any:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        store = Stores.ROS1_NOETIC if self.path.suffix.lower() == ".bag" else Stores.ROS2_HUMBLE
        try:
            reader = AnyReader([self.path], default_typestore=get_typestore(store))
            reader.open()
        except Exception as exc:  # rosbags raises its own errors, and KeyError/ValueError
            raise RecordingError(f"{self.path}: not a readable ROS bag: {exc}") from None
        return _Closing(reader)

    def _scan_topic(self, topics: dict[str, str]) -> str:
        scans = sorted(name for name, kind in topics.items() if kind == LASER_SCAN)
        listed = ", ".join(f"{name} ({kind})" for name, kind in sorted(topics.items()))
        if self.options.topic is not None:
            if topics.get(self.options.topic) == LASER_SCAN:
                return self.options.topic
            have = ", ".join(scans) or "none"
            raise RecordingError(
                f"{self.path}: --topic {self.options.topic!r} is not a {LASER_SCAN} topic "
                f"of the bag (its LaserScan topics: {have})"
            )
        if not scans:
            raise RecordingError(
                f"{self.path}: no {LASER_SCAN} topic; the bag's topics: {listed or 'none'}"
            )
        if len(scans) > 1:
            raise RecordingError(
                f"{self.path}: {len(scans)} {LASER_SCAN} topics ({', '.join(scans)}): choose "
                "one with --topic"
            )
        return scans[0]

    def _pose_type(self, topics: dict[str, str]) -> str | None:
        """The pose topic's type (None: poses from /tf or the fixed sensor); raises when
        the bag holds no poses the options can use."""
        candidates = ", ".join(sorted(t for t, k in topics.items() if k in POSE_TYPES)) or "none"
        if self.options.fixed_sensor is not None:
            return None
        if self.options.pose_topic is not None:
            kind = topics.get(self.options.pose_topic)
            if kind not in POSE_TYPES:
                raise RecordingError(
                    f"{self.path}: --pose-topic {self.options.pose_topic!r} is not an "
                    f"Odometry, PoseStamped or PoseWithCovarianceStamped topic of the bag "
                    f"(it is {kind or 'absent'}; the bag's pose topics: {candidates})"
                )
            return kind
        if not self.tf_topics:
            raise RecordingError(
                f"{self.path}: no poses: the bag has no /tf or /tf_static; pass --fixed-sensor "
                "X,Y,YAW (the laser stood still there) or --pose-topic TOPIC (the bag's pose "
                f"topics: {candidates})"
            )
        return None

    def _poses(self) -> TfPoses:
        if self.options.fixed_sensor is not None:
            p = self.options.fixed_sensor
            return FixedPose(p.x, p.y, p.yaw)
        if self.pose_type is not None:
            return TopicPoses(self.pose_type)
        return TfPoses(self.options.fixed_frame)

    # -- reading

    def __iter__(self) -> Iterator[Scan]:
        poses = self._poses()
        placer = _Placer(self, poses)
        with self._reader() as reader:
            t0 = reader.start_time
            by_topic = {c.topic: c for c in reader.connections}
            if TF_STATIC_TOPIC in self.tf_topics and not isinstance(poses, FixedPose):
                static = [c for c in reader.connections if c.topic == TF_STATIC_TOPIC]
                for conn, _, raw in reader.messages(static):
                    poses.add_static(reader.deserialize(raw, conn.msgtype))
            wanted = [self.scan_topic]
            if isinstance(poses, TopicPoses):
                wanted.append(self.options.pose_topic)
            elif not isinstance(poses, FixedPose) and TF_TOPIC in self.tf_topics:
                wanted.append(TF_TOPIC)
            connections = [c for c in reader.connections if c.topic in wanted]
            start = end = None
            if self.options.start is not None:
                start = t0 + int((self.options.start - READ_AHEAD_S) * 1e9)
            if self.options.end is not None:
                end = t0 + int((self.options.end + WAIT_S + READ_AHEAD_S) * 1e9) + 1
            scan_conn = by_topic[self.scan_topic]
            for conn, t_ns, raw in reader.messages(connections, start=start, stop=end):
                msg = reader.deserialize(raw, conn.msgtype)
                if conn.topic == scan_conn.topic:
                    if self.options.within((t_ns - t0) / 1e9):
                        placer.wait(_reading(msg))
                    placer.newest = max(placer.newest, seconds(msg.header.stamp))
                else:
                    poses.add(conn.topic, msg)
                    placer.newest_pose = max(placer.newest_pose, _newest_stamp(msg))
                    placer.newest = max(placer.newest, placer.newest_pose)
                yield from placer.ready()
            yield from placer.finish()

    def scan_count(self) -> int | None:
        return self._scan_total

    def duration(self) -> float | None:
        return self._span_s

    def describe(self) -> str:
        kind = "ROS 1 bag" if self.ros1 else "ROS 2 bag"
        if self.options.fixed_sensor is not None:
            source = f"a fixed sensor at {self.options.fixed_sensor}"
        elif self.pose_type is not None:
            source = f"poses from {self.options.pose_topic} ({self.pose_type})"
        else:
            topics = " + ".join(self.tf_topics)
            source = f"poses from {topics} in frame {self.options.fixed_frame!r}"
        return f"{self.path}: {kind}, {self._scan_total} scans on {self.scan_topic}, {source}"


class _Placer:
    """Scans waiting for their pose, placed in order as the transforms arrive."""

    def __init__(self, recording: RosBagRecording, poses: TfPoses) -> None:
        self.recording = recording
        self.poses = poses
        self.unit_id = recording.unit_id()
        self.pending: deque[Reading] = deque()
        self.newest = -math.inf  # [s] the latest stamp read, of any message
        self.newest_pose = -math.inf  # [s] the latest stamp of a transform or pose read
        self.order: StampOrder[Scan] = StampOrder(WAIT_S)
        self.placed = 0
        self.skipped: Counter[str] = Counter()
        self.first_reason: str | None = None

    def wait(self, reading: Reading) -> None:
        self.pending.append(reading)

    def ready(self) -> Iterator[Scan]:
        while self.pending:
            head = self.pending[0]
            overdue = self.newest - head.stamp > WAIT_S or len(self.pending) > MAX_PENDING
            if not overdue and self.poses.waits and self.newest_pose < head.stamp:
                return  # nothing stamped after it yet: it cannot be placed
            scan = self._place(head, final=overdue)
            if scan is None and not overdue:
                return  # wait for more transforms
            self.pending.popleft()
            if scan is not None:
                yield from self.order.push(scan.stamp, scan)

    def finish(self) -> Iterator[Scan]:
        while self.pending:
            scan = self._place(self.pending.popleft(), final=True)
            if scan is not None:
                yield from self.order.push(scan.stamp, scan)
        yield from self.order.flush()
        self._report()

    def _place(self, reading: Reading, final: bool) -> Scan | None:
        """The scan placed, or None: not yet (``final`` False) or skipped (counted)."""
        try:
            try:
                transform, std = self.poses.place(reading, 0.0)
            except TfLookupError as exc:
                if not final and exc.kind != "behind":
                    return None
                transform, std = self.poses.place(reading, TOLERANCE_S)
            pose = transform if isinstance(transform, PlanarPose) else planar_pose(transform)
        except TfLookupError as exc:
            self.skipped[exc.kind] += 1
            self.first_reason = self.first_reason or str(exc)
            return None
        except TiltError as exc:
            raise RecordingError(
                f"{self.recording.path}: frame {reading.frame!r} at stamp "
                f"{reading.stamp:.6f} s: {exc}"
            ) from None
        self.placed += 1
        return build_scan(
            self.recording.path, self.unit_id, reading.stamp, pose, reading.angle_min,
            reading.angle_increment, reading.range_min, reading.range_max, reading.ranges, std,
        )  # fmt: skip

    def _report(self) -> None:
        skipped = sum(self.skipped.values())
        late = self.order.late
        path = self.recording.path
        if skipped and not self.placed:
            raise RecordingError(
                f"{path}: none of its {skipped} scans could be placed: {self.first_reason}"
                f"{self.poses.hint()}"
            )
        if skipped:
            kinds = ", ".join(f"{n} {kind}" for kind, n in sorted(self.skipped.items()))
            log.warning("%s: skipped %d of %d scans without a pose (%s); the first: %s",
                        path, skipped, skipped + self.placed, kinds, self.first_reason)  # fmt: skip
        if late:
            log.warning("%s: skipped %d scans stamped before a scan already read", path, late)


class _Closing:
    """A context manager closing an opened AnyReader (it was opened to catch errors)."""

    def __init__(self, reader: Any) -> None:
        self.reader = reader

    def __enter__(self) -> Any:
        return self.reader

    def __exit__(self, *exc: object) -> None:
        self.reader.close()


def _reading(msg: Any) -> Reading:
    return Reading(
        stamp=seconds(msg.header.stamp),
        frame=strip_frame(msg.header.frame_id),
        angle_min=float(msg.angle_min),
        angle_increment=float(msg.angle_increment),
        range_min=float(msg.range_min),
        range_max=float(msg.range_max),
        ranges=np.asarray(msg.ranges, dtype=np.float64),
    )


def _newest_stamp(msg: Any) -> float:
    """The latest stamp a /tf or pose message carries [s]."""
    if hasattr(msg, "transforms"):
        return max((seconds(t.header.stamp) for t in msg.transforms), default=-math.inf)
    return seconds(msg.header.stamp)
