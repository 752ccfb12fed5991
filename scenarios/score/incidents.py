"""Collision incidents: contacts grouped as an operator counts them, and what the map held
where the unit touched when it planned the path it was driving.

The simulator reports every contact a unit *begins* (``fleet.sim.CollisionEvent``) and,
each step, the contacts it still holds (``StepResult.contacts``). A real drive's bumper
stops it (``DriveUnit.halt``: path dropped, put back to where it first touched); its
agent plans again within ``replan_s`` (0.5 s) and, if the map still shows the way free,
drives into the same rack again. One such wedge is one incident, not one collision per
attempt:

- an *incident* is the contacts of one unit with one other thing (an obstacle or a unit)
  of one cause (``"fleet"``, ``"scenario"``) whose gaps are at most ``INCIDENT_GAP_S``
  (2 s: four replans, longer than a bumper retry and shorter than a turn in place, 4 s):
  a contact begun, or still held, within 2 s of the incident's last contact extends it;
- ``start``: its first contact [s]; ``end``: its last step in contact [s] (a contact
  began or was held then); ``duration = end - start`` (0 for a single bump);
  ``contacts``: the contacts begun in it.

What the map held (``PlanContext``): when the unit planned the path it was driving at its
first contact (the costmap it planned on, by its ``version``), the cells where it touched
(``contact_cells``: the touched thing's cells under the unit's body grown by a cell),
each with its cost class in that costmap (``map``) and in ground truth at that time
(``truth``): a rack cell the map held ``free`` while truth held it ``lethal`` is a map
that forgot the rack; ``inscribed`` in the map, a plan that drove too close.

Metrics (``collision_counts``): ``collisions`` counts the fleet's incidents,
``scenario_collisions`` the scenario's, ``collision_seconds`` [s] sums the durations of
the fleet's, ``collision_contacts`` counts the fleet's contacts.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from mapserver.core.costvalues import FREE, INSCRIBED, LETHAL, UNKNOWN
from mapserver.core.geometry import GridGeometry
from scenarios.score.metric_registry import feeds

if TYPE_CHECKING:
    from fleet.sim import CollisionEvent  # imports pybullet

INCIDENT_GAP_S = 2.0  # [s] module docstring
FLEET = "fleet"
SCENARIO = "scenario"
SECONDS_DECIMALS = 3  # [s] 1 ms


def cost_class(cost: int) -> str:
    """A Nav2 cost's class in words: ``free`` (0), ``inflated`` (1..252), ``inscribed``,
    ``lethal`` (an occupied cell) or ``unknown``."""
    names = {int(FREE): "free", int(INSCRIBED): "inscribed", int(LETHAL): "lethal",
             int(UNKNOWN): "unknown"}  # fmt: skip
    return names.get(int(cost), "inflated")


@dataclass(frozen=True)
class ContactCell:
    """A cell where the unit touched: centre (x, y) [m], its cost class in the costmap the
    unit planned on (``map``) and in ground truth then (``truth``)."""

    x: float
    y: float
    map: str
    truth: str


@dataclass(frozen=True)
class PlanContext:
    """The plan the unit was driving when an incident began: made at ``stamp`` [s] on the
    costmap of ``map_version``, and the contact cells as that map and the truth held them."""

    stamp: float
    map_version: int
    cells: tuple[ContactCell, ...]


@dataclass
class CollisionIncident:
    """One incident (module docstring): unit, what it touched (id and kind), cause, start
    and end [s], the contacts begun in it, where the unit stood at its first contact
    (x, y [m]) and the plan it was driving then (None: it had none)."""

    unit_id: str
    other_id: str
    other_kind: str
    cause: str
    start: float
    end: float
    x: float
    y: float
    contacts: int = 1
    plan: PlanContext | None = None

    @property
    def duration(self) -> float:
        """[s] from the first contact to the last step in contact."""
        return self.end - self.start


@dataclass
class IncidentTracker:
    """Groups a run's contacts into incidents, step by step (module docstring)."""

    gap_s: float = INCIDENT_GAP_S
    incidents: list[CollisionIncident] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._last: dict[tuple[str, str, str], CollisionIncident] = {}

    def observe(
        self,
        now: float,
        events: Sequence[CollisionEvent],
        held: Iterable[tuple[str, str]],
        plan: Callable[[CollisionEvent], PlanContext | None] = lambda e: None,
    ) -> list[CollisionIncident]:
        """One step at ``now`` [s]: the contacts begun (``events``) and the (unit, other)
        pairs in contact at its end (``held``); ``plan(event)`` gives a new incident its
        ``PlanContext``. Returns the incidents begun in this step."""
        begun = []
        for event in events:
            key = (event.unit_id, event.other_id, event.cause)
            last = self._last.get(key)
            if last is not None and event.time - last.end <= self.gap_s + 1e-9:
                last.end = event.time
                last.contacts += 1
                continue
            incident = CollisionIncident(
                event.unit_id, event.other_id, event.other_kind, event.cause, event.time,
                event.time, event.x, event.y, plan=plan(event),
            )  # fmt: skip
            self._last[key] = incident
            self.incidents.append(incident)
            begun.append(incident)
        for unit_id, other_id in held:
            for cause in (FLEET, SCENARIO):
                last = self._last.get((unit_id, other_id, cause))
                if last is not None and now - last.end <= self.gap_s + 1e-9:
                    last.end = max(last.end, now)
        return begun


@feeds("collisions", "scenario_collisions", "collision_seconds", "collision_contacts")
def collision_counts(incidents: Sequence[CollisionIncident]) -> dict[str, int | float]:
    """``collisions``, ``scenario_collisions``, ``collision_seconds`` [s] and
    ``collision_contacts`` of ``incidents`` (module docstring), for ``metrics.json``."""
    fleet = [i for i in incidents if i.cause != SCENARIO]
    return {
        "collisions": len(fleet),
        "scenario_collisions": len(incidents) - len(fleet),
        "collision_seconds": round(sum(i.duration for i in fleet), SECONDS_DECIMALS),
        "collision_contacts": sum(i.contacts for i in fleet),
    }


def contact_cells(
    geometry: GridGeometry,
    x: float,
    y: float,
    radius: float,
    distance: Callable[[np.ndarray, np.ndarray], np.ndarray],
) -> list[tuple[int, int]]:
    """(col, row) of the cells where a unit of ``radius`` [m] centred at (x, y) [m] touches
    a thing whose ``distance(xs, ys)`` [m] from points is 0 inside it: the cells whose
    centres lie within ``radius`` plus a cell of (x, y) and inside the thing; when no
    centre is inside (a thing thinner than a cell), the nearest such cells."""
    res = geometry.resolution
    reach = radius + res
    col0, row0 = geometry.world_to_cell(x - reach, y - reach)
    col1, row1 = geometry.world_to_cell(x + reach, y + reach)
    cols, rows = np.meshgrid(np.arange(col0, col1 + 1), np.arange(row0, row1 + 1))
    cols, rows = cols.ravel(), rows.ravel()
    xs = geometry.origin_x + (cols + 0.5) * res
    ys = geometry.origin_y + (rows + 0.5) * res
    near = np.hypot(xs - x, ys - y) <= reach
    if not near.any():
        return []
    cols, rows, gaps = cols[near], rows[near], np.asarray(distance(xs[near], ys[near]))
    pick = gaps <= max(float(gaps.min()), 0.0) + 1e-9
    return list(zip(cols[pick].tolist(), rows[pick].tolist(), strict=True))
