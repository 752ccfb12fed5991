"""Prometheus metrics of one server (its own registry): scans fused, refused and
throttled (ingest budgets), fusion time, the ingest stages' times and group sizes,
request latency, journal size, map version, quarantined journal records, failed
snapshots, heavy reads admitted and refused."""

from __future__ import annotations

from collections.abc import Iterator, Mapping

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram
from prometheus_client.core import HistogramMetricFamily
from prometheus_client.registry import Collector

from mapserver.api.admission import Admission
from mapserver.service.ingest_stages import Histogram as StageHistogram
from mapserver.service.ingest_stages import IngestStages
from mapserver.service.map_service import MapService

LATENCY_BUCKETS = (0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)
METHODS = frozenset(
    {"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS", "TRACE", "CONNECT"}
)


def method_label(method: str) -> str:
    """``method`` for a standard HTTP method, else ``OTHER``: a client inventing methods
    must not make a new metrics series each (a label's values stay bounded)."""
    return method if method in METHODS else "OTHER"


class ServerMetrics:
    """The metrics; ``registry`` is what ``GET /metrics`` renders."""

    def __init__(self, service: MapService) -> None:
        self.registry = CollectorRegistry()
        self.scans_fused = Counter(
            "fleetmap_scans_fused", "Scans accepted and fused into the map", registry=self.registry
        )
        self.scans_rejected = Counter(
            "fleetmap_scans_rejected",
            "Scan submissions refused, by HTTP status",
            ["status"],
            registry=self.registry,
        )
        self.scans_throttled = Counter(
            "fleetmap_scans_throttled",
            "Scan requests refused with 429 past a unit's or a token's ingest budget, by "
            "scope (unit, token) and limit (beams, scans)",
            ["scope", "limit"],
            registry=self.registry,
        )
        for scope in ("unit", "token"):
            for limit in ("beams", "scans"):
                self.scans_throttled.labels(scope, limit)  # listed at 0 from the start
        self.request_latency = Histogram(
            "fleetmap_request_seconds",
            "HTTP request latency [s] by method, route and status",
            ["method", "route", "status"],
            buckets=LATENCY_BUCKETS,
            registry=self.registry,
        )
        fusion = Gauge(
            "fleetmap_fusion_seconds",
            "Cumulative time [s] spent fusing scans and refreshing the costmap",
            registry=self.registry,
        )
        fusion.set_function(lambda: service.fusion_seconds)
        journal = Gauge(
            "fleetmap_journal_bytes", "Size [bytes] of the journal files", registry=self.registry
        )
        journal.set_function(service.journal_bytes)
        version = Gauge("fleetmap_map_version", "The map's version", registry=self.registry)
        version.set_function(lambda: service.version)
        quarantined = Gauge(
            "fleetmap_journal_quarantined",
            "Journal records in quarantine (damaged or dropped; never replayed)",
            registry=self.registry,
        )
        quarantined.set_function(lambda: service.journal.quarantined)
        snapshot_failures = Gauge(
            "fleetmap_snapshot_failures",
            "Snapshot saves that failed since start-up (the journal still holds the scans)",
            registry=self.registry,
        )
        snapshot_failures.set_function(lambda: service.snapshot_failures)
        self.registry.register(IngestStagesCollector(service.stages))

    def watch_reads(self, admissions: Mapping[str, Admission]) -> None:
        """Gauges of the heavy reads by kind (``query``, ``plan``): admitted now (computing
        or waiting) and refused with 429 since start-up."""
        inside = Gauge(
            "fleetmap_reads_admitted",
            "Heavy reads computing or waiting now, by kind",
            ["kind"],
            registry=self.registry,
        )
        refused = Gauge(
            "fleetmap_reads_refused",
            "Heavy reads refused with 429 (saturated) since start-up, by kind",
            ["kind"],
            registry=self.registry,
        )
        for kind, admission in admissions.items():
            inside.labels(kind).set_function(lambda a=admission: a.admitted)
            refused.labels(kind).set_function(lambda a=admission: a.refused)


def _buckets(histogram: StageHistogram) -> list[tuple[str, float]]:
    """Prometheus' cumulative buckets of ``histogram``, ``+Inf`` last."""
    bounds = [repr(float(b)) for b in histogram.bounds] + ["+Inf"]
    return list(zip(bounds, histogram.counts, strict=True))


class IngestStagesCollector(Collector):
    """``fleetmap_ingest_stage_seconds{stage}``: each accepted scan submission's time in
    each ingest stage (``ingest_stages``: queued, journal, fuse_wait, fuse, and answered,
    the whole); ``fleetmap_ingest_group_scans``: new scans per journaled group."""

    def __init__(self, stages: IngestStages) -> None:
        self.stages = stages

    def collect(self) -> Iterator[HistogramMetricFamily]:
        seconds = HistogramMetricFamily(
            "fleetmap_ingest_stage_seconds",
            "Time [s] an accepted scan submission spent in each ingest stage (queued, "
            "journal, fuse_wait, fuse) and from submit to answer (answered)",
            labels=["stage"],
        )
        for stage, histogram in self.stages.stages().items():
            seconds.add_metric([stage], _buckets(histogram), histogram.total)
        yield seconds
        groups = self.stages.group_sizes()
        sizes = HistogramMetricFamily(
            "fleetmap_ingest_group_scans", "New scans per journaled and fused group"
        )
        sizes.add_metric([], _buckets(groups), groups.total)
        yield sizes
