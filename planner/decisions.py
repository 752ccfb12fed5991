"""What the lane coordinator decided and why: ``Decision``, its ``Action`` and ``Cause``.

``Action`` and ``Cause`` are ``StrEnum``s: a member is equal to, formats as and
serialises as its string (``Action.BACK_OFF == "back_off"``), so the decision log,
``Decision.to_dict``, replays and the freeze evidence of ``freezes.json`` keep the
strings other tools read (docs/files.md). Code that counts or compares decisions uses
the members, never the strings.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum


class Action(StrEnum):
    """What the coordinator did about a unit."""

    ROUTE = "route"
    """A new task's route."""
    GRANT = "grant"
    """An edge granted."""
    WAIT = "wait"
    """The unit waits (at a node, or stopped on a blocked lane)."""
    REROUTE = "reroute"
    """Its route changed."""
    BACK_OFF = "back_off"
    """Moved out of another unit's way (grants the edge it backs off over)."""
    ARRIVED = "arrived"
    """It reached its goal and parks there."""


class Cause(StrEnum):
    """Why the coordinator did it."""

    REQUEST = "request"
    """A new task."""
    ROUTE = "route"
    """The next edge of the route."""
    NODE_HELD = "node_held"
    """The next node is held by another unit."""
    LANE_HELD = "lane_held"
    """The lane, or its corridor, is held or claimed by another unit."""
    EXIT_HELD = "exit_held"
    """The way out of the crossing ahead is held (do not block the box)."""
    CLEAR_WAY = "clear_way"
    """A standing unit moved aside for a waiting unit (``planner.policy_standing``)."""
    PARKED_UNIT = "parked_unit"
    """Rerouted around standing units."""
    DEADLOCK = "deadlock"
    """Gave way to break a wait-for cycle (``planner.policy_deadlocks``)."""
    DEADLOCK_UNRESOLVED = "deadlock_unresolved"
    """In a wait-for cycle nobody can leave yet."""
    LANE_BLOCKED = "lane_blocked"
    """The costmap blocks a lane of its route (``planner.policy_blocked_lanes``)."""
    NO_ROUTE = "no_route"
    """No route to its goal."""
    LANE_CLEARED = "lane_cleared"
    """The lane graph changed: a unit with no route tries again."""
    GOAL = "goal"
    """Arrived at its goal."""
    PIBT = "pibt"
    """Rerouted by priority inheritance: its next node is taken (``planner.policy_pibt``)."""
    INHERIT = "inherit"
    """Pushed out of a higher-priority unit's way (priority inheritance)."""


ACTIONS = tuple(Action)
"""Every ``Action``, in declaration order."""


@dataclass(frozen=True)
class Decision:
    """One coordinator decision about one unit, at ``time`` [s].

    action: an ``Action``; cause: a ``Cause``; detail: the same in words. edge: the edge
    granted, asked for or reversed onto; waiting_for: the units it waits for (for a
    deadlock, every unit of the cycle); route: the unit's route after the decision.
    """

    time: float
    unit: str
    action: Action
    cause: Cause
    detail: str
    edge: tuple[str, str] | None = None
    waiting_for: tuple[str, ...] = ()
    route: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, object]:
        """Plain JSON-ready form (action and cause as their strings)."""
        return {
            "time": self.time,
            "unit": self.unit,
            "action": self.action.value,
            "cause": self.cause.value,
            "detail": self.detail,
            "edge": list(self.edge) if self.edge else None,
            "waiting_for": list(self.waiting_for),
            "route": list(self.route),
        }
