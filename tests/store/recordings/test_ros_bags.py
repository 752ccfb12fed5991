"""ROS 1 and ROS 2 bags written by the tests (``recording_helpers``), read back as scans
in the map frame: poses through /tf and /tf_static or a pose topic, the errors a user
meets, REP 117 ranges and the time window."""

import math

import numpy as np
import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st
from recording_helpers import BagSpec, assert_room_map, fused_room, write_bag

from mapserver.core.scan import BEAM_INVALID, BEAM_NO_RETURN, BEAM_RETURN, Pose2D
from mapserver.store.recordings import RecordingError, RecordingOptions, open_recording
from mapserver.store.recordings.scan_build import counter_clockwise
from scenarios.cli.main import main

STORAGES = {"mcap": "bag2", "sqlite3": "bag3", "ros1": "bag1.bag"}


def bag(tmp_path, **spec_fields):
    spec = BagSpec(**spec_fields)
    return write_bag(tmp_path / STORAGES[spec.storage], spec), spec


def assert_true_poses(scans, spec):
    assert len(scans) == spec.scans
    assert [s.stamp for s in scans] == pytest.approx(spec.scan_stamps(), abs=1e-9)
    for scan in scans:
        x, y, yaw = spec.motion.laser_in_map(scan.stamp)
        assert (scan.pose.x, scan.pose.y) == pytest.approx((x, y), abs=1e-9)
        assert math.remainder(scan.pose.yaw - yaw, 2 * math.pi) == pytest.approx(0, abs=1e-9)


@pytest.mark.parametrize("storage", STORAGES)
def test_a_laser_moving_through_map_odom_base_link_reproduces_the_room(tmp_path, storage):
    path, spec = bag(tmp_path, storage=storage)
    recording = open_recording(path)
    assert recording.scan_count() == spec.scans
    assert f"{spec.scans} scans on /scan, poses from /tf + /tf_static" in recording.describe()
    scans = list(recording)
    assert_true_poses(scans, spec)
    assert {s.unit_id for s in scans} == {path.name.removesuffix(".bag")}
    belief, states = fused_room(scans)
    assert_room_map(states, belief.geometry)
    assert [s.stamp for s in recording] == [s.stamp for s in scans]  # read again


def test_bare_mcap_and_db3_files_are_read_without_their_folder(tmp_path):
    for storage, suffix in (("mcap", ".mcap"), ("sqlite3", ".db3")):
        folder, spec = bag(tmp_path, storage=storage)
        (storage_file,) = folder.glob(f"*{suffix}")
        assert_true_poses(list(open_recording(storage_file)), spec)


@pytest.mark.parametrize(
    "kind, std",
    [
        ("nav_msgs/msg/Odometry", (math.sqrt(0.065), 0.1)),
        ("geometry_msgs/msg/PoseWithCovarianceStamped", (math.sqrt(0.065), 0.1)),
        ("geometry_msgs/msg/PoseStamped", None),
    ],
)
def test_poses_from_a_pose_topic_compose_with_the_static_mount(tmp_path, kind, std):
    path, spec = bag(tmp_path, tf=False, pose_topic=("/robot_pose", kind))
    recording = open_recording(path, RecordingOptions(pose_topic="/robot_pose"))
    assert f"poses from /robot_pose ({kind})" in recording.describe()
    scans = list(recording)
    assert_true_poses(scans, spec)
    for scan in scans:
        got = None if scan.pose_std is None else (scan.pose_std.xy, scan.pose_std.yaw)
        assert got == (None if std is None else pytest.approx(std))


def test_a_fixed_sensor_places_every_scan_at_its_pose(tmp_path):
    path, _ = bag(tmp_path, tf=False, static=False)
    scans = list(open_recording(path, RecordingOptions(fixed_sensor=Pose2D(-1.0, 2.0, 0.5))))
    assert {(s.pose.x, s.pose.y, s.pose.yaw) for s in scans} == {(-1.0, 2.0, 0.5)}


def test_a_bag_without_poses_says_how_to_give_them(tmp_path):
    path, _ = bag(tmp_path, tf=False, static=False)
    with pytest.raises(RecordingError) as error:
        open_recording(path)
    assert "no poses: the bag has no /tf or /tf_static" in str(error.value)
    assert "--fixed-sensor X,Y,YAW" in str(error.value) and "--pose-topic" in str(error.value)


