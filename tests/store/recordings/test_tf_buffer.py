"""The TF buffer: composing chains, interpolating at a stamp, refusing to extrapolate,
projecting a 3D pose to the plane."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mapserver.store.recordings.tf_buffer import (
    TfBuffer,
    TfLookupError,
    TiltError,
    Transform,
    planar_pose,
    slerp,
)

angles = st.floats(-math.pi, math.pi)
coords = st.floats(-50, 50)


def yaw_of(transform: Transform) -> float:
    return planar_pose(transform).yaw


@given(coords, coords, angles, coords, coords, angles)
def test_composing_planar_transforms_matches_the_planar_formula(x1, y1, a1, x2, y2, a2):
    composed = Transform.planar(x1, y1, a1).compose(Transform.planar(x2, y2, a2))
    pose = planar_pose(composed)
    assert pose.x == pytest.approx(x1 + math.cos(a1) * x2 - math.sin(a1) * y2, abs=1e-9)
    assert pose.y == pytest.approx(y1 + math.sin(a1) * x2 + math.cos(a1) * y2, abs=1e-9)
    assert math.remainder(pose.yaw - (a1 + a2), 2 * math.pi) == pytest.approx(0, abs=1e-9)


@given(coords, coords, angles)
def test_a_transform_composed_with_its_inverse_is_the_identity(x, y, a):
    t = Transform.planar(x, y, a)
    pose = planar_pose(t.compose(t.inverse()))
    assert (pose.x, pose.y, pose.yaw) == pytest.approx((0, 0, 0), abs=1e-9)


def test_a_chain_is_interpolated_exactly_at_the_stamp_between_samples():
    tf = TfBuffer()
    tf.add("map", "odom", 0.0, Transform.planar(1.0, 0.0, 0.0), static=True)
    tf.add("odom", "base_link", 10.0, Transform.planar(0.0, 0.0, 0.0), static=False)
    tf.add("odom", "base_link", 12.0, Transform.planar(4.0, 2.0, 1.0), static=False)
    tf.add("/base_link", "/laser", 0.0, Transform.planar(0.5, 0.0, 0.0), static=True)
    pose = planar_pose(tf.lookup("map", "laser", 10.5))
    # base at (1, 0.5, 0.25) in odom (a quarter of the way), laser 0.5 m ahead of it.
    assert pose.x == pytest.approx(1.0 + 1.0 + 0.5 * math.cos(0.25), abs=1e-12)
    assert pose.y == pytest.approx(0.5 + 0.5 * math.sin(0.25), abs=1e-12)
    assert pose.yaw == pytest.approx(0.25, abs=1e-12)
    assert planar_pose(tf.lookup("map", "laser", 12.0)).yaw == pytest.approx(1.0)


def test_slerp_takes_the_shorter_arc_and_keeps_unit_length():
    a = Transform.planar(0, 0, math.radians(170)).rotation
    b = Transform.planar(0, 0, math.radians(-170)).rotation
    mid = slerp(a, b, 0.5)
    assert np.linalg.norm(mid) == pytest.approx(1.0)
    assert abs(yaw_of(Transform((0, 0, 0), mid))) == pytest.approx(math.pi)


def test_a_stamp_past_the_last_transform_waits_unless_within_the_tolerance():
    tf = TfBuffer()
    tf.add("odom", "base", 1.0, Transform.identity(), static=False)
    tf.add("odom", "base", 2.0, Transform.planar(1, 0, 0), static=False)
    with pytest.raises(TfLookupError) as ahead:
        tf.lookup("odom", "base", 2.01)
    assert ahead.value.kind == "ahead"
    assert "odom -> base" in str(ahead.value) and "2.010000" in str(ahead.value)
    assert planar_pose(tf.lookup("odom", "base", 2.01, tolerance=0.05)).x == 1.0
    with pytest.raises(TfLookupError) as behind:
        tf.lookup("odom", "base", 0.5)
    assert behind.value.kind == "behind"


def test_history_is_bounded_per_edge():
    tf = TfBuffer(history_s=1.0)
    for i in range(100):
        tf.add("odom", "base", i * 0.1, Transform.identity(), static=False)
    with pytest.raises(TfLookupError, match="older than the kept transforms"):
        tf.lookup("odom", "base", 5.0)
    tf.lookup("odom", "base", 9.0)


def test_unconnected_frames_are_named_with_the_root_frames():
    tf = TfBuffer()
    tf.add("odom", "base_link", 0.0, Transform.identity(), static=True)
    with pytest.raises(TfLookupError) as error:
        tf.lookup("map", "base_link", 3.25)
    message = str(error.value)
    assert "from frame 'map' to frame 'base_link' at stamp 3.250000 s" in message
    assert "'map' is in no transform" in message and "the root frames are: odom" in message


def test_an_upside_down_laser_is_mirrored_and_a_tilted_one_refused():
    flipped = Transform((1.0, 2.0, 0.3), (1.0, 0.0, 0.0, 0.0))  # 180 deg about x
    pose = planar_pose(flipped)
    assert pose.mirrored and (pose.x, pose.y, pose.yaw) == pytest.approx((1.0, 2.0, 0.0))
    half = math.radians(30) / 2
    tilted = Transform((0, 0, 0), (math.sin(half), 0.0, 0.0, math.cos(half)))
    with pytest.raises(TiltError, match="tilted 30.0 degrees from level"):
        planar_pose(tilted)
