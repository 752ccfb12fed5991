"""The run metrics, each declared once: its key, title, unit, which direction is better,
how a setting's runs (its seeds) are reduced to one number, how it is written, and where
it is shown. ``metrics.json``'s keys (docs/files.md 3), the report's title and throughput
table (``scenarios.score.report``), ``fleetmap run``'s table, the ``compare`` tables, a
sweep's ``results.csv`` and Pareto objectives (``scenarios.sweep``), the replay's
``/metrics`` channel (``scenarios.replay.metrics_channel``) and the docs' lists
(``scenarios.score.metric_docs``) all read ``REGISTRY``.

A metric's ``key`` is its path in ``metrics.json``: ``phantom_freeze_seconds``, or for a
part of an object ``wait_s.traffic`` and ``map_truth.forgotten_cells`` (whose run value
is the ``mean`` of its ``{mean, final}``, ``Read.MEAN_FIELD``). The scorers that make
``metrics.json`` declare the top-level keys they emit (``feeds``); a run's metrics are
checked against the registry when the run is scored (``check_run_metrics``), so a key
the registry does not know cannot be written silently, nor one it knows left out.

Consumers read ``REGISTRY`` through this module (``shown_in``, ``metric``) when they
run, not at import, so a registry with one more metric (``Registry.plus``) put in its
place shows that metric everywhere its views say.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from functools import wraps
from typing import Any, TypeVar

from mapserver.core.errors import FleetmapError

__all__ = [
    "REGISTRY",
    "Better",
    "Metric",
    "MetricError",
    "Read",
    "Reduce",
    "Registry",
    "Unit",
    "View",
    "check_run_metrics",
    "feeds",
    "metric",
    "shown_in",
]


class MetricError(FleetmapError, ValueError):
    """A metric the registry does not declare (named), or one it declares left out."""


class Better(StrEnum):
    """Which way a metric is better (the ``compare`` verdict row reads it)."""

    LOWER = "lower"
    HIGHER = "higher"
    NEITHER = "neither"


class Reduce(StrEnum):
    """How a setting's runs (one per seed) are reduced to one number: ``mean`` (the
    ``compare`` tables add its 95 % interval), ``sum``, ``max``, ``same`` (every run has
    the same value: the scenario's own) or ``none`` (the runs differ by design: seed)."""

    MEAN = "mean"
    SUM = "sum"
    MAX = "max"
    SAME = "same"
    NONE = "none"

    def of(self, values: Sequence[float]) -> float | None:
        """``values`` (one per run, none missing) reduced; None for no value; MetricError
        for ``none``, or ``same`` over values that differ."""
        if self is Reduce.NONE:
            raise MetricError("a metric reduced 'none' tells runs apart; it has no reduction")
        if not values:
            return None
        if self is Reduce.MEAN:
            return math.fsum(values) / len(values)
        if self is Reduce.SUM:
            return math.fsum(values)
        if self is Reduce.MAX:
            return max(values)
        if any(v != values[0] for v in values):
            raise MetricError(f"values meant to be the same differ: {sorted(set(values))}")
        return values[0]


class Read(StrEnum):
    """How one run's stored value becomes its number: ``value`` (a number as stored),
    ``list_mean`` (the mean of a list's non-null entries: ``time_to_clear_s``) or
    ``mean_field`` (the ``mean`` of a ``{mean, final}`` object: ``map_truth``'s)."""

    VALUE = "value"
    LIST_MEAN = "list_mean"
    MEAN_FIELD = "mean_field"


class View(StrEnum):
    """Where a metric is shown (each in registry order)."""

    METRICS_JSON = "metrics.json"
    RUN_TABLE = "fleetmap run"
    COMPARE = "compare"
    PARETO = "pareto"
    REPORT_TITLE = "report title"
    REPORT_TABLE = "report table"
    FOXGLOVE = "/metrics"


@dataclass(frozen=True)
class Unit:
    """A metric's unit: ``symbol`` (docs, axis labels), ``suffix`` written after a
    number for people (empty: none), ``percent`` (a share [1] written as a percent) and
    ``integer`` (a count: a run's value is written without decimals)."""

    symbol: str
    suffix: str = ""
    percent: bool = False
    integer: bool = False


COUNT = Unit("count", integer=True)
SECONDS = Unit("s", "s")
UNIT_SECONDS = Unit("unit-s", "s")
CELLS = Unit("cells")
RATIO = Unit("1")
SHARE = Unit("1", percent=True)
SPEED = Unit("m/s", "m/s")
TRIP_RATE = Unit("trips / (unit x h)")
LABEL = Unit("-")
"""A run's identity (scenario, policy, seed): not a measure."""


@dataclass(frozen=True)
class Metric:
    """One run metric (module docstring). ``title``: words for people (the report, the
    docs); ``column``: a table's header (empty: the title); ``decimals``: of a number in
    tables and of a run's value written for people (a percent with one fewer; a count's
    run value has none); ``views``: where it is shown; ``group``: the docs page block
    that lists it; ``contract``: named in docs/files.md 3; ``optional``: a run may lack
    it (runs scored before it existed), tables drop it when no run has it;
    ``meaning``: its definition, one sentence for the docs."""

    key: str
    title: str
    unit: Unit
    better: Better
    meaning: str
    group: str
    column: str = ""
    reduce: Reduce = Reduce.MEAN
    read: Read = Read.VALUE
    decimals: int = 1
    views: frozenset[View] = field(default_factory=lambda: frozenset({View.METRICS_JSON}))
    contract: bool = False
    optional: bool = False

    @property
    def root(self) -> str:
        """Its top-level ``metrics.json`` key."""
        return self.key.split(".")[0]

    @property
    def header(self) -> str:
        """Its table header."""
        return self.column or self.title

    @property
    def label(self) -> str:
        """Its title with its unit, for an axis: ``phantom freeze time [s]``."""
        unit = self.unit.symbol
        return self.title if unit in (COUNT.symbol, LABEL.symbol) else f"{self.title} [{unit}]"

    def _lookup(self, metrics: Mapping[str, Any]) -> tuple[bool, Any]:
        """(whether one run's ``metrics`` hold it, its value there or None)."""
        value: Any = metrics
        for part in self.key.split("."):
            if not isinstance(value, Mapping) or part not in value:
                return False, None
            value = value[part]
        return True, value

    def stored(self, metrics: Mapping[str, Any]) -> Any:
        """Its value as one run's ``metrics`` hold it (None when absent)."""
        return self._lookup(metrics)[1]

    def present(self, metrics: Mapping[str, Any]) -> bool:
        """Whether one run's ``metrics`` hold it (null counts as held)."""
        return self._lookup(metrics)[0]

    def number(self, metrics: Mapping[str, Any]) -> float | None:
        """One run's number (``read``); None when absent, null or not a number."""
        value = self.stored(metrics)
        if self.read is Read.MEAN_FIELD:
            return _number(value.get("mean") if isinstance(value, Mapping) else None)
        if self.read is Read.LIST_MEAN:
            if not isinstance(value, list):
                return None
            numbers = [n for n in (_number(v) for v in value) if n is not None]
            return math.fsum(numbers) / len(numbers) if numbers else None
        return _number(value)

    def fixed(self, value: float) -> str:
        """``value`` in a table: ``decimals`` decimals, no unit."""
        return f"{value:.{self.decimals}f}"

    def text(self, value: Any) -> str:
        """One run's ``value`` for people: ``4.2 s``, ``3``, ``50.2%``; ``n/a`` for null."""
        if value is None:
            return "n/a"
        if self.unit.integer:
            return f"{int(value):d}"
        if self.unit.percent:
            return f"{value:.{max(self.decimals - 1, 0)}%}"
        text = self.fixed(value)
        return f"{text} {self.unit.suffix}" if self.unit.suffix else text


def _number(value: Any) -> float | None:
    """``value`` as a finite float; None for None, booleans, text and NaN."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    number = float(value)
    return number if math.isfinite(number) else None


class Registry:
    """The metrics in order (the order of every view). MetricError for a key declared
    twice, a key both plain and the root of parts, or a Pareto objective without a
    better direction."""

    def __init__(self, metrics: Iterable[Metric]) -> None:
        self.metrics: tuple[Metric, ...] = tuple(metrics)
        self._by_key = {m.key: m for m in self.metrics}
        if len(self._by_key) != len(self.metrics):
            keys = [m.key for m in self.metrics]
            twice = sorted({k for k in keys if keys.count(k) > 1})
            raise MetricError(f"metrics declared twice: {', '.join(twice)}")
        roots = {m.root for m in self.metrics if "." in m.key}
        if clash := sorted(roots & set(self._by_key)):
            raise MetricError(f"keys both a metric and an object of parts: {', '.join(clash)}")
        if aimless := [m.key for m in self.shown_in(View.PARETO) if m.better is Better.NEITHER]:
            raise MetricError(f"Pareto objectives need a better direction: {', '.join(aimless)}")

    def __iter__(self) -> Iterator[Metric]:
        return iter(self.metrics)

    def __contains__(self, key: object) -> bool:
        return key in self._by_key

    def __getitem__(self, key: str) -> Metric:
        """The metric of ``key``; MetricError naming an unknown key."""
        try:
            return self._by_key[key]
        except KeyError:
            raise MetricError(f"{key!r} is not a metric of the registry") from None

    def plus(self, *metrics: Metric) -> Registry:
        """This registry with ``metrics`` after its own."""
        return Registry((*self.metrics, *metrics))

    def shown_in(self, view: View) -> tuple[Metric, ...]:
        """The metrics ``view`` shows, in order."""
        return tuple(m for m in self.metrics if view in m.views)

    def json_keys(self) -> tuple[str, ...]:
        """The top-level keys of ``metrics.json``, in order."""
        return tuple(dict.fromkeys(m.root for m in self.shown_in(View.METRICS_JSON)))

    def parts(self, root: str) -> tuple[str, ...]:
        """The parts of object ``root`` (``wait_s`` -> ``traffic``, ``freeze``, ...)."""
        return tuple(m.key.split(".", 1)[1] for m in self.metrics if m.key.startswith(root + "."))

    def contract_keys(self) -> tuple[str, ...]:
        """The ``metrics.json`` keys docs/files.md 3 names, in order."""
        return tuple(dict.fromkeys(m.root for m in self.metrics if m.contract))

    def check(self, metrics: Mapping[str, Any]) -> None:
        """MetricError naming every top-level key of one run's ``metrics`` (and every part
        of an object metric) the registry does not declare, or declares and it lacks."""
        problems = _differences("metrics.json", metrics, self.json_keys())
        for root in self.json_keys():
            value = metrics.get(root)
            if self.parts(root) and isinstance(value, Mapping):
                problems += _differences(root, value, self.parts(root))
        if problems:
            raise MetricError("; ".join(problems))


def _differences(where: str, given: Iterable[str], declared: Sequence[str]) -> list[str]:
    extra = [k for k in given if k not in declared]
    missing = [k for k in declared if k not in given]
    out = []
    if extra:
        out.append(f"{where}: {', '.join(map(repr, extra))} not declared in the metric registry")
    if missing:
        out.append(f"{where}: declared {', '.join(map(repr, missing))} missing")
    return out


def shown_in(view: View) -> tuple[Metric, ...]:
    """``REGISTRY.shown_in(view)`` of the registry in place now."""
    return REGISTRY.shown_in(view)


def metric(key: str) -> Metric:
    """``REGISTRY[key]`` of the registry in place now."""
    return REGISTRY[key]


def check_run_metrics(metrics: Mapping[str, Any]) -> None:
    """``REGISTRY.check(metrics)`` of the registry in place now."""
    REGISTRY.check(metrics)


Scorer = TypeVar("Scorer", bound=Callable[..., Mapping[str, Any]])


def feeds(*keys: str) -> Callable[[Scorer], Scorer]:
    """Declare the top-level ``metrics.json`` keys a scorer's dict holds (``scorer.feeds``):
    MetricError at once for a key the registry does not declare, and whenever the scorer
    returns a key it did not declare, or leaves one out."""
    unknown = [k for k in keys if k not in REGISTRY.json_keys()]
    if unknown:
        raise MetricError(f"{', '.join(map(repr, unknown))} not declared in the metric registry")

    def declare(scorer: Scorer) -> Scorer:
        @wraps(scorer)
        def checked(*args: Any, **kwargs: Any) -> Mapping[str, Any]:
            out = scorer(*args, **kwargs)
            problems = _differences(scorer.__qualname__, out, keys)
            if problems:
                raise MetricError("; ".join(problems))
            return out

        checked.feeds = keys  # type: ignore[attr-defined]
        return checked  # type: ignore[return-value]

    return declare


# ----------------------------------------------------------------------------- the metrics
def _views(*views: View) -> frozenset[View]:
    return frozenset({View.METRICS_JSON, *views})


_JSON = _views()
_COMPARED = _views(View.COMPARE, View.RUN_TABLE)
_TITLED = _views(View.COMPARE, View.RUN_TABLE, View.REPORT_TITLE, View.FOXGLOVE)
_THROUGHPUT = _views(View.REPORT_TABLE)
_LOWER, _HIGHER, _NEITHER = Better.LOWER, Better.HIGHER, Better.NEITHER

_WAIT_CAUSES = (
    ("traffic", _LOWER, "waiting for a lane or node, or starting up"),
    ("freeze", _LOWER, "no admissible path or lane (the agent reports a blocked reason)"),
    ("dwell", _NEITHER, "dwelling at a pickup or dropoff"),
    ("breakdown", _NEITHER, "broken down (a scenario event)"),
    ("turn", _NEITHER, "turning in place"),
)
_MAP_TRUTH = (  # name, unit, decimals, views beyond metrics.json and compare, meaning
    ("phantom_cells", CELLS, 1, (), "lethal or inscribed in the shared costmap, free in truth"),
    ("forgotten_cells", CELLS, 1, (View.PARETO,),
     "lethal in truth, free or graded in the shared costmap"),
    ("unknown_share", RATIO, 3, (),
     "share of the reachable floor the shared costmap calls unknown"),
)  # fmt: skip

REGISTRY = Registry(
    [
        Metric("scenario", "scenario", LABEL, _NEITHER, "the scenario's name", "run",
               reduce=Reduce.SAME, contract=True),
        Metric("policy", "map policy", LABEL, _NEITHER, "the map server's policy", "run",
               column="policy", reduce=Reduce.SAME, contract=True,
               views=_views(View.RUN_TABLE)),
        Metric("seed", "seed", LABEL, _NEITHER, "the run's seed", "run", reduce=Reduce.NONE,
               contract=True),
        Metric("units", "units", COUNT, _NEITHER, "drive units in the fleet", "run",
               reduce=Reduce.SAME, contract=True),
        Metric("phantom_freezes", "phantom freezes", COUNT, _LOWER,
               "freezes with phantom seconds: the planner got through on ground truth",
               "freezes", views=_TITLED, contract=True),
        Metric("phantom_freeze_seconds", "phantom freeze time", SECONDS, _LOWER,
               "the freezes' phantom seconds, summed", "freezes", column="phantom s",
               views=_TITLED | {View.PARETO}, contract=True),
        Metric("true_block_freezes", "true blocks", COUNT, _LOWER,
               "freezes with true-block seconds: ground truth blocked the way too",
               "freezes", views=_TITLED, contract=True),
        Metric("true_block_seconds", "true-block time", SECONDS, _LOWER,
               "the freezes' true-block seconds, summed", "freezes", column="true block s",
               views=_TITLED),
        Metric("stale_free_plans", "stale-free plans", COUNT, _LOWER,
               "plans whose legs cross a cell lethal in ground truth", "plans",
               views=_TITLED | {View.PARETO}, contract=True),
        Metric("inscribed_plans", "inscribed plans", COUNT, _LOWER,
               "plans that cross a truly inscribed cell and no lethal one", "plans",
               views=_TITLED),
        Metric("collisions", "collisions", COUNT, _LOWER,
               "the fleet's collision incidents (contacts of a unit with one thing no more "
               "than 2 s apart are one)", "collisions",
               views=_TITLED, contract=True),
        Metric("scenario_collisions", "scenario collisions", COUNT, _NEITHER,
               "the scenario's collision incidents (a person or object walking into a unit)",
               "collisions", views=_views(View.FOXGLOVE)),
        Metric("collision_seconds", "collision time", SECONDS, _LOWER,
               "the fleet's incidents' durations, summed", "collisions", column="collision s",
               views=_views(View.COMPARE)),
        Metric("collision_contacts", "collision contacts", COUNT, _LOWER,
               "the contacts of the fleet's incidents", "collisions"),
        Metric("tasks_completed", "tasks done", COUNT, _HIGHER, "trips completed",
               "throughput", column="tasks", views=_TITLED, contract=True),
        Metric("trips_per_unit_hour", "trips per unit-hour", TRIP_RATE, _HIGHER,
               "`tasks_completed / (units x sim_seconds / 3600)`", "throughput",
               column="trips/unit-h", views=_COMPARED | {View.REPORT_TABLE}, contract=True),
        Metric("ideal_trip_s", "ideal trip (mean)", SECONDS, _NEITHER,
               "mean over completed trips of the trip's ideal time; null if no trip completed",
               "throughput", views=_THROUGHPUT, contract=True),
        Metric("trip_time_ratio", "actual / ideal trip", RATIO, _LOWER,
               "mean over completed trips of `actual / ideal`, `actual = done - assigned`; "
               "null if none", "throughput", column="actual/ideal", decimals=2,
               views=_views(View.RUN_TABLE, View.REPORT_TABLE), contract=True),
        Metric("fleet_efficiency", "fleet efficiency", SHARE, _HIGHER,
               "sum of the ideal times of completed trips / (`units x sim_seconds`)",
               "throughput", column="efficiency", decimals=2,
               views=_COMPARED | {View.REPORT_TABLE}, contract=True),
        Metric("moving_share", "moving, with a task", SHARE, _HIGHER,
               "over unit-ticks in which the unit has a task: the share in which it translates "
               "(drive speed > 0); null if no unit ever had a task", "throughput",
               decimals=2, views=_THROUGHPUT, contract=True),
        Metric("mean_speed_moving", "mean speed moving", SPEED, _HIGHER,
               "mean drive speed over the unit-ticks in which a unit translates, with or "
               "without a task; null if none moved", "throughput", decimals=2,
               views=_THROUGHPUT, contract=True),
        Metric("trips_returned", "trips returned", COUNT, _LOWER,
               "attempts handed back to the queue: the trip had no route for "
               "`tasks.return_after`", "throughput", views=_THROUGHPUT),
        Metric("trips_retried", "trips retried", COUNT, _NEITHER,
               "attempts at a trip that had been returned before", "throughput",
               views=_THROUGHPUT),
        Metric("returned_s", "time in returned trips", UNIT_SECONDS, _LOWER,
               "the time of the returned attempts, from their assignment to their return: "
               "time lost to blocked work", "throughput", views=_THROUGHPUT),
        Metric("trips_free_run", "trips, congestion-free", COUNT, _NEITHER,
               "the trips the run's congestion-free replay completes by its end: the same "
               "trips, releases, dispatcher and breakdowns, every trip driven alone in its "
               "ideal time (docs/throughput.md); what the floor allows", "throughput",
               views=_THROUGHPUT),
        Metric("trips_of_free_run", "trips of congestion-free", SHARE, _HIGHER,
               "`tasks_completed / trips_free_run`; null when that is 0", "throughput",
               decimals=2, views=_THROUGHPUT),
        *(
            Metric(f"wait_s.{cause}", f"standing, {cause}", UNIT_SECONDS, better,
                   f"unit-seconds units with a task stood still (speed 0): {why}",
                   "throughput", views=_THROUGHPUT, contract=cause != "turn")
            for cause, better, why in _WAIT_CAUSES
        ),
        Metric("time_to_clear_s", "time to clear", SECONDS, _LOWER,
               "per removed (or moved) object, from its removal until the shared costmap no "
               "longer holds a lethal cell where it was (null: never); a run's number is the "
               "mean of those that cleared", "clearing", column="time to clear s",
               read=Read.LIST_MEAN, views=_COMPARED, contract=True),
        *(
            Metric(f"map_truth.{name}", name.replace("_", " "), unit, _LOWER,
                   f"{meaning}, `{{mean, final}}` over the map reads (a run's number: the mean)",
                   "map_truth", read=Read.MEAN_FIELD, decimals=decimals, optional=True,
                   contract=True, views=_views(View.COMPARE, *more))
            for name, unit, decimals, more, meaning in _MAP_TRUTH
        ),
        Metric("replans", "replans", COUNT, _LOWER,
               "recoveries and route changes (navigators' replans and reroutes, the "
               "coordinator's reroutes)", "throughput", views=_views(View.REPORT_TITLE),
               contract=True),
        Metric("deadlocks", "deadlocks", COUNT, _LOWER,
               "wait-for cycles the lane coordinator found", "throughput",
               views=_views(View.REPORT_TITLE), contract=True),
        Metric("scans_fused", "scans fused", COUNT, _NEITHER,
               "scans the map server took in", "run", contract=True),
        Metric("events", "events", COUNT, _NEITHER, "scenario events that happened", "run",
               views=_views(View.FOXGLOVE)),
        Metric("frozen_units", "frozen units", COUNT, _LOWER,
               "units frozen at the moment (the replay's `/metrics` only)", "run",
               views=frozenset({View.FOXGLOVE})),
        Metric("sim_seconds", "sim time", SECONDS, _NEITHER, "simulated time the run lasted",
               "run", reduce=Reduce.SAME, decimals=0, views=_views(View.REPORT_TITLE),
               contract=True),
        Metric("wall_seconds", "wall time", SECONDS, _LOWER,
               "wall-clock time of the run loop (no server start-up)", "run", contract=True),
    ]
)  # fmt: skip
