"""The fleet's clock: how far ahead of the rest of the fleet a scan's stamp may be.

The map's "now" is the latest stamp it fused, and every cell's evidence fades with its
age at "now" (``DecayParams``). A unit whose clock runs ahead would, if believed, age
the whole fleet's evidence to unknown and make their new scans look stale. So no single
unit decides the time; a scan is refused (422) when its stamp ``s`` is ahead of either
reference by more than ``max_lead_s`` [s]:

- **the server's wall clock** (``time.time()``, epoch seconds): stamps are simulated
  seconds from 0 or epoch seconds (docs/http-api.md 2.1), and neither can be ahead of the
  server's wall clock; this bounds the very first scan of an empty map too.
- **the rest of the fleet**: the lower median of the latest stamps of the units heard
  from among the last ``window_scans`` accepted scans (the scan's own unit included at
  its previous stamp). A unit can lead that median by at most ``max_lead_s``; as long as
  fewer than half of the recently heard units are wrong, the median is a correct clock,
  so a bad unit cannot drag it along, not even by small steps (with two units the lower
  median is the slower one). With no unit heard yet, only the wall clock applies.

The rule depends only on the order of accepted scans (and the wall clock, which an
accepted stamp is already behind), so replaying a journal applies it identically: a
journaled scan that breaks it (an old journal written before the rule) is quarantined.
"""

from __future__ import annotations

import bisect
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

DEFAULT_MAX_LEAD_S = 5.0
DEFAULT_WINDOW_SCANS = 1000


@dataclass(frozen=True)
class ClockLead:
    """A stamp refused for leading: the reference it leads and what that reference is."""

    stamp: float
    reference: float
    reference_name: str
    max_lead_s: float

    def describe(self) -> str:
        """The refusal, naming both clocks (for a 422 detail after ``stamp: ``)."""
        return (
            f"leads {self.reference_name} ({self.reference:.6g} s) by "
            f"{self.stamp - self.reference:.6g} s, more than clock.max_lead_s = "
            f"{self.max_lead_s:g} s; check the unit's clock"
        )


class FleetClock:
    """The references of the module docstring, updated with every accepted scan.

    max_lead_s: [s] how far a stamp may lead either reference.
    window_scans: how many of the latest accepted scans decide which units count as
        "the fleet" for the median (units silent longer do not hold the clock back).
    wall_clock: epoch seconds now (``time.time``; a parameter for tests).

    ``state()`` and ``restore(state)`` let a caller take back what it observed for
    scans that were not journaled after all.
    """

    def __init__(
        self,
        max_lead_s: float = DEFAULT_MAX_LEAD_S,
        window_scans: int = DEFAULT_WINDOW_SCANS,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        if not max_lead_s > 0:
            raise ValueError(f"max_lead_s must be > 0 seconds, got {max_lead_s!r}")
        if window_scans < 1:
            raise ValueError(f"window_scans must be >= 1, got {window_scans!r}")
        self.max_lead_s = float(max_lead_s)
        self.window_scans = int(window_scans)
        self.wall_clock = wall_clock
        self._heard: OrderedDict[str, tuple[float, int]] = OrderedDict()  # newest last
        self._stamps: list[float] = []  # the heard units' stamps, sorted
        self._accepted = 0  # scans observed so far

    def fleet_median(self) -> float | None:
        """The lower median [s] of the recently heard units' latest stamps (None: none)."""
        if not self._stamps:
            return None
        return self._stamps[(len(self._stamps) - 1) // 2]

    def check(self, stamp: float) -> ClockLead | None:
        """Why ``stamp`` [s] leads too far, or None when it may be accepted."""
        wall = self.wall_clock()
        if stamp > wall + self.max_lead_s:
            return ClockLead(stamp, wall, "the server's wall clock", self.max_lead_s)
        median = self.fleet_median()
        if median is not None and stamp > median + self.max_lead_s:
            return ClockLead(
                stamp, median, "the fleet's clock (median of its units)", self.max_lead_s
            )
        return None

    def observe(self, unit_id: str, stamp: float) -> None:
        """Record an accepted scan of ``unit_id`` at ``stamp`` [s]."""
        self._accepted += 1
        self._forget(unit_id)
        self._heard[unit_id] = (stamp, self._accepted)
        bisect.insort(self._stamps, stamp)
        oldest = self._accepted - self.window_scans
        while True:  # units silent for window_scans scans no longer count
            unit, (_, heard_at) = next(iter(self._heard.items()))
            if heard_at > oldest:
                return
            self._forget(unit)

    def state(self) -> tuple:
        """An opaque copy of what has been observed."""
        return OrderedDict(self._heard), list(self._stamps), self._accepted

    def restore(self, state: tuple) -> None:
        """Go back to a ``state()``."""
        heard, stamps, accepted = state
        self._heard, self._stamps, self._accepted = OrderedDict(heard), list(stamps), accepted

    def _forget(self, unit_id: str) -> None:
        entry = self._heard.pop(unit_id, None)
        if entry is not None:
            del self._stamps[bisect.bisect_left(self._stamps, entry[0])]
