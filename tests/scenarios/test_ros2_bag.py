"""``fleetmap export ros2``: a run's replay as a rosbag2 MCAP, read back with the ROS 2
reader (``mcap_ros2``'s decoder, which decodes by the bag's schemas) and with ``rosbags``
(by its own ROS 2 Humble types), against what the run recorded (a real ``tiny`` run:
PyBullet, its own map server)."""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap_ros2.decoder import DecoderFactory
from rosbags.interfaces import QosDurability, QosReliability
from rosbags.rosbag2 import Reader as RosbagsReader
from rosbags.typesys import Stores, get_typestore

from mapserver.core.costvalues import COST_TO_OCCUPANCY, FREE, INSCRIBED, LETHAL, UNKNOWN
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Scan
from scenarios.cli.main import main
from scenarios.replay.foxglove_messages import stamp_ns
from scenarios.replay.mcap import REPLAY_FILENAME, write_replay
from scenarios.replay.ros2_bag import ROS2_FILENAME, export_ros2
from scenarios.replay.ros2_msgdefs import SEPARATOR, full_text
from scenarios.run import runner
from scenarios.run.record import GridSample, PlanSample, RunRecord, ScanSample
from scenarios.spec.scenario import load_scenario

TINY = "scenarios/tiny.yaml"
TYPES = {
    "/u1/scan": "sensor_msgs/msg/LaserScan",
    "/u2/scan": "sensor_msgs/msg/LaserScan",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/u1/plan": "nav_msgs/msg/Path",
    "/u2/plan": "nav_msgs/msg/Path",
    "/map": "nav_msgs/msg/OccupancyGrid",
    "/costmap": "nav_msgs/msg/OccupancyGrid",
}
f32 = np.float32


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """(the run's record, its fused scans in seq order, its run folder, the bag, the
    counts export_ros2 returned)."""
    base = tmp_path_factory.mktemp("tiny")
    record = runner.run(load_scenario(TINY), data_dir=base / "data")
    run_dir = base / "run"
    run_dir.mkdir()
    write_replay(record, run_dir / REPLAY_FILENAME)
    fused = [scan for _, scan in record.fused.scans()]
    bag = run_dir / ROS2_FILENAME
    counts = export_ros2(run_dir / REPLAY_FILENAME, bag)
    return record, fused, run_dir, bag, counts


@dataclass(frozen=True)
class Read:
    """One message as the ROS 2 reader gives it: its channel, record and decoded message."""

    channel: Channel
    message: Message
    ros_msg: Any


