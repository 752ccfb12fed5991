"""A scenario's task stream: seeded pick trips from storage locations to stations.

The ``tasks`` section::

    tasks:
      count: 12            # 12 trips, all released at t = 0 (a backlog), or
      rate_per_unit: 0.02  # [1/s] per unit: trips arrive as a Poisson process
      dwell: 3.0           # [s] a unit stands at the pickup, then at the dropoff
      return_after: 30.0   # [s] a trip with no route this long goes back to the queue
      retry_after: 60.0    # [s] and its goal is held this long unless it clears

Semantics (``task_stream``):

- Trip k (id ``t<k>``, from 1) picks up at a storage location and drops off at a
  station, each drawn uniformly at random (storage locations in file order: the
  ``layout.storage`` points, else the pods; stations in file order).
- ``count``: every trip is released at 0. ``rate_per_unit``: trips are released by a
  Poisson process of rate ``rate_per_unit * units.count`` [1/s]; the stream ends with the
  last release before the scenario's duration.
- Trips carry no unit (``unit`` is None): the runner hands the oldest released trip to
  a unit as soon as it is idle (no trip, not broken down), units in id order.
- Each trip draws its numbers in a fixed order (the arrival gap, with a rate; the
  storage location; the station) from a generator seeded by the scenario's seed alone
  (``task_rng``), so the stream does not depend on the policy, on the sim, or on how
  fast the runner consumes it.
- A trip whose goal has had no route for ``return_after`` [s] (null: never) goes back to
  the queue and is tried again when its goal clears or after ``retry_after`` [s]
  (``scenarios.run.trip_queue``, where the defaults are argued).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mapserver.service.validation import Section, number
from scenarios.run.trip_queue import DEFAULT_RETRY_AFTER_S, DEFAULT_RETURN_AFTER_S
from scenarios.spec.yaml_lines import Document

if TYPE_CHECKING:
    from scenarios.spec.scenario import Scenario

Point = tuple[float, float]

DEFAULT_DWELL_S = 3.0
MAX_TASKS = 100_000
"""Most trips a scenario may ask for (``count``, or the expected number at a rate)."""
TASK_STREAM_KEY = 0x7A5C
"""Mixed with the seed so the trips' generator is independent of the sim's."""


@dataclass(frozen=True)
class TaskSpec:
    """The ``tasks`` section: ``count`` trips released at 0, or ``rate_per_unit`` [1/s]
    trips per unit arriving at random (at most one of them; neither: no trips); ``dwell``
    [s] at each stop; a trip with no route for ``return_after`` [s] (None: never) goes
    back to the queue, its goal held for ``retry_after`` [s] unless it clears
    (``scenarios.run.trip_queue``)."""

    count: int | None = None
    rate_per_unit: float | None = None
    dwell: float = DEFAULT_DWELL_S
    return_after: float | None = DEFAULT_RETURN_AFTER_S
    retry_after: float = DEFAULT_RETRY_AFTER_S

    @property
    def enabled(self) -> bool:
        """Whether the scenario has any trips at all."""
        return bool(self.count) or bool(self.rate_per_unit)


@dataclass(frozen=True)
class Task:
    """A pick trip ``task_id``: drive to ``pickup`` (x, y) [m] (storage location
    ``pickup_id``), dwell ``dwell`` [s], drive to ``dropoff`` (station ``dropoff_id``),
    dwell again. Not to be started before ``release`` [s]; ``unit``: the unit it is
    meant for (None: whichever is idle first)."""

    task_id: str
    pickup: Point
    dropoff: Point
    dwell: float
    release: float
    pickup_id: str
    dropoff_id: str
    unit: str | None = None


class TasksFields(Section):
    """The ``tasks`` section of the file (``TaskSpec``)."""

    count: number(integer=True, ge=0, le=MAX_TASKS) | None = None
    rate_per_unit: number("trips per unit per second", ge=0) | None = None
    dwell: number("seconds", ge=0) = DEFAULT_DWELL_S
    return_after: number("seconds", gt=0) | None = DEFAULT_RETURN_AFTER_S
    retry_after: number("seconds", ge=0) = DEFAULT_RETRY_AFTER_S


def parse_tasks(doc: Document, f: TasksFields, units: int, duration: float) -> TaskSpec:
    """The ``tasks`` section for ``units`` units over ``duration`` [s]."""
    where = ("tasks", "rate_per_unit")
    if f.count is not None and f.rate_per_unit is not None:
        raise doc.error(where, "give count or rate_per_unit, not both")
    rate = f.rate_per_unit
    if rate is not None and rate * units * duration > MAX_TASKS:
        expected = rate * units * duration
        raise doc.error(where, f"asks for about {expected:.0f} trips, more than {MAX_TASKS}", rate)
    return TaskSpec(f.count, rate, f.dwell, f.return_after, f.retry_after)


def task_rng(seed: int) -> np.random.Generator:
    """The trips' generator for a scenario seed."""
    return np.random.default_rng(np.random.SeedSequence([TASK_STREAM_KEY, seed]))


def task_stream(scenario: Scenario, rng: np.random.Generator | None = None) -> Iterator[Task]:
    """The scenario's trips in release order (module docstring); ``rng`` defaults to
    ``task_rng(scenario.seed)``. Same scenario and seed, same trips."""
    spec = scenario.tasks
    if not spec.enabled:
        return
    rng = task_rng(scenario.seed) if rng is None else rng
    storage = scenario.storage
    stations = scenario.layout.stations
    rate = (spec.rate_per_unit or 0.0) * scenario.units.count
    release = 0.0
    k = 0
    while spec.count is None or k < spec.count:
        gap = rng.exponential(1.0 / rate) if rate > 0 else 0.0
        source = storage[int(rng.integers(len(storage)))]
        station = stations[int(rng.integers(len(stations)))]
        release += gap
        if spec.count is None and release >= scenario.duration:
            return
        k += 1
        yield Task(
            task_id=f"t{k}",
            pickup=(source.x, source.y),
            dropoff=(station.x, station.y),
            dwell=spec.dwell,
            release=release if spec.count is None else 0.0,
            pickup_id=source.id,
            dropoff_id=station.id,
        )
