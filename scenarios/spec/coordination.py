"""The ``coordination`` section of a scenario file: how the fleet is coordinated.

::

    coordination:
      policy: pibt           # or reserve_ahead (the default)
      segment_m: 4.0         # lanes split every 4 m (null: junction to junction)
      reserve_ahead_m: null  # null: the braking distance + 1 m; 0: on arrival only
      clear_m: null          # null: the unit's diameter + 0.2 m
      arrive_tol: 0.1
      retry_s: 1.0
      back_off_hops: 3
      lane_refresh_s: 1.0
      lanes_from: costmap    # or server
      dispatch: nearest      # or first

``policy`` is a registered policy set (``planner.policy.policy_names``; built in:
``reserve_ahead``, a waiting unit is granted its next lane as soon as it is free and
wait-for cycles are broken when found; ``pibt``, priority inheritance with backtracking,
``planner.policy_pibt``). The other keys are the coordinator's settings
(``planner.coordination_state.CoordinatorSettings``) and how the run feeds it: the lane
graph's ``segment_m`` [m], how often it re-reads lane costs (``lane_refresh_s`` [s]) and
from where (``lanes_from``), and which idle unit gets a released trip (``dispatch``,
``scenarios.run.dispatch``). docs/scenarios.md documents each. A bad value is an error
naming the field, the value and the allowed range; an unknown key names the closest.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Any, Literal

from pydantic import Field, ValidatorFunctionWrapHandler, WrapValidator
from pydantic_core import PydanticCustomError

from mapserver.service.validation import Section, number, reworded
from planner.coordination_state import CoordinatorSettings
from planner.coordinator import POLICIES
from planner.policy import policy_names

DEFAULT_COORDINATION = POLICIES[0]
DISPATCH_RULES = ("first", "nearest")
"""Which idle unit gets a released trip (``scenarios.run.dispatch``)."""
LANE_SOURCES = ("costmap", "server")
"""Where the coordinator reads lane costs: the costmap the fleet last read, or a
``POST /v1/query/segments`` to the map server per refresh."""
RESERVE_MARGIN_M = 1.0
"""[m] how much earlier than its braking distance a unit asks for its next lanes (when
``reserve_ahead_m`` is not given)."""
CLEAR_MARGIN_M = 0.2
"""[m] beyond the unit's diameter at which a leaving unit releases a node (when
``clear_m`` is not given)."""

_DEFAULTS = CoordinatorSettings()


def _registered(value: Any, handler: ValidatorFunctionWrapHandler) -> Any:
    names = policy_names()
    reason = "must be one of " + ", ".join(names)
    if not isinstance(value, str) or value not in names:
        raise PydanticCustomError("invalid", reason)
    return handler(value)


CoordinationPolicy = Annotated[
    str,
    WrapValidator(_registered),
    Field(json_schema_extra={"enum": list(POLICIES)}),
]
"""A registered lane coordination policy's name (``planner.policy.policy_names``)."""


def _choice(options: tuple[str, ...]) -> Any:
    return Annotated[Literal[options], reworded("must be one of " + ", ".join(options))]


@dataclass(frozen=True)
class CoordinationSpec:
    """The validated ``coordination`` section (module docstring): None for ``clear_m``
    and ``reserve_ahead_m`` means derived from the units' drive (``settings``)."""

    policy: str = DEFAULT_COORDINATION
    segment_m: float | None = 4.0
    reserve_ahead_m: float | None = None
    clear_m: float | None = None
    arrive_tol: float = _DEFAULTS.arrive_tol
    retry_s: float = _DEFAULTS.retry_s
    back_off_hops: int = _DEFAULTS.back_off_hops
    lane_refresh_s: float = 1.0
    lanes_from: str = LANE_SOURCES[0]
    dispatch: str = "nearest"

    def settings(
        self, radius: float, braking_m: float, speed: float = _DEFAULTS.speed
    ) -> CoordinatorSettings:
        """The coordinator's settings for units of ``radius`` [m] that stop within
        ``braking_m`` [m]: ``clear_m`` defaults to the diameter + ``CLEAR_MARGIN_M``,
        ``reserve_ahead_m`` to the braking distance + ``RESERVE_MARGIN_M``."""
        clear_m = 2.0 * radius + CLEAR_MARGIN_M if self.clear_m is None else self.clear_m
        ahead = self.reserve_ahead_m
        if ahead is None:
            ahead = braking_m + RESERVE_MARGIN_M
        return CoordinatorSettings(
            speed=speed,
            clear_m=clear_m,
            arrive_tol=self.arrive_tol,
            retry_s=self.retry_s,
            reserve_ahead_m=ahead,
            back_off_hops=self.back_off_hops,
        )


class CoordinationFields(Section):
    """The ``coordination`` section as written (module docstring)."""

    policy: CoordinationPolicy = DEFAULT_COORDINATION
    segment_m: number("metres", gt=0) | None = CoordinationSpec.segment_m
    reserve_ahead_m: number("metres", ge=0) | None = None
    clear_m: number("metres", gt=0) | None = None
    arrive_tol: number("metres", gt=0) = CoordinationSpec.arrive_tol
    retry_s: number("seconds", gt=0) = CoordinationSpec.retry_s
    back_off_hops: number("edges", integer=True, ge=1, le=100) = CoordinationSpec.back_off_hops
    lane_refresh_s: number("seconds", gt=0) = CoordinationSpec.lane_refresh_s
    lanes_from: _choice(LANE_SOURCES) = CoordinationSpec.lanes_from
    dispatch: _choice(DISPATCH_RULES) = CoordinationSpec.dispatch

    def build(self) -> CoordinationSpec:
        """The ``CoordinationSpec`` of these values."""
        return CoordinationSpec(**self.model_dump())
