"""The built-in lane coordination policy sets, registered by name (``planner.policy``).

- ``reserve_ahead`` (the default): ``ReserveAhead`` (``planner.policy_reserve_ahead``),
  ``BlockedLanes`` (``planner.policy_blocked_lanes``), ``GrantWhenFree``
  (``planner.policy_grants``: a waiting unit is granted its next edge as soon as it is
  free, units in priority order; standing units are moved aside,
  ``planner.policy_standing``) and ``Deadlocks`` (``planner.policy_deadlocks``:
  wait-for cycles broken when found).
- ``pibt``: the same with ``Pibt`` (``planner.policy_pibt``: priority inheritance with
  backtracking, Okumura et al., AIJ 2022) deciding instead of ``GrantWhenFree``; the
  deadlock breaker stays as a safety net.

A new set is one module with its policy class and a ``register_policy`` call, imported
here.
"""

from __future__ import annotations

from planner.coordination_state import CoordinatorSettings
from planner.policy import CoordinationPolicy, register_policy
from planner.policy_blocked_lanes import BlockedLanes
from planner.policy_deadlocks import Deadlocks
from planner.policy_grants import GrantWhenFree
from planner.policy_pibt import Pibt
from planner.policy_reserve_ahead import ReserveAhead

BUILT_IN = ("reserve_ahead", "pibt")
"""The built-in policy sets, the default first."""


def reserve_ahead(settings: CoordinatorSettings) -> tuple[CoordinationPolicy, ...]:
    """The ``reserve_ahead`` set (module docstring), in driving order."""
    return (
        ReserveAhead(settings.reserve_ahead_m),
        BlockedLanes(),
        GrantWhenFree(settings.retry_s),
        Deadlocks(settings.retry_s, settings.back_off_hops),
    )


def pibt(settings: CoordinatorSettings) -> tuple[CoordinationPolicy, ...]:
    """The ``pibt`` set (module docstring), in driving order."""
    return (
        ReserveAhead(settings.reserve_ahead_m),
        BlockedLanes(),
        Pibt(),
        Deadlocks(settings.retry_s, settings.back_off_hops),
    )


register_policy("reserve_ahead", reserve_ahead)
register_policy("pibt", pibt)