def test_no_laserscan_topic_lists_the_topics_and_their_types(tmp_path):
    path, _ = bag(tmp_path, scans=1, scan_topics=())
    with pytest.raises(RecordingError) as error:
        open_recording(path)
    message = str(error.value)
    assert "no sensor_msgs/msg/LaserScan topic; the bag's topics: " in message
    assert "/tf (tf2_msgs/msg/TFMessage)" in message


def test_two_laserscan_topics_ask_for_topic_and_topic_chooses(tmp_path):
    path, spec = bag(tmp_path, storage="ros1", scan_topics=("/front", "/rear"))
    with pytest.raises(RecordingError) as error:
        open_recording(path)
    assert "2 sensor_msgs/msg/LaserScan topics (/front, /rear): choose one with --topic" in str(
        error.value
    )
    assert_true_poses(list(open_recording(path, RecordingOptions(topic="/rear"))), spec)
    with pytest.raises(RecordingError, match="its LaserScan topics: /front, /rear"):
        open_recording(path, RecordingOptions(topic="/side"))


def test_a_missing_link_names_both_frames_and_the_stamp(tmp_path):
    path, spec = bag(tmp_path, static=False)  # nothing joins base_link to laser
    with pytest.raises(RecordingError) as error:
        list(open_recording(path))
    message = str(error.value)
    assert f"none of its {spec.scans} scans could be placed" in message
    stamp = f"{spec.scan_stamps()[0]:.6f}"
    assert f"from frame 'map' to frame 'laser' at stamp {stamp} s" in message
    assert "'laser' is in no transform" in message


def test_a_bag_without_the_fixed_frame_names_its_root_frames(tmp_path):
    path, spec = bag(tmp_path, map_frame="world")
    with pytest.raises(RecordingError) as error:
        list(open_recording(path))
    message = str(error.value)
    assert "the fixed frame 'map' is in no transform" in message
    assert "root frames are: world (choose one with --fixed-frame)" in message
    assert_true_poses(list(open_recording(path, RecordingOptions(fixed_frame="world"))), spec)


def test_rep_117_ranges_are_kept_as_recorded(tmp_path):
    def special(k, ranges):
        out = ranges.copy()
        out[:4] = [math.inf, math.nan, 0.05, 25.0]  # no return, invalid, < min, > max
        return out

    path, _ = bag(tmp_path, scans=3, ranges=special)
    scan = next(iter(open_recording(path)))
    assert scan.ranges[0] == math.inf and math.isnan(scan.ranges[1])
    classes = scan.beam_classes()
    assert list(classes[:5]) == [BEAM_NO_RETURN, BEAM_INVALID, BEAM_INVALID, BEAM_NO_RETURN,
                                 BEAM_RETURN]  # fmt: skip


def test_start_and_end_count_from_the_first_message(tmp_path):
    path, spec = bag(tmp_path)
    # The first message is /tf_static, 0.11 s before the first scan: scans 4 .. 8 lie
    # 0.51 .. 0.91 s after it.
    scans = list(open_recording(path, RecordingOptions(start=0.5, end=1.0)))
    assert [s.stamp for s in scans] == pytest.approx(spec.scan_stamps()[4:9], abs=1e-9)


def test_map_build_of_a_bag_writes_the_room(tmp_path, capsys):
    path, spec = bag(tmp_path, storage="ros1")
    out = tmp_path / "map"
    code = main(["map", "build", str(path), "--out", str(out), "--resolution", "0.1"])
    assert code == 0, capsys.readouterr().err
    assert f"fused {spec.scans} scans" in capsys.readouterr().out
    meta = yaml.safe_load((out / "map.yaml").read_text())
    assert meta["resolution"] == 0.1


@given(
    st.floats(-math.pi, math.pi),
    st.floats(0.001, 0.1) | st.floats(-0.1, -0.001),
    st.lists(st.floats(0.5, 10.0), min_size=1, max_size=40),
    st.booleans(),
)
def test_beams_turned_counter_clockwise_point_where_the_sensor_pointed(
    angle_min, increment, ranges, mirrored
):
    r = np.array(ranges)
    a = angle_min + increment * np.arange(len(r))
    sign = -1.0 if mirrored else 1.0  # upside down, a beam at a points at -a in the map
    expected = sorted(zip((sign * a).round(9), r, strict=True))
    new_min, new_inc, new_r = counter_clockwise(angle_min, increment, r, mirrored)
    assert new_inc > 0
    got = sorted(zip((new_min + new_inc * np.arange(len(r))).round(9), new_r, strict=True))
    assert got == expected
