"""The ``coordination`` section of a scenario file: how the lane coordinator decides.

::

    coordination:
      policy: pibt   # or reserve_ahead (the default)

``policy`` is one of ``planner.coordinator.POLICIES``: ``reserve_ahead``, a waiting
unit is granted its next lane as soon as it is free and wait-for cycles are broken when
found (``planner.policy_deadlocks``); ``pibt``, priority inheritance with backtracking
(``planner.policy_pibt``). Any other value is an error naming the field and the value.
"""

from __future__ import annotations

from typing import Annotated, Literal

from mapserver.service.validation import Section, reworded
from planner.coordinator import POLICIES

DEFAULT_COORDINATION = POLICIES[0]

CoordinationPolicy = Annotated[
    Literal[POLICIES],
    reworded("must be one of " + ", ".join(POLICIES)),
]
"""A lane coordination policy's name (``planner.coordinator.POLICIES``)."""


class CoordinationFields(Section):
    """The ``coordination`` section (module docstring)."""

    policy: CoordinationPolicy = DEFAULT_COORDINATION
