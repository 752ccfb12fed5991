"""The unit board: the latest published state of each unit, for the viewer.

Fleets publish their units' poses, planned paths and freezes with ``POST /v1/units``;
``GET /v1/units`` reads them back. The board keeps one state per ``unit_id`` in memory
(it is not journaled: a restarted server starts with an empty board and fills again as
units publish). A unit's stamps must not go backwards (409), as for scans.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence

from mapserver.api.schemas import UnitState
from mapserver.core.errors import FleetmapError
from mapserver.core.text import quote

MAX_TRACKED_UNITS = 4096  # distinct unit ids held at most


class UnitBoardError(FleetmapError, Exception):
    """A post refused as a whole: ``status`` (409, 422) and a ``detail`` naming the field."""

    def __init__(self, status: int, detail: str) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail


class UnitBoard:
    """The latest state per unit; ``capacity`` bounds the distinct unit ids held."""

    def __init__(self, capacity: int = MAX_TRACKED_UNITS) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be at least one unit, got {capacity!r}")
        self.capacity = capacity
        self._states: dict[str, UnitState] = {}
        self._lock = threading.Lock()

    def publish(self, states: Sequence[UnitState]) -> int:
        """Take ``states`` (all or none); returns how many units the board now holds.

        Raises UnitBoardError: 422 when a unit appears twice in ``states``, 409 when a
        unit's stamp [s] is older than the one it last published or when new units would
        exceed ``capacity``.
        """
        with self._lock:
            self._check(states)
            for state in states:
                self._states[state.unit_id] = state
            return len(self._states)

    def latest(self) -> list[UnitState]:
        """Every unit's latest state, ordered by ``unit_id``."""
        with self._lock:
            return [self._states[unit_id] for unit_id in sorted(self._states)]

    def _check(self, states: Sequence[UnitState]) -> None:
        first: dict[str, int] = {}
        for i, state in enumerate(states):
            if state.unit_id in first:
                raise UnitBoardError(
                    422,
                    f"units[{i}].unit_id: each unit at most once per post "
                    f"(also units[{first[state.unit_id]}]), got {quote(state.unit_id)}",
                )
            first[state.unit_id] = i
            held = self._states.get(state.unit_id)
            if held is not None and state.stamp < held.stamp:
                raise UnitBoardError(
                    409,
                    f"units[{i}].stamp: unit {quote(state.unit_id)} already published stamp "
                    f"{held.stamp}, stamps must not go backwards, got {state.stamp}",
                )
        new = [unit_id for unit_id in first if unit_id not in self._states]
        if len(self._states) + len(new) > self.capacity:
            i = first[new[self.capacity - len(self._states)]]
            raise UnitBoardError(
                409,
                f"units[{i}].unit_id: the server tracks at most {self.capacity} units, "
                f"got a new unit {quote(states[i].unit_id)} beyond that",
            )
