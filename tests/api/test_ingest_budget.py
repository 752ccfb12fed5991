"""The ingest budget's buckets with a fake clock: exact refill arithmetic, Retry-After,
per-token aggregation, honest units never refused, bounded memory."""

import pytest

from mapserver.api.ingest_budget import Budget, IngestBudget, Throttled


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def budget(unit=(1000.0, None), token=(None, None), burst_s=2.0, max_tracked=100_000):
    clock = FakeClock()
    units = Budget(*unit, burst_s, "ingest.unit")
    tokens = Budget(*token, burst_s, "ingest.token")
    return IngestBudget(units, tokens, clock, max_tracked), clock


def test_a_full_bucket_admits_its_burst_then_refills_at_the_rate():
    b, clock = budget(unit=(1000.0, None), burst_s=2.0)  # capacity 2,000 beams
    b.check(None, [("u1", 1500)])  # level 500
    with pytest.raises(Throttled) as refused:
        b.check(None, [("u1", 1000)])  # needs 1,000: 500 short, 0.5 s at 1,000/s
    assert refused.value.retry_after_s == 1  # whole seconds, rounded up
    assert refused.value.scope == "unit" and refused.value.limit == "beams"
    clock.now += 0.5  # exactly 500 more: level 1,000
    b.check(None, [("u1", 1000)])  # level 0
    clock.now += 0.25
    with pytest.raises(Throttled) as refused:
        b.check(None, [("u1", 1000)])  # level 250, 750 short: 0.75 s
    assert refused.value.retry_after_s == 1
    clock.now += 0.75
    b.check(None, [("u1", 1000)])


def test_retry_after_is_the_whole_seconds_until_the_need_is_met():
    b, clock = budget(unit=(100.0, None), burst_s=10.0)  # capacity 1,000
    b.check(None, [("u1", 1000)])  # level 0
    clock.now += 2.0  # level 200
    with pytest.raises(Throttled) as refused:
        b.check(None, [("u1", 750)])  # 550 short at 100/s: 5.5 s -> 6
    assert refused.value.retry_after_s == 6
    message = str(refused.value)
    assert "unit 'u1'" in message and "ingest.unit_beams_per_s" in message
    assert "100 beams/s" in message and "ingest.burst_s" in message and "750 beams" in message
    clock.now += 5.5
    b.check(None, [("u1", 750)])


def test_a_refused_request_takes_nothing_and_a_look_takes_nothing():
    b, clock = budget(unit=(1000.0, None), burst_s=1.0)
    b.check(None, [("u1", 600)])  # level 400
    for _ in range(10):
        with pytest.raises(Throttled):
            b.check(None, [("u1", 500)])
    b.check(None, [("u1", 400)], charge=False)  # only looks
    b.check(None, [("u1", 400)])  # level 0: the refusals and the look took nothing


def test_a_request_larger_than_the_burst_passes_from_a_full_bucket_then_waits_off_its_debt():
    b, clock = budget(unit=(1000.0, None), burst_s=1.0)  # capacity 1,000
    b.check(None, [("u1", 3000)])  # a backlog batch: level -2,000
    with pytest.raises(Throttled) as refused:
        b.check(None, [("u1", 250)])  # 2,250 short: 2.25 s -> 3
    assert refused.value.retry_after_s == 3
    clock.now += 2.25
    b.check(None, [("u1", 250)])


def test_scans_per_second_are_limited_apart_from_beams():
    b, clock = budget(unit=(None, 10.0), burst_s=1.0)  # 10 scans, any beams
    b.check(None, [("u1", 1)] * 10)
    with pytest.raises(Throttled) as refused:
        b.check(None, [("u1", 1)])
    assert refused.value.limit == "scans" and refused.value.retry_after_s == 1
    clock.now += 0.1
    b.check(None, [("u1", 1)])


def test_units_have_buckets_of_their_own():
    b, clock = budget(unit=(1000.0, None), burst_s=1.0)
    b.check(None, [("greedy", 1000)])
    with pytest.raises(Throttled):
        b.check(None, [("greedy", 1000)])
    b.check(None, [("u1", 1000)])  # another unit is untouched


def test_a_token_pays_for_every_unit_it_posts_as():
    b, clock = budget(unit=(1000.0, None), token=(1500.0, None), burst_s=1.0)
    b.check("sim", [("a", 800)])
    b.check("sim", [("b", 600)])  # token level 100, each unit below its own budget
    with pytest.raises(Throttled) as refused:
        b.check("sim", [("c", 200)])  # a fresh unit id: its own bucket is full, the token's not
    assert refused.value.scope == "token" and "token 'sim'" in str(refused.value)
    assert "ingest.token_beams_per_s" in str(refused.value)
    with pytest.raises(Throttled):
        b.check("sim", [("d", 101)])  # 1 beam more than the token holds
    b.check("other", [("c", 200)])  # another token is untouched
    b.check(None, [("c", 200)])  # no token (open server): only the unit's budget


def test_a_token_in_debt_is_refused_before_its_body_is_read():
    b, clock = budget(unit=(None, None), token=(1000.0, None), burst_s=1.0)
    b.check_token("sim")  # no bucket yet: full
    b.check("sim", [("a", 1999)])  # level -999
    with pytest.raises(Throttled) as refused:
        b.check_token("sim")  # needs 1 beam: 1,000 short -> 1 s
    assert refused.value.retry_after_s == 1
    clock.now += 1.0
    b.check_token("sim")
    b.check_token(None)  # an open server has no token to refuse


def test_a_batch_is_charged_whole_or_not_at_all():
    b, clock = budget(unit=(1000.0, None), burst_s=1.0)
    b.check(None, [("u1", 900)])  # u1 level 100
    with pytest.raises(Throttled):
        b.check(None, [("u2", 500), ("u1", 200)])  # u1 past: u2 not charged either
    b.check(None, [("u2", 1000)])  # u2 still full


def test_honest_units_are_never_refused():
    """A 20 Hz x 2,000-beam unit at the defaults (60,000 beams/s, 100 scans/s, 10 s burst)
    for 10 minutes; one that docks for an hour and comes back; a late joiner; a unit
    back from a 15 s network drop posting its backlog in one batch, then live."""
    b, clock = budget(unit=(60_000.0, 100.0), burst_s=10.0)
    for _ in range(20 * 600):
        b.check(None, [("lidar", 2000)])
        clock.now += 0.05
    clock.now += 3600.0  # docked
    for _ in range(100):
        b.check(None, [("lidar", 2000)])
        b.check(None, [("late", 1080)])
        clock.now += 0.05
    b.check(None, [("lidar", 2000)] * 256)  # 15 s of backlog in two batches
    b.check(None, [("lidar", 2000)] * 44)
    for _ in range(20 * 60):
        clock.now += 0.05
        b.check(None, [("lidar", 2000)])  # live again: 20,000 beams/s of headroom refill


def test_buckets_expire_once_refilled_and_are_bounded_in_number():
    b, clock = budget(unit=(1000.0, None), burst_s=1.0, max_tracked=50)
    for k in range(40):
        b.check(None, [(f"id{k}", 500)])
    assert len(b) == 40
    clock.now += 0.5  # all refilled to full: forgotten
    b.check(None, [("x", 500)])
    assert len(b) == 1
    for k in range(1000):
        b.check(None, [(f"rotating{k}", 500)])  # a client making up ids, all at once
    assert len(b) == 50  # the least recently used go first


def test_disabled_budgets_track_nothing():
    b, clock = budget(unit=(None, 0.0), token=(0.0, None))
    for k in range(100):
        b.check("t", [(f"u{k}", 10**9)])
    assert len(b) == 0
