"""The map's clock: which stamps are ahead of "now", judged against a reference no group
of units controls (docs/map-time.md).

The map's "now" is the latest stamp it fused, and every cell's evidence fades with its
age at "now" (``DecayParams``). A scan whose stamp is ahead of the time would, if
believed, age everybody's evidence, so it is refused (422) when its stamp ``s`` leads
the reference by more than ``max_lead_s`` [s]. The references follow ROS's model of
time (the ROS 2 design article "Clock and Time",
https://design.ros2.org/articles/clock_and_time.html): a real fleet keeps its clocks
synchronised (NTP/PTP) and stamps in epoch seconds; a simulation declares its clock
(``use_sim_time`` with ``/clock``):

1. **The server's wall clock** (``time.time()``, epoch seconds) bounds every stamp: no
   stamp, epoch or simulated, can honestly be ahead of it.
2. **A declared simulation clock** (``declare``: ``PUT /v1/clock``), while it is fresh
   (declared less than ``sim_ttl_s`` [s] of wall time ago), bounds every stamp: the
   simulation's time is the time.
3. **The map's simulated time**, when nothing is declared and the map's newest stamp is
   a simulated one (below ``EPOCH_FLOOR_S``: seconds from 0, not since 1970): it may
   have run on by ``max_sim_rate`` times the wall time since it last advanced (a
   simulation runs faster than real time, and all its units may be silent a while), so
   a simulated stamp may lead that by ``max_lead_s``. An epoch stamp is held to it only
   while it advanced less than ``sim_ttl_s`` ago: a simulation that stopped posting does
   not keep a real fleet with synced clocks off the map.

No rule depends on which units are talking, so a unit that goes quiet, joins late,
reboots, lags or replays a buffer never gets another unit's honest scan refused: a
stamp behind the references is always accepted (its evidence is simply older, and the
fusion never makes a cell's evidence older than it was). A declared clock lapses, and
the map's simulated time runs on with the wall clock, so recovery never needs a
restart.

The rule is applied where scans enter (``scan_gate``), not when a journal is replayed:
the journal holds the scans that were accepted, and replaying them all rebuilds the map.
Only a journaled stamp ahead of the wall clock even at start-up can never have been
accepted (a journal written before any clock rule): replay sets it aside
(``mapserver.store.journal_reading``), since rule 1 holds a stamp once behind the wall.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

from mapserver.core.errors import FleetmapError

DEFAULT_MAX_LEAD_S = 5.0
DEFAULT_SIM_TTL_S = 10.0
DEFAULT_MAX_SIM_RATE = 10.0
EPOCH_FLOOR_S = 1e9
"""[s] Stamps from here on (2001-09-09 in epoch seconds) are epoch stamps; below it,
simulated seconds from the start of a run (or since a unit booted)."""

WALL = "wall"
DECLARED = "declared"
SIMULATED = "simulated"
REFERENCE_NAMES = {
    WALL: "the server's clock",
    DECLARED: "the declared simulation clock",
    SIMULATED: "the map's simulated time",
}
FIXES = {
    WALL: "sync the unit's clock (NTP/PTP); a simulation stamps from 0 or declares its "
    "clock (PUT /v1/clock)",
    DECLARED: "stamp with the simulation's clock, or declare it again (PUT /v1/clock)",
    SIMULATED: "stamp with the simulation's clock; a simulation declares it (PUT /v1/clock)",
}


class ClockDeclarationError(FleetmapError, ValueError):
    """A declared simulation clock that cannot be right (not finite, ahead of the wall)."""


@dataclass(frozen=True)
class Reference:
    """What "now" is for a stamp: ``value`` [s], which clock it is (``WALL``, ...) and,
    for the map's simulated time, how it was reached (``note``)."""

    value: float
    kind: str
    note: str = ""


@dataclass(frozen=True)
class ClockLead:
    """A stamp refused for leading ``reference`` by more than ``max_lead_s`` [s]."""

    stamp: float
    reference: Reference
    max_lead_s: float

    @property
    def offset_s(self) -> float:
        """[s] how far the stamp is ahead of the reference: the unit's clock error."""
        return self.stamp - self.reference.value

    def describe(self) -> str:
        """The refusal after ``stamp: ``, naming the unit's own offset and the fix."""
        kind = self.reference.kind
        return (
            f"{self.stamp!r} is {self.offset_s:.6g} s ahead of "
            f"{REFERENCE_NAMES[kind]} ({round(self.reference.value, 3)!r} s"
            f"{self.reference.note}), "
            "more than "
            f"clock.max_lead_s = {self.max_lead_s:g} s: this unit's clock runs "
            f"{self.offset_s:.6g} s ahead; {FIXES[kind]}"
        )


@dataclass(frozen=True)
class ClockView:
    """The clock's state at one moment: the reference binding, the declared clock ((its
    reading [s], wall seconds since it was declared) or None), the wall clock [s], the
    map's newest stamp [s] (-inf before any scan) and the lead allowed [s]."""

    reference: Reference
    declared: tuple[float, float] | None
    wall: float
    map_stamp: float
    max_lead_s: float


