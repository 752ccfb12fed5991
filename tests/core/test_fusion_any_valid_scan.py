"""No poison pill: every scan ``Scan.from_dict`` accepts fuses without an error and
leaves every cell finite, however extreme its numbers (so the journal never holds a scan
the server cannot replay)."""

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from mapserver.core.belief import BeliefGrid
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import MAX_POSE_STD, Pose2D, Scan, ScanError
from mapserver.core.sensor_model import Policy

GEOMETRY = GridGeometry(60, 40, 0.1)  # 6 m x 4 m
HUGE = st.sampled_from([1e-300, 1e-12, 1e12, 1e300, 1.7e308, -1e300, 10**300])
ANY = st.one_of(st.floats(-1e3, 1e3), HUGE, st.floats(allow_nan=True, allow_infinity=True))
POSITIVE = st.one_of(st.floats(1e-3, 10.0), st.sampled_from([1e-300, 1e-12, 1e12, 1e300]))


@st.composite
def bodies(draw):
    """Scan bodies on the map, mostly valid, with extreme numbers where numbers go."""
    range_min = draw(st.one_of(st.floats(0.0, 1.0), HUGE))
    return {
        "unit_id": "u1",
        "stamp": draw(ANY),
        "pose": {
            "x": draw(st.floats(0.0, 5.99)),
            "y": draw(st.floats(0.0, 3.99)),
            "yaw": draw(ANY),
        },
        "pose_std": draw(st.none() | st.fixed_dictionaries({"xy": POSITIVE, "yaw": POSITIVE})),
        "angle_min": draw(ANY),
        "angle_increment": draw(POSITIVE),
        "range_min": range_min,
        "range_max": draw(st.one_of(st.floats(1.0, 30.0), HUGE)),
        "ranges": draw(st.lists(st.none() | st.floats(0.0, 40.0) | ANY, min_size=1, max_size=40)),
    }


@settings(max_examples=300, suppress_health_check=[HealthCheck.too_slow], deadline=None)
@given(body=bodies(), policy=st.sampled_from(list(Policy)))
def test_an_accepted_scan_always_fuses_and_every_cell_stays_finite(body, policy):
    try:
        scan = Scan.from_dict(body)
    except ScanError:
        return  # refused by name: never journaled
    event("accepted")
    assert scan.pose_std is None or max(scan.pose_std.xy, scan.pose_std.yaw) <= MAX_POSE_STD
    belief = BeliefGrid(GEOMETRY, policy=policy)
    belief.fuse(scan)
    assert np.isfinite(belief.raw_log_odds()).all()
    seen = belief.last_observed()
    assert np.isnan(seen[~np.isfinite(seen)]).all()  # a stamp or never observed
    assert np.isfinite(belief.log_odds_at(scan.stamp + 1.0)).all()


def test_beams_without_a_direction_change_nothing_in_the_kernel():
    """Behind validation, the kernel itself: an infinite beam angle (yaw + angle_min past
    float range) once made it write outside the grid (a segmentation fault)."""
    scan = Scan(
        unit_id="u1",
        stamp=1.0,
        pose=Pose2D(3.0, 2.0, 1.7e308),
        angle_min=1.7e308,
        angle_increment=0.01,
        range_min=0.0,
        range_max=10.0,
        ranges=np.array([1.0, 2.0, 20.0, 3.0]),
    )
    belief = BeliefGrid(GEOMETRY)
    assert belief.fuse(scan).cells == 0
    assert np.isnan(belief.last_observed()).all()


def test_angles_past_a_million_radians_are_refused_by_name():
    body = {"unit_id": "u1", "stamp": 1.0, "pose": {"x": 1.0, "y": 1.0, "yaw": 1.7e308},
            "angle_min": 0.0, "angle_increment": 0.1, "range_min": 0.0, "range_max": 5.0,
            "ranges": [1.0]}  # fmt: skip
    with pytest.raises(ScanError, match=r"^pose.yaw: must be <= 1e\+06"):
        Scan.from_dict(body)
    with pytest.raises(ScanError, match=r"^angle_min: must be >= -1000000"):
        Scan.from_dict({**body, "pose": {"x": 1.0, "y": 1.0, "yaw": 0.0}, "angle_min": -1e7})
