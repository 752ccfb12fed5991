"""The kinematic drive unit: follows paths within its limits, halts on demand."""

import math

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from fleet.unit import (
    CORNER_ERROR_M,
    WAYPOINT_TOLERANCE_M,
    DriveLimits,
    DriveUnit,
    stopping_speed,
)
from mapserver.core.scan import Pose2D

LIMITS = DriveLimits(max_speed=1.5, max_accel=1.0, max_turn_rate=1.5)


def drive(unit: DriveUnit, dt: float, max_steps: int = 2000):
    """Step until idle; return the (speed, turn_rate, pose) of every step."""
    trace = []
    for _ in range(max_steps):
        unit.step(dt)
        trace.append((unit.speed, unit.turn_rate, unit.pose))
        if unit.idle:
            return trace
    raise AssertionError(f"unit still moving after {max_steps} steps at {unit.pose}")


@pytest.mark.parametrize("dt", [0.02, 0.05, 0.1])
def test_a_unit_follows_a_path_with_corners_to_its_end_within_its_limits(dt):
    unit = DriveUnit("u1", Pose2D(0.0, 0.0, 2.0), LIMITS)
    path = [(4.0, 0.0), (4.0, 3.0), (4.0, 6.0), (0.5, 6.5), (0.5, 6.4)]
    unit.follow(path)
    trace = drive(unit, dt)
    end = trace[-1][2]
    assert math.hypot(end.x - 0.5, end.y - 6.4) <= WAYPOINT_TOLERANCE_M
    speeds = [0.0] + [s for s, _, _ in trace]
    assert max(speeds) == pytest.approx(LIMITS.max_speed)
    assert all(
        abs(b - a) <= LIMITS.max_accel * dt + 1e-9 for a, b in zip(speeds, speeds[1:], strict=False)
    )
    assert all(abs(w) <= LIMITS.max_turn_rate + 1e-12 for _, w, _ in trace)


def test_a_unit_stops_at_a_corner_and_turns_in_place():
    unit = DriveUnit("u1", Pose2D(0.0, 0.0, 0.0), LIMITS)
    unit.follow([(3.0, 0.0), (3.0, 3.0)])
    trace = drive(unit, 0.05)
    turning = [(s, p) for s, w, p in trace if abs(w) > 0.5]
    assert turning and all(s * 0.05 <= 0.01 for s, _ in turning)  # no driving while turning
    assert all(abs(p.x - 3.0) < 0.02 for _, p in turning)


def test_a_waypoint_on_a_straight_run_is_passed_without_slowing():
    unit = DriveUnit("u1", Pose2D(0.0, 0.0, 0.0), LIMITS)
    unit.follow([(3.0, 0.0), (6.0, 0.0), (12.0, 0.0)])
    trace = drive(unit, 0.05)
    near_middle = [s for s, _, p in trace if 2.5 < p.x < 6.5]
    assert min(near_middle) == pytest.approx(LIMITS.max_speed)


def test_the_braking_profile_stops_exactly_at_the_distance():
    dt, accel = 0.1, 1.0
    for k in range(1, 8):
        distance = accel * dt * dt * k * (k + 1) / 2  # speeds k a dt, ..., a dt
        assert stopping_speed(distance, accel, dt) == pytest.approx(k * accel * dt)


def test_halt_drops_the_path_and_stops_at_once():
    unit = DriveUnit("u1", Pose2D(0.0, 0.0, 0.0), LIMITS)
    unit.follow([(10.0, 0.0)])
    for _ in range(30):
        unit.step(0.1)
    assert unit.speed > 0
    unit.halt()
    assert unit.idle and unit.path == ()
    before = unit.pose
    assert unit.step(0.1) == before


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: DriveLimits(max_speed=0.0), "max_speed must be positive and finite, got 0.0"),
        (lambda: DriveLimits(align_tolerance=2.0), "align_tolerance must be in .*got 2.0"),
        (lambda: DriveUnit("u1", Pose2D(0, 0, 0)).follow([(1.0, "a")]), r"path\[0\] must be"),
        (lambda: DriveUnit("u1", Pose2D(0, 0, 0)).step(-0.1), "dt must be .*got -0.1"),
        (lambda: DriveUnit("", Pose2D(0, 0, 0)), "unit_id must be .*got ''"),
    ],
)
def test_errors_name_the_field_and_the_value(build, message):
    with pytest.raises(ValueError, match=message):
        build()


