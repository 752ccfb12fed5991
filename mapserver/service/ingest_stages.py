"""Where an accepted scan submission's time goes between ``submit`` and its answer.

The ingest pipeline (``map_service``) has four stages, timed for each accepted
submission [s]:

- ``queued``: from ``submit`` until the ingest thread takes its group;
- ``journal``: the group's state checks and journal transaction (its fsync);
- ``fuse_wait``: from the journal's commit until the fusion thread takes the group;
- ``fuse``: the group's fusion (and a costmap refresh when one was due), until answered;

and ``answered``, the whole: from ``submit`` to the answer. Scans are grouped (group
commit), so a submission waits for its whole group in ``journal`` and ``fuse``: the
group sizes are kept too. Cumulative histograms (Prometheus' convention: a count per
upper bound, ``+Inf`` last), read by ``GET /metrics``.
"""

from __future__ import annotations

import bisect
import itertools
import threading
from collections.abc import Sequence
from dataclasses import dataclass

STAGES = ("queued", "journal", "fuse_wait", "fuse", "answered")
STAGE_BUCKETS = (0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)  # [s]
GROUP_BUCKETS = (1, 2, 4, 8, 16, 32, 64, 128, 256, 512)  # scans per group


@dataclass(frozen=True)
class Histogram:
    """A cumulative histogram: ``counts[i]`` observations <= ``bounds[i]``, the last
    (``+Inf``) all of them; ``total`` their sum."""

    bounds: tuple[float, ...]
    counts: tuple[int, ...]
    total: float

    @property
    def count(self) -> int:
        return self.counts[-1]

    @property
    def mean(self) -> float:
        """The mean observation (NaN before the first)."""
        return self.total / self.count if self.count else float("nan")


class _Bins:
    """Counts per bucket (not cumulative) and the sum, for one series. Plain Python: the
    fusion thread records a few values a group, where each numpy call would cost more
    than the counting (and a chance to wait for the GIL)."""

    def __init__(self, bounds: Sequence[float]) -> None:
        self.bounds = tuple(bounds)
        self.counts = [0] * (len(self.bounds) + 1)
        self.total = 0.0

    def add(self, value: float, times: int = 1) -> None:
        """``value`` observed ``times`` times."""
        # Prometheus' buckets hold values <= their bound: bisect_left puts a value equal
        # to a bound in that bound's bucket.
        self.counts[bisect.bisect_left(self.bounds, value)] += times
        self.total += value * times

    def histogram(self) -> Histogram:
        return Histogram(self.bounds, tuple(itertools.accumulate(self.counts)), self.total)


class IngestStages:
    """The stage times of accepted submissions and the sizes of their groups
    (thread-safe: the fusion thread records, ``GET /metrics`` reads)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._stages = {stage: _Bins(STAGE_BUCKETS) for stage in STAGES}
        self._groups = _Bins(GROUP_BUCKETS)

    def record_group(
        self,
        submitted: Sequence[float],
        taken: float,
        journaled: float,
        fuse_taken: float,
        answered: float,
        scans: int,
    ) -> None:
        """One answered group: its accepted submissions' ``submit`` times and the group's
        times (all [s] on one monotonic clock: taken by the ingest thread, journaled,
        taken by the fusion thread, answered) and its count of new scans."""
        if not submitted:
            return
        n = len(submitted)
        stages = self._stages
        with self._lock:
            for start in submitted:
                stages["queued"].add(taken - start)
                stages["answered"].add(answered - start)
            stages["journal"].add(journaled - taken, n)
            stages["fuse_wait"].add(fuse_taken - journaled, n)
            stages["fuse"].add(answered - fuse_taken, n)
            self._groups.add(scans)

    def stages(self) -> dict[str, Histogram]:
        """Each stage's histogram [s], in pipeline order (``answered`` last)."""
        with self._lock:
            return {stage: bins.histogram() for stage, bins in self._stages.items()}

    def group_sizes(self) -> Histogram:
        """New scans per answered group."""
        with self._lock:
            return self._groups.histogram()