def read_ros2_messages(bag: Path, topics: list[str] | None = None) -> list[Read]:
    """The bag's messages in log time order, decoded by ``mcap_ros2`` (what
    ``mcap_ros2.reader.read_ros2_messages``, now deprecated, does)."""
    with open(bag, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [
            Read(channel, message, ros_msg)
            for _, channel, message, ros_msg in reader.iter_decoded_messages(topics)
        ]


def messages(bag: Path, topic: str) -> list[Read]:
    return read_ros2_messages(bag, topics=[topic])


def stamp_of(ros_time) -> int:
    return ros_time.sec * 1_000_000_000 + ros_time.nanosec


# ------------------------------------------------------------------------------ the file
def test_the_bag_has_the_ros2_profile_ros2msg_schemas_and_cdr_channels(tiny):
    *_, bag, _ = tiny
    with open(bag, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
    schemas = summary.schemas
    assert {s.encoding for s in schemas.values()} == {"ros2msg"}
    for schema in schemas.values():
        assert schema.data.decode() == full_text(schema.name)
    channels = {c.topic: c for c in summary.channels.values()}
    assert {t: schemas[c.schema_id].name for t, c in channels.items()} == TYPES
    assert {c.message_encoding for c in channels.values()} == {"cdr"}
    for topic, channel in channels.items():
        (qos,) = yaml.safe_load(channel.metadata["offered_qos_profiles"])
        latched = topic in ("/map", "/costmap")
        assert (qos["reliability"], qos["durability"]) == (1, 1 if latched else 2), topic
        assert qos["depth"] == (1 if latched else 100 if topic == "/tf" else 10)


def test_the_counts_are_what_the_run_recorded(tiny):
    record, fused, _, bag, counts = tiny
    read = Counter(m.channel.topic for m in read_ros2_messages(bag))
    assert read == counts
    per_unit = Counter(scan.unit_id for scan in fused)
    plans = Counter(plan.unit_id for plan in record.plans)
    assert len(fused) == record.metrics["scans_fused"] == 400
    assert counts == {
        "/u1/scan": per_unit["u1"],
        "/u2/scan": per_unit["u2"],
        "/tf": len(fused),
        "/u1/plan": plans["u1"],
        "/u2/plan": plans["u2"],
        "/map": len(record.grids),
        "/costmap": len(record.grids),
    }
    assert min(counts.values()) >= 4


# ------------------------------------------------------------------------------ scans, tf
def _by_unit(scans: list[Scan]) -> dict[str, list[Scan]]:
    out: dict[str, list[Scan]] = defaultdict(list)
    for scan in sorted(scans, key=lambda s: s.stamp):
        out[scan.unit_id].append(scan)
    return out


def test_each_laser_scan_is_a_fused_scan_in_its_units_base_link(tiny):
    _, fused, _, bag, _ = tiny
    for unit, scans in _by_unit(fused).items():
        read = messages(bag, f"/{unit}/scan")
        assert len(read) == len(scans)
        for m, scan in zip(read, scans, strict=True):
            msg, ns = m.ros_msg, stamp_ns(scan.stamp)
            assert m.message.log_time == m.message.publish_time == stamp_of(msg.header.stamp) == ns
            assert msg.header.frame_id == f"{unit}/base_link"
            n = scan.beam_count
            assert (msg.angle_min, msg.angle_increment) == (
                f32(scan.angle_min),
                f32(scan.angle_increment),
            )
            assert msg.angle_max == f32(scan.angle_min + (n - 1) * scan.angle_increment)
            assert (msg.range_min, msg.range_max) == (f32(scan.range_min), f32(scan.range_max))
            np.testing.assert_array_equal(np.array(msg.ranges, f32), scan.ranges.astype(f32))
            assert msg.intensities == []


def test_each_transform_is_the_pose_its_scan_was_fused_at(tiny):
    _, fused, _, bag, _ = tiny
    read = messages(bag, "/tf")
    order = sorted(fused, key=lambda s: (stamp_ns(s.stamp), s.unit_id))
    transforms = sorted(
        (t for m in read for t in m.ros_msg.transforms),
        key=lambda t: (stamp_of(t.header.stamp), t.child_frame_id),
    )
    assert len(transforms) == len(order) == 400
    for t, scan in zip(transforms, order, strict=True):
        assert stamp_of(t.header.stamp) == stamp_ns(scan.stamp)
        assert (t.header.frame_id, t.child_frame_id) == ("map", f"{scan.unit_id}/base_link")
        move, turn = t.transform.translation, t.transform.rotation
        assert (move.x, move.y, move.z) == (scan.pose.x, scan.pose.y, 0.0)
        half = scan.pose.yaw / 2
        assert (turn.x, turn.y, turn.z, turn.w) == (0.0, 0.0, math.sin(half), math.cos(half))


# ------------------------------------------------------------------------------ grids
def _grid_info_is_the_map(msg, geometry: GridGeometry, stamp: float) -> None:
    info = msg.info
    assert stamp_of(msg.header.stamp) == stamp_of(info.map_load_time) == stamp_ns(stamp)
    assert msg.header.frame_id == "map"
    assert (info.resolution, info.width, info.height) == (
        f32(geometry.resolution),
        geometry.width,
        geometry.height,
    )
    o = info.origin
    assert (o.position.x, o.position.y, o.position.z) == (geometry.origin_x, geometry.origin_y, 0)
    assert (o.orientation.x, o.orientation.y, o.orientation.z, o.orientation.w) == (0, 0, 0, 1)


def test_map_is_the_recorded_occupancy_grid(tiny):
    record, _, _, bag, _ = tiny
    read = messages(bag, "/map")
    assert len(read) == len(record.grids)
    for m, sample in zip(read, sorted(record.grids, key=lambda g: g.stamp), strict=True):
        _grid_info_is_the_map(m.ros_msg, record.geometry, sample.stamp)
        data = np.array(m.ros_msg.data, dtype=np.int8).reshape(record.geometry.shape)
        np.testing.assert_array_equal(data, sample.occupancy)
    last = data
    assert np.count_nonzero(last == -1) > 0  # unknown stays -1, never free
    assert np.count_nonzero((last >= 0) & (last <= 25)) > 1000  # free
    assert np.count_nonzero(last >= 65) > 50  # occupied


def test_costmap_is_the_costvalues_table_applied_to_the_recorded_costmap(tiny):
    record, _, _, bag, _ = tiny
    read = messages(bag, "/costmap")
    assert len(read) == len(record.grids)
    for m, sample in zip(read, sorted(record.grids, key=lambda g: g.stamp), strict=True):
        _grid_info_is_the_map(m.ros_msg, record.geometry, sample.stamp)
        data = np.array(m.ros_msg.data, dtype=np.int8).reshape(record.geometry.shape)
        np.testing.assert_array_equal(data, COST_TO_OCCUPANCY[sample.costs])
    costs = sample.costs
    # Nav2's translation, literally: free 0, inscribed 99, lethal 100, unknown -1, graded 1..98
    for cost, value in ((FREE, 0), (INSCRIBED, 99), (LETHAL, 100), (UNKNOWN, -1)):
        assert np.count_nonzero(costs == cost) > 0
        assert set(data[costs == cost].tolist()) == {value}
    graded = (costs > FREE) & (costs < INSCRIBED)
    assert np.count_nonzero(graded) > 0
    assert data[graded].min() >= 1 and data[graded].max() <= 98


# ------------------------------------------------------------------------------ plans
def _heading_quaternion(points, i):
    if len(points) == 1:
        yaw = 0.0
    else:
        (x0, y0), (x1, y1) = points[i : i + 2] if i + 1 < len(points) else points[i - 1 : i + 1]
        yaw = math.atan2(y1 - y0, x1 - x0)
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


def test_each_path_is_the_plan_the_unit_made(tiny):
    record, *_, bag, _ = tiny
    for unit in ("u1", "u2"):
        plans = sorted((p for p in record.plans if p.unit_id == unit), key=lambda p: p.stamp)
        read = messages(bag, f"/{unit}/plan")
        assert len(read) == len(plans)
        for m, plan in zip(read, plans, strict=True):
            msg = m.ros_msg
            assert stamp_of(msg.header.stamp) == stamp_ns(plan.stamp)
            assert msg.header.frame_id == "map"
            points = [(p.pose.position.x, p.pose.position.y) for p in msg.poses]
            assert points == [(float(x), float(y)) for x, y in plan.path]
            for i, p in enumerate(msg.poses):
                assert p.header.frame_id == "map" and p.header.stamp == msg.header.stamp
                q = p.pose.orientation
                assert (q.x, q.y, q.z, q.w) == _heading_quaternion(plan.path, i)
    assert sum(len(p.path) > 1 for p in record.plans) > 10


# ------------------------------------------------------------------------------ rosbags
def test_rosbags_reads_the_bag_with_its_own_ros2_types(tiny):
    _, fused, _, bag, counts = tiny
    typestore = get_typestore(Stores.ROS2_HUMBLE)  # Humble's definitions, not the bag's
    with RosbagsReader(bag) as reader:
        connections = {c.topic: c for c in reader.connections}
        assert {t: c.msgtype for t, c in connections.items()} == TYPES
        assert {t: c.msgcount for t, c in connections.items()} == counts
        assert reader.message_count == sum(counts.values())
        assert reader.start_time == stamp_ns(min(s.stamp for s in fused))
        qos = connections["/map"].ext.offered_qos_profiles[0]
        assert (qos.reliability, qos.durability) == (
            QosReliability.RELIABLE,
            QosDurability.TRANSIENT_LOCAL,
        )
        decoded = Counter()
        for connection, timestamp, raw in reader.messages():
            msg = typestore.deserialize_cdr(raw, connection.msgtype)
            decoded[connection.topic] += 1
            if connection.topic == "/u1/scan" and decoded["/u1/scan"] == 1:
                first = min((s for s in fused if s.unit_id == "u1"), key=lambda s: s.stamp)
                assert timestamp == stamp_ns(first.stamp)
                np.testing.assert_array_equal(msg.ranges, first.ranges.astype(f32))
                assert msg.header.frame_id == "u1/base_link"
    assert decoded == counts


# ------------------------------------------------------------------------------ without fused scans
def test_a_replay_without_fused_scans_exports_its_sampled_laser_scans(tmp_path):
    geometry = GridGeometry(width=4, height=3, resolution=0.5, origin_x=-1.0, origin_y=2.0)
    record = RunRecord("hand", "decay", 0, geometry)  # as a run against an outside server
    ranges = np.array([1.25, math.inf, math.nan, -math.inf, 19.5], dtype=np.float32)
    record.scans += [
        ScanSample(0.5, "a", 1.0, 2.0, 3.0, -1.0, 0.25, 0.1, 20.0, ranges),
        ScanSample(1.0, "a", 1.5, 2.0, -3.0, -1.0, 0.25, 0.1, 20.0, ranges[::-1].copy()),
    ]
    costs = np.array([[0, 1, 252, 253], [254, 255, 128, 0], [0, 0, 0, 0]], dtype=np.uint8)
    occupancy = np.array([[-1, 0, 100, 50], [-1, -1, 3, 0], [0, 0, 0, 0]], dtype=np.int8)
    record.grids.append(GridSample(0.75, 1, costs, occupancy))
    record.plans += [PlanSample(0.5, "a", ((1.0, 2.0),)), PlanSample(1.0, "a", ())]
    write_replay(record, tmp_path / REPLAY_FILENAME)
    counts = export_ros2(tmp_path / REPLAY_FILENAME, tmp_path / "bag.mcap")
    assert counts == {"/a/scan": 2, "/tf": 2, "/a/plan": 2, "/map": 1, "/costmap": 1}
    scans = messages(tmp_path / "bag.mcap", "/a/scan")
    np.testing.assert_array_equal(
        scans[0].ros_msg.ranges, [1.25, math.inf, math.nan, math.nan, 19.5]
    )  # the replay's LaserScans keep no-return (+inf) and invalid (NaN; -inf reads as NaN)
    (tf,) = messages(tmp_path / "bag.mcap", "/tf")[1].ros_msg.transforms
    assert (tf.transform.translation.x, tf.transform.translation.y) == (1.5, 2.0)
    assert math.isclose(2 * math.atan2(tf.transform.rotation.z, tf.transform.rotation.w), -3.0)
    (costmap,) = messages(tmp_path / "bag.mcap", "/costmap")
    assert list(costmap.ros_msg.data) == [0, 1, 98, 99, 100, -1, 50, 0, 0, 0, 0, 0]
    (grid,) = messages(tmp_path / "bag.mcap", "/map")
    assert list(grid.ros_msg.data) == occupancy.ravel().tolist()
    assert (grid.ros_msg.info.width, grid.ros_msg.info.height) == (4, 3)
    plans = messages(tmp_path / "bag.mcap", "/a/plan")
    assert [len(p.ros_msg.poses) for p in plans] == [1, 0]  # an empty plan clears the path


# ------------------------------------------------------------------------------ definitions
def test_a_full_text_lists_each_dependency_once_after_a_separator():
    text = full_text("nav_msgs/msg/OccupancyGrid")
    assert text.startswith("std_msgs/Header header\nnav_msgs/MapMetaData info\nint8[] data\n")
    sections = text.split(f"\n{SEPARATOR}\n")
    names = [s.splitlines()[0] for s in sections[1:]]
    assert names == [
        "MSG: nav_msgs/MapMetaData",
        "MSG: builtin_interfaces/Time",
        "MSG: geometry_msgs/Pose",
        "MSG: geometry_msgs/Point",
        "MSG: geometry_msgs/Quaternion",
        "MSG: std_msgs/Header",
    ]
    assert full_text("nav_msgs/OccupancyGrid") == text


def test_a_type_without_a_definition_is_refused_by_name():
    with pytest.raises(ValueError, match="'sensor_msgs/Image'"):
        full_text("sensor_msgs/msg/Image")
    with pytest.raises(ValueError, match="got 'LaserScan'"):
        full_text("LaserScan")


# ------------------------------------------------------------------------------ the command
def test_the_command_writes_the_bag_beside_the_run_and_says_what_it_holds(tiny, capsys):
    *_, run_dir, bag, counts = tiny
    before = bag.read_bytes()
    bag.unlink()
    assert main(["export", "ros2", str(run_dir)]) == 0
    out = capsys.readouterr().out.strip()
    topics = ", ".join(f"{t} {n}" for t, n in sorted(counts.items()))
    assert out == f"wrote {bag}: {sum(counts.values())} messages on 7 topics: {topics}"
    assert bag.read_bytes() == before  # the same run gives the same bag, byte for byte


@pytest.mark.parametrize(
    ("where", "says"),
    [
        ("missing", "RUN_DIR '{run}' is not a run folder (no such file or folder)"),
        ("empty", "RUN_DIR '{run}' is not a run folder (no replay.mcap)"),
        ("garbage", "{run}/replay.mcap: not a readable fleetmap replay"),
        ("truncated", "{run}/replay.mcap: not a readable fleetmap replay"),
        ("no_parent", "--out '{out}': cannot write (No such file or directory)"),
        ("onto_replay", "--out '{out}' is the run's replay itself; name another file"),
    ],
)
def test_bad_run_folders_and_outputs_are_one_line_errors(tiny, tmp_path, capsys, where, says):
    run, out = tmp_path / "run", tmp_path / "bag.mcap"
    if where != "missing":
        run.mkdir()
    if where == "garbage":
        (run / REPLAY_FILENAME).write_bytes(b"not an mcap file")
    if where == "truncated":  # a run cut off while its replay was written
        whole = (tiny[2] / REPLAY_FILENAME).read_bytes()
        (run / REPLAY_FILENAME).write_bytes(whole[: len(whole) // 2])
    if where in ("no_parent", "onto_replay"):
        run = tiny[2]
        out = tmp_path / "nowhere" / "bag.mcap" if where == "no_parent" else run / REPLAY_FILENAME
    before = sorted(p.name for p in tmp_path.rglob("*"))
    assert main(["export", "ros2", str(run), "--out", str(out)]) == 2
    captured = capsys.readouterr()
    (line,) = captured.err.splitlines()
    assert line.startswith("fleetmap export: error: " + says.format(run=run, out=out))
    assert captured.out == ""
    assert sorted(p.name for p in tmp_path.rglob("*")) == before  # nothing written