class MapClock:
    """The references of the module docstring, and the map's time they follow.

    max_lead_s: [s] how far a stamp may lead a reference.
    sim_ttl_s: [s] of wall time a declared clock binds after it was declared, and the
        map's simulated time holds epoch stamps after it last advanced.
    max_sim_rate: how many times faster than the wall clock simulated time may have run
        since it last advanced (rule 3).
    wall_clock: epoch seconds now (``time.time``; a parameter for tests).

    ``check`` a stamp, ``observe`` an accepted one; ``state``/``restore`` take back what
    was observed for scans that were not journaled after all. ``declare`` may be called
    from another thread than the checks (it replaces one attribute at once).
    """

    def __init__(
        self,
        max_lead_s: float = DEFAULT_MAX_LEAD_S,
        sim_ttl_s: float = DEFAULT_SIM_TTL_S,
        max_sim_rate: float = DEFAULT_MAX_SIM_RATE,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        for name, value in (
            ("max_lead_s", max_lead_s),
            ("sim_ttl_s", sim_ttl_s),
            ("max_sim_rate", max_sim_rate),
        ):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        self.max_lead_s = float(max_lead_s)
        self.sim_ttl_s = float(sim_ttl_s)
        self.max_sim_rate = float(max_sim_rate)
        self.wall_clock = wall_clock
        self.map_stamp = -math.inf  # [s] the newest accepted stamp: the map's "now"
        self._advanced_at = -math.inf  # [s] wall time when map_stamp last advanced
        self._declared: tuple[float, float] | None = None  # (clock [s], wall [s] then)

    def resume(self, map_stamp: float) -> None:
        """Start from a restored map whose newest stamp is ``map_stamp`` [s], as if it
        had just advanced (its simulated time runs on from now)."""
        self.map_stamp = float(map_stamp)
        self._advanced_at = self.wall_clock()

    def reference(self) -> Reference:
        """The tightest reference binding now: the declared clock or the map's
        simulated time when one binds, else the wall clock."""
        wall = self.wall_clock()
        simulated = self._simulated(wall)
        return simulated if simulated is not None else Reference(wall, WALL)

    def check(self, stamp: float) -> ClockLead | None:
        """Why ``stamp`` [s] leads too far, or None when it may be accepted."""
        wall = self.wall_clock()
        if stamp > wall + self.max_lead_s:
            return ClockLead(stamp, Reference(wall, WALL), self.max_lead_s)
        simulated = self._simulated(wall, epoch=stamp >= EPOCH_FLOOR_S)
        if simulated is not None and stamp > simulated.value + self.max_lead_s:
            return ClockLead(stamp, simulated, self.max_lead_s)
        return None

    def observe(self, stamp: float) -> None:
        """Record an accepted stamp [s]: it may advance the map's time."""
        if stamp > self.map_stamp:
            self.map_stamp = float(stamp)
            self._advanced_at = self.wall_clock()

    def declare(self, now: float) -> None:
        """A simulation's clock reads ``now`` [s] (``PUT /v1/clock``); it may go back (a
        simulation reset) but not ahead of the wall clock by more than ``max_lead_s``."""
        wall = self.wall_clock()
        if isinstance(now, bool) or not isinstance(now, int | float) or not math.isfinite(now):
            raise ClockDeclarationError(f"now: must be a finite number of seconds, got {now!r}")
        if now > wall + self.max_lead_s:
            raise ClockDeclarationError(
                f"now: {float(now)!r} is {now - wall:.6g} s ahead of the server's clock "
                f"({wall:.17g} s), more than clock.max_lead_s = {self.max_lead_s:g} s: a "
                "simulation's clock counts from 0, a real one is synced (NTP/PTP)"
            )
        self._declared = (float(now), wall)

    def declared(self) -> tuple[float, float] | None:
        """(the declared clock [s], wall seconds since it was declared), or None when no
        clock was declared or it lapsed."""
        declared, wall = self._declared, self.wall_clock()
        if declared is None or wall - declared[1] > self.sim_ttl_s:
            return None
        return declared[0], wall - declared[1]

    def view(self) -> ClockView:
        """What ``GET /v1/clock`` shows, read at one moment."""
        return ClockView(
            self.reference(), self.declared(), self.wall_clock(), self.map_stamp, self.max_lead_s
        )

    def state(self) -> tuple[float, float]:
        """An opaque copy of what has been observed."""
        return self.map_stamp, self._advanced_at

    def restore(self, state: tuple[float, float]) -> None:
        """Go back to a ``state()``."""
        self.map_stamp, self._advanced_at = state

    def _simulated(self, wall: float, epoch: bool = False) -> Reference | None:
        """Rule 2 or 3 when one binds at wall time ``wall`` [s] for a stamp (``epoch``:
        an epoch stamp, which rule 3 holds only while the simulation posts), else None."""
        declared = self._declared
        if declared is not None and wall - declared[1] <= self.sim_ttl_s:
            return Reference(declared[0], DECLARED)
        if not (math.isfinite(self.map_stamp) and self.map_stamp < EPOCH_FLOOR_S):
            return None
        since = max(wall - self._advanced_at, 0.0)
        if epoch and since > self.sim_ttl_s:
            return None
        note = (
            f": {self.map_stamp!r} s when it last advanced, {since:.3g} s of wall time ago, "
            f"and at most clock.max_sim_rate = {self.max_sim_rate:g} times faster since"
        )
        return Reference(self.map_stamp + self.max_sim_rate * since, SIMULATED, note)
