"""The ingest stage times: exact histograms of what was recorded, and every accepted
submission of a running service counted once its ack is out."""

import numpy as np
from conftest import make_scan
from hypothesis import given
from hypothesis import strategies as st
from server_helpers import small_settings

from mapserver.service.ingest_stages import STAGE_BUCKETS, STAGES, IngestStages
from mapserver.service.map_service import MapService


def test_a_group_is_recorded_per_submission_with_exact_bucket_counts():
    stages = IngestStages()
    # two submissions at -1 s and -0.5 s, taken at 0 s, journaled at 0.002 s (a bound:
    # counted at it), taken for fusion at 0.01 s, answered at 0.0625 s; 3 new scans
    stages.record_group([-1.0, -0.5], 0.0, 0.002, 0.01, 0.0625, 3)
    got = stages.stages()
    assert list(got) == list(STAGES)
    assert got["queued"].total == 1.5 and got["queued"].count == 2
    index = {bound: i for i, bound in enumerate(STAGE_BUCKETS)}
    # queued 1.0 and 0.5: in the buckets of 1.0 and 0.5
    assert got["queued"].counts[index[0.2]] == 0
    assert got["queued"].counts[index[0.5]] == 1 and got["queued"].counts[index[1.0]] == 2
    journal = got["journal"]
    assert journal.counts[index[0.001]] == 0 and journal.counts[index[0.002]] == 2
    assert np.isclose(journal.total, 0.004)
    assert got["fuse_wait"].counts[index[0.01]] == 2 and got["fuse"].counts[index[0.05]] == 0
    assert got["fuse"].counts[index[0.1]] == 2
    assert got["answered"].total == 1.0625 + 0.5625
    groups = stages.group_sizes()
    assert (groups.count, groups.total, groups.mean) == (1, 3.0, 3.0)


@given(st.lists(st.floats(0.0, 10.0, allow_nan=False), min_size=1, max_size=50))
def test_cumulative_counts_are_the_values_at_or_below_each_bound(waits):
    stages = IngestStages()
    stages.record_group([-w for w in waits], 0.0, 0.0, 0.0, 0.0, len(waits))
    queued = stages.stages()["queued"]
    expected = [sum(w <= b for w in waits) for b in STAGE_BUCKETS] + [len(waits)]
    assert list(queued.counts) == expected
    assert np.isclose(queued.total, sum(waits))


def test_every_accepted_submission_is_counted_once_its_ack_is_out(tmp_path):
    service = MapService(small_settings(tmp_path / "data"))
    try:
        futures = [
            service.submit(
                [make_scan(np.full(60, 2.0), x=2.0 + u, y=2.0, stamp=float(k), unit_id=f"u{u}")]
            )
            for k in range(1, 6)
            for u in range(4)
        ]
        for future in futures:
            future.result()
        refused = service.submit([make_scan(np.full(60, 2.0), x=2.0, y=2.0, stamp=0.5,
                                            unit_id="u0")])  # fmt: skip
        assert refused.exception() is not None  # its stamp went backwards: not counted
        stages = service.stages.stages()
        assert {stage: h.count for stage, h in stages.items()} == dict.fromkeys(STAGES, 20)
        assert service.stages.group_sizes().total == 20  # every new scan, in some group
        answered = stages["answered"].total
        parts = sum(stages[s].total for s in ("queued", "journal", "fuse_wait", "fuse"))
        assert np.isclose(answered, parts)  # the stages add up to the whole
    finally:
        service.close()