@settings(max_examples=60)
@example(  # braked for the path's way round a waypoint, not the straight last stretch
    dt=0.02, speed=1.0, accel=1.0, turn=1.0, yaw=0.0, path=[(-0.25, 1.75), (-0.25, 2.0)]
)
@given(
    dt=st.sampled_from([0.02, 0.05, 0.1]),
    speed=st.floats(0.3, 2.5),
    accel=st.floats(0.2, 3.0),
    turn=st.floats(0.3, 3.0),
    yaw=st.floats(-3.1, 3.1),
    path=st.lists(st.tuples(st.floats(-5, 5), st.floats(-5, 5)), min_size=1, max_size=5),
)
def test_any_path_is_driven_to_its_end_within_the_limits(dt, speed, accel, turn, yaw, path):
    limits = DriveLimits(max_speed=speed, max_accel=accel, max_turn_rate=turn)
    unit = DriveUnit("u1", Pose2D(0.0, 0.0, yaw), limits)
    unit.follow(path)
    trace = drive(unit, dt, max_steps=20000)
    end = trace[-1][2]
    assert math.hypot(end.x - path[-1][0], end.y - path[-1][1]) <= WAYPOINT_TOLERANCE_M
    speeds = [0.0] + [s for s, _, _ in trace]
    assert max(speeds) <= speed + 1e-9
    assert all(abs(b - a) <= accel * dt + 1e-9 for a, b in zip(speeds, speeds[1:], strict=False))
    assert all(abs(w) <= turn + 1e-12 for _, w, _ in trace)


def test_a_gentle_bend_is_driven_through_without_stopping():
    # 30 degrees, under rotate_to_heading: the unit slows to the corner speed (a swing of
    # at most CORNER_ERROR_M outside it at full turn rate), turns, and never stops.
    unit = DriveUnit("u1", Pose2D(0.0, 0.0, 0.0), LIMITS)
    bend = (6.0 + 6.0 * math.cos(math.pi / 6), 6.0 * math.sin(math.pi / 6))
    unit.follow([(6.0, 0.0), bend])
    trace = drive(unit, 0.05)
    corner_speed = LIMITS.max_turn_rate * CORNER_ERROR_M / (1 - math.cos(math.pi / 6))
    around = [s for s, _, p in trace if 4.0 < p.x < 9.0]
    assert min(around) >= 0.9 * corner_speed > 0.3
    assert max(s for s, _, p in trace if p.x < 3.0) == pytest.approx(LIMITS.max_speed)
    inside = [p for _, _, p in trace if p.x > 6.0]  # past the corner: not cut inside it
    assert all(p.y <= math.tan(math.pi / 6) * (p.x - 6.0) + 1e-9 for p in inside)
    assert all(abs(w) <= LIMITS.max_turn_rate + 1e-12 for _, w, _ in trace)
    end = trace[-1][2]
    assert math.hypot(end.x - bend[0], end.y - bend[1]) <= WAYPOINT_TOLERANCE_M


def test_a_unit_standing_off_its_heading_turns_in_place_before_it_drives():
    unit = DriveUnit("u1", Pose2D(0.0, 0.0, 0.0), LIMITS)
    unit.follow([(0.0, 5.0)])  # 90 degrees to its left
    trace = drive(unit, 0.1)
    first_move = next(i for i, (s, _, _) in enumerate(trace) if s > 0)
    assert abs(trace[first_move - 1][2].yaw - math.pi / 2) <= LIMITS.align_tolerance
    assert all(s == 0.0 for s, _, _ in trace[:first_move])


def test_lookahead_limits_are_checked():
    with pytest.raises(ValueError, match=r"max_lookahead must be >= min_lookahead .*got 0.1"):
        DriveLimits(min_lookahead=0.4, max_lookahead=0.1)
    with pytest.raises(ValueError, match=r"rotate_to_heading must be in .*got 0.05"):
        DriveLimits(rotate_to_heading=0.05)
