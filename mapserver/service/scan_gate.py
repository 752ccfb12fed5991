"""Which submitted scans the map takes: the state checks of ingest, a group at a time.

A scan is taken when its unit's stamps do not go backwards, its sensor is on the map and
its stamp is not ahead of the map's clock (``map_clock``). The same unit, stamp and scan
again (a retry) is answered with that scan's acknowledgement and not taken twice; another
scan at a stamp the unit already used is refused (409). Checks run on a group's own copy
of the state (``GroupCheck``): a refused submission changes nothing, and the group's
state becomes the gate's only once its scans are journaled (``commit``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from mapserver.core.errors import FleetmapError
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Scan, ScanError
from mapserver.core.text import quote
from mapserver.service.map_clock import MapClock


class IngestError(FleetmapError, Exception):
    """A submission refused as a whole: ``status`` (409, 422, 503) and a ``detail``."""

    def __init__(self, status: int, detail: str) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail

    def __reduce__(self) -> tuple:
        """Pickled whole (the map process sends refusals to the front)."""
        return (type(self), (self.status, self.detail))


@dataclass(frozen=True)
class Ack:
    """An accepted scan: its journal ``seq`` and the map version that includes it."""

    seq: int
    map_version: int


@dataclass(frozen=True)
class UnitLatest:
    """A unit's newest scan: its stamp [s], the scan while its group is checked (None
    once journaled: read back from the journal when needed) and ack (None while it waits
    in its group at ``slot``, its index among the group's new scans). Neither the scan
    nor its digest is kept past its group: a scan repeated at its unit's latest stamp (a
    retry, or a 409) is compared with the journaled one, so a scan taken is never hashed
    and the gate holds a few numbers per unit however many unit ids have posted."""

    stamp: float
    scan: Scan | None
    ack: Ack | None = None
    slot: int | None = None


FindScan = Callable[[str, float], "tuple[int, Mapping[str, Any]] | None"]


class ScanGate:
    """The state the checks read: each unit's latest scan and the map's clock.

    geometry: the map (a sensor must be on it). clock: the map's clock, resumed at the
    restored map's stamp. unit_stamps: each unit's largest journaled stamp [s].
    find_scan: ``(unit_id, stamp) -> (seq, scan object) | None`` from the journal, to
    answer a retry of a scan this process has not seen (after a restart).
    max_beams: the scan validator's bound, for scans read back from the journal.
    """

    def __init__(
        self,
        geometry: GridGeometry,
        clock: MapClock,
        unit_stamps: Mapping[str, float],
        find_scan: FindScan,
        max_beams: int,
    ) -> None:
        self.geometry = geometry
        self.clock = clock
        self._latest = {unit: UnitLatest(stamp, None) for unit, stamp in unit_stamps.items()}
        self._find_scan = find_scan
        self._max_beams = max_beams

    def open_group(self) -> GroupCheck:
        """A group's checks on a copy of the state (the caller holds the map's lock)."""
        return GroupCheck(self)


class GroupCheck:
    """The checks of one group of submissions: ``admit`` each, journal ``new``, then
    ``commit`` the acks (or ``abandon`` when the journal failed)."""

    def __init__(self, gate: ScanGate) -> None:
        self._gate = gate
        self._latest = dict(gate._latest)
        self._clock_before = gate.clock.state()
        self.new: list[Scan] = []  # the group's scans to journal, in order

    def admit(self, scans: list[Scan]) -> IngestError | list[UnitLatest]:
        """Check a submission (all or none). Accepted: the entry answering each scan (a
        retry answers with its original's). Refused: why, and nothing changed."""
        clock = self._gate.clock
        # A refusal of the first scan has changed nothing yet: only a submission of several
        # scans needs a copy to go back to (most are one scan: no O(units) copy per scan).
        saved = (clock.state(), dict(self._latest), len(self.new)) if len(scans) > 1 else None
        entries: list[UnitLatest] = []
        for i, scan in enumerate(scans):
            where = f"scans[{i}]." if len(scans) > 1 else ""
            outcome = self._check(scan, where, self._latest.get(scan.unit_id))
            if isinstance(outcome, IngestError):
                if saved is not None:
                    clock_state, self._latest, new_before = saved
                    clock.restore(clock_state)
                    del self.new[new_before:]
                return outcome
            if outcome is None:  # a new scan
                outcome = UnitLatest(scan.stamp, scan, slot=len(self.new))
                self.new.append(scan)
                clock.observe(scan.stamp)
            self._latest[scan.unit_id] = outcome
            entries.append(outcome)
        return entries

    def commit(self, acks: list[Ack]) -> None:
        """The group's new scans were journaled with these acks: its state is the gate's."""
        for unit, entry in self._latest.items():
            if entry.slot is not None:
                self._latest[unit] = UnitLatest(entry.stamp, None, acks[entry.slot])
        self._gate._latest = self._latest

    def abandon(self) -> None:
        """Nothing of the group was journaled: the clock forgets what it observed."""
        self._gate.clock.restore(self._clock_before)

    @staticmethod
    def answers(entries: list[UnitLatest], acks: list[Ack]) -> list[Ack]:
        """The acks of one admitted submission, given the group's new acks."""
        return [e.ack if e.ack is not None else acks[e.slot] for e in entries]

    def _check(
        self, scan: Scan, where: str, last: UnitLatest | None
    ) -> IngestError | UnitLatest | None:
        """One scan: None (new, acceptable), its unit's latest entry (a retry of that very
        scan) or why it is refused."""
        if last is not None and scan.stamp <= last.stamp:
            repeated = self._repeat_of(scan, last) if scan.stamp == last.stamp else None
            if repeated is not None:
                return repeated
            if scan.stamp == last.stamp:
                return IngestError(
                    409,
                    f"{where}stamp: unit {quote(scan.unit_id)} already sent another scan at "
                    f"stamp {scan.stamp} (a retry must repeat the scan exactly)",
                )
            return IngestError(
                409,
                f"{where}stamp: unit {quote(scan.unit_id)} already sent stamp {last.stamp}, "
                f"stamps must not go backwards, got {scan.stamp}",
            )
        geometry = self._gate.geometry
        if not geometry.contains_point(scan.pose.x, scan.pose.y):
            xmin, ymin, xmax, ymax = geometry.bounds
            return IngestError(
                422,
                f"{where}pose: the sensor must be on the map [{xmin}, {xmax}) x "
                f"[{ymin}, {ymax}), got ({scan.pose.x}, {scan.pose.y})",
            )
        lead = self._gate.clock.check(scan.stamp)
        if lead is not None:
            return IngestError(422, f"{where}stamp: {lead.describe()}")
        return None

    def _repeat_of(self, scan: Scan, last: UnitLatest) -> UnitLatest | None:
        """``last`` (with its ack) when ``scan`` is that very scan again (equal digests),
        else None. A journaled scan is read back from the journal (its ack kept; after a
        restart, made from its seq)."""
        if last.scan is None:
            found = self._gate._find_scan(scan.unit_id, scan.stamp)
            if found is None:
                return None
            seq, body = found
            try:
                stored = Scan.from_dict(body, max_beams=self._gate._max_beams)
            except ScanError:  # not readable as a scan now (a lower max_beams): not a repeat
                return None
            last = UnitLatest(last.stamp, stored, last.ack or Ack(seq, seq))
        return last if scan.digest() == last.scan.digest() else None
