"""The counters sampled for the replay's ``/metrics`` (``CountersRecorder``): counted as
plans arrive, each sample equal to counting every plan so far (``plan_counts``)."""

from types import SimpleNamespace

from hypothesis import given, settings
from hypothesis import strategies as st

from mapserver.core.geometry import GridGeometry
from scenarios.run.observers import CountersRecorder
from scenarios.run.record import PlanSample, RunRecord
from scenarios.score.counts import plan_counts

CELL = ((1.05, 1.05),)
KINDS = {  # a plan's (stale_cells, inscribed_cells): clean, stale-free, inscribed, both
    "clean": ((), ()),
    "stale": (CELL, ()),
    "inscribed": ((), CELL),
    "both": (CELL, CELL),  # stale-free only: it crosses a lethal cell
}


@settings(max_examples=60, deadline=None)
@given(batches=st.lists(st.lists(st.sampled_from(sorted(KINDS)), max_size=6), max_size=8))
def test_every_sample_counts_every_plan_so_far(batches):
    record = RunRecord("t", "dual", 0, GridGeometry(10, 10, 0.1))
    throughput = SimpleNamespace(tracker=SimpleNamespace(trips=[]))
    recorder = CountersRecorder(throughput, every_s=1.0)
    for step, kinds in enumerate(batches):
        for kind in kinds:
            stale, inscribed = KINDS[kind]
            record.plans.append(
                PlanSample(float(step), "u1", ((0.0, 0.0), (1.0, 1.0)), stale, inscribed)
            )
        report = SimpleNamespace(now=float(step), frozen=set())
        recorder.observe(SimpleNamespace(record=record, report=report, events=[]))
        sample, expected = record.counters[-1], plan_counts(record.plans)
        assert sample.stale_free_plans == expected["stale_free_plans"]
        assert sample.inscribed_plans == expected["inscribed_plans"]
    assert len(record.counters) == len(batches)
