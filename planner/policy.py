"""Lane coordination policies: the interface the coordinator drives, and their registry.

A policy is an object with four hooks. ``LaneCoordinator`` (``planner.coordinator``)
calls them in its policy set's order, on the shared ``CoordinationState``
(``planner.coordination_state``), the way ``LayeredCostmap`` drives its layers
(``mapserver.costmap.layers``); policies never call one another:

1. ``lanes_blocked(state, tick, blocked)``: on ``refresh``, with the lanes the costmap
   newly blocks (before units with no route try the changed graph again).
2. ``approaching(state, tick, unit, to_head)``: on ``tick``, for each unit driving an
   edge and not yet arrived, ``to_head`` [m] from the edge's head, in natural unit
   order as their progress is taken.
3. ``decide(state, tick, ready)``: on ``tick``, after progress, with the units ready to
   decide (at a node with a route to drive, or stopped on a blocked lane to turn back),
   in natural unit order; returns the ones it left to the policies after it.
4. ``settle(state, tick)``: on ``tick``, after every ``decide`` (deadlock breaking).

``CoordinationPolicy`` is the base class: every hook does nothing, a policy overrides
the ones it needs. A policy set is named (``coordination.policy`` of a scenario file,
``LaneCoordinator(policy=...)``) and made by its factory from the coordinator's
``CoordinatorSettings``: a new policy is one module with its class and one
``register_policy`` call (the built-in sets are registered in ``planner.policy_sets``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from planner.coordination_state import CoordinationState, CoordinatorSettings, Tick, Unit
from planner.lane_graph import Lane

__all__ = [
    "CoordinationPolicy",
    "PolicyFactory",
    "make_policies",
    "policy_names",
    "register_policy",
]


class CoordinationPolicy:
    """One lane coordination policy (module docstring); every hook does nothing here."""

    name: str = "policy"

    def lanes_blocked(self, state: CoordinationState, tick: Tick, blocked: set[Lane]) -> None:
        """React to lanes the costmap newly blocks (phase 1, on ``refresh``)."""
        return None

    def approaching(self, state: CoordinationState, tick: Tick, unit: Unit, to_head: float) -> None:
        """A moving unit is ``to_head`` [m] from its edge's head (phase 2)."""
        return None

    def decide(self, state: CoordinationState, tick: Tick, ready: list[Unit]) -> list[Unit]:
        """Grant, or make wait, the ready units it handles (phase 3); the rest go on."""
        return ready

    def settle(self, state: CoordinationState, tick: Tick) -> None:
        """Look at the tick's outcome once every unit decided (phase 4)."""
        return None


PolicyFactory = Callable[[CoordinatorSettings], Sequence[CoordinationPolicy]]
"""Makes a policy set, in driving order, from the coordinator's settings."""

_REGISTRY: dict[str, PolicyFactory] = {}


def register_policy(name: str, factory: PolicyFactory) -> None:
    """Make policy set ``name`` selectable (``LaneCoordinator(policy=name)``, a scenario's
    ``coordination.policy``). A name is registered once."""
    if not isinstance(name, str) or not name.isidentifier():
        raise ValueError(f"a policy name must be an identifier, got {name!r}")
    if name in _REGISTRY:
        raise ValueError(f"policy {name!r} is registered already")
    _REGISTRY[name] = factory


def policy_names() -> tuple[str, ...]:
    """Every registered policy set, in registration order (the default first)."""
    return tuple(_REGISTRY)


def make_policies(name: str, settings: CoordinatorSettings) -> tuple[CoordinationPolicy, ...]:
    """The policies of set ``name`` for ``settings``, in driving order."""
    factory = _REGISTRY.get(name)
    if factory is None:
        raise ValueError(f"policy must be one of {', '.join(_REGISTRY)}, got {name!r}")
    return tuple(factory(settings))
