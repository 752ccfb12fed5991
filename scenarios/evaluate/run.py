"""One pass over a recording: every map under test fused in lockstep, and measured.

The recording is read once (a second, earlier pass sizes the grid when none is given:
``grid_from_args``). For each scan, in order:

1. the reads due before it: at each read stamp ``t_k = t_first + k * read_every`` [s]
   strictly before this scan's stamp, the ghost candidates of the previous scan (the
   one current at ``t_k``) are read from every map as it stands after that scan, at
   ``t_k`` (a fading map fades up to the read);
2. the scan's sight (``sight.py``): its returns, its floor, the cells it sees through;
3. the scan fused into each map, each fusion timed alone.

After the last scan, the reads due up to its stamp, then each map's final states at that
stamp give the rest of the measures (``measures.py``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from mapserver.core.belief import CellState, load_fusion_kernels
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Scan
from scenarios.evaluate.maps import MapUnderTest
from scenarios.evaluate.measures import (
    GhostTally,
    Verdict,
    occupied_cells,
    structure_kept,
    unknown_share,
)
from scenarios.evaluate.sight import SightKeeper


@dataclass(frozen=True)
class Evaluation:
    """What one pass measured: the grid, ``scans`` and ``returns`` read, the recording's
    ``first_stamp`` and ``last_stamp`` [s], the read interval [s] and sight margin
    [cells], one ``Verdict`` per map (in the maps' order), each map's ghost tally and
    final states (CellState, (height, width)) by name, and ``wall_s`` [s], the pass's
    wall time (reading, fusing and measuring)."""

    geometry: GridGeometry
    scans: int
    returns: int
    first_stamp: float
    last_stamp: float
    read_every: float
    margin: int
    verdicts: list[Verdict]
    ghosts: dict[str, GhostTally]
    finals: dict[str, np.ndarray]
    wall_s: float

    @property
    def duration(self) -> float:
        """[s] of recording time from the first scan to the last."""
        return self.last_stamp - self.first_stamp


class _Reads:
    """The reads every ``interval`` [s] from the first scan's stamp (see the module)."""

    def __init__(self, maps: Sequence[MapUnderTest], sight: SightKeeper, interval: float):
        self.maps = maps
        self.sight = sight
        self.interval = interval
        self.tallies = {m.name: GhostTally(interval) for m in maps}
        self.first: float | None = None
        self.k = 0
        self.through = np.empty(0, dtype=np.int64)  # the current scan's

    def due(self, stamp: float, inclusive: bool) -> None:
        """Read at every read stamp before ``stamp`` (up to it, when ``inclusive``)."""
        if self.first is None:
            self.first = stamp
            return
        candidates = self.sight.ghost_candidates(self.through)
        while True:
            t = self.first + self.k * self.interval
            if not (t < stamp or (inclusive and t <= stamp)):
                return
            for m in self.maps:
                self.tallies[m.name].add(t, m.states_of(candidates, t) == CellState.OCCUPIED)
            self.k += 1


def evaluate(
    scans: Iterable[Scan],
    geometry: GridGeometry,
    maps: Sequence[MapUnderTest],
    read_every: float = 1.0,
    margin: int = 2,
    progress: Callable[[int, int | None], None] | None = None,
    total: int | None = None,
) -> Evaluation:
    """Fuse ``scans`` (streamed, read once) into every map in lockstep and measure them
    (see the module); ``read_every`` [s] > 0 of recording time between ghost reads;
    ``margin`` [cells] of the sight (``SightKeeper``); ``progress(done, total)`` after
    every scan. ValueError for a bad interval or margin, or no scans."""
    if not read_every > 0:
        raise ValueError(f"the read interval must be seconds > 0, got {read_every!r}")
    if len({m.name for m in maps}) != len(maps):
        raise ValueError(f"the maps must have distinct names, got {[m.name for m in maps]}")
    load_fusion_kernels()  # compiled or loaded once, untimed
    started = time.perf_counter()
    sight = SightKeeper(geometry, margin)
    reads = _Reads(maps, sight, read_every)
    fusion_s = dict.fromkeys((m.name for m in maps), 0.0)
    done = 0
    last = first = float("nan")
    for scan in scans:
        reads.due(scan.stamp, inclusive=False)
        first = scan.stamp if done == 0 else first
        reads.through = sight.observe(scan)
        for m in maps:
            t0 = time.perf_counter()
            m.fuse(scan)
            fusion_s[m.name] += time.perf_counter() - t0
        done += 1
        last = scan.stamp
        if progress is not None:
            progress(done, total)
    if done == 0:
        raise ValueError("the recording holds no scans to evaluate (check --start, --end)")
    reads.due(last, inclusive=True)
    finals = {m.name: m.final_states(last) for m in maps}
    verdicts = [
        Verdict(
            name=m.name,
            structure_kept=structure_kept(finals[m.name], sight.hit_count, sight.returns_total),
            ghost_cell_seconds=reads.tallies[m.name].cell_seconds,
            unknown_share=unknown_share(finals[m.name], sight.floor),
            occupied_cells=occupied_cells(finals[m.name]),
            scans_per_s=done / fusion_s[m.name] if fusion_s[m.name] > 0 else 0.0,
        )
        for m in maps
    ]
    return Evaluation(
        geometry=geometry,
        scans=done,
        returns=sight.returns_total,
        first_stamp=first,
        last_stamp=last,
        read_every=read_every,
        margin=margin,
        verdicts=verdicts,
        ghosts=reads.tallies,
        finals=finals,
        wall_s=time.perf_counter() - started,
    )
