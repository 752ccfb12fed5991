"""The belief grid: per-cell log-odds and last-observed stamps, fused from scans.

Per cell the grid holds ``L`` (float32 log-odds, as of ``last_observed``) and
``last_observed`` (float64 stamp [s], NaN = never observed). Under the ``decay`` policy
the stored ``L`` is the value at ``last_observed``; reads at a later stamp fade it
lazily (``SensorModel``/``DecayParams`` document the formulas), so no timer ever sweeps
the grid. Time is always an argument (a scan's stamp), never the wall clock.

Three states (``CellState``): a cell is OCCUPIED when its (faded) probability is above
``occupied_threshold``, FREE when below ``free_threshold``, and UNKNOWN otherwise, which
includes never observed and faded back to the prior.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from enum import IntEnum
from itertools import accumulate

import numpy as np

from mapserver.core import fusion_kernel as kernel
from mapserver.core.errors import FieldError
from mapserver.core.geometry import GridGeometry
from mapserver.core.scan import Pose2D, Scan
from mapserver.core.sensor_model import DEFAULT_POLICY, DecayParams, Policy, SensorModel


class CellState(IntEnum):
    """The three states of a cell (uint8 in state arrays)."""

    UNKNOWN = 0
    FREE = 1
    OCCUPIED = 2


@dataclass(frozen=True)
class CellBox:
    """An inclusive rectangle of cells: columns col0..col1, rows row0..row1."""

    col0: int
    row0: int
    col1: int
    row1: int

    @property
    def empty(self) -> bool:
        return self.col1 < self.col0 or self.row1 < self.row0

    @property
    def width(self) -> int:
        return 0 if self.empty else self.col1 - self.col0 + 1

    @property
    def height(self) -> int:
        return 0 if self.empty else self.row1 - self.row0 + 1

    @property
    def slices(self) -> tuple[slice, slice]:
        """(rows, cols) slices selecting this box from a (height, width) grid array."""
        return (slice(self.row0, self.row1 + 1), slice(self.col0, self.col1 + 1))

    def clip(self, shape: tuple[int, int]) -> CellBox:
        """This box intersected with a (height, width) grid; EMPTY_BOX when disjoint."""
        height, width = shape
        clipped = CellBox(
            max(self.col0, 0),
            max(self.row0, 0),
            min(self.col1, width - 1),
            min(self.row1, height - 1),
        )
        return EMPTY_BOX if clipped.empty else clipped

    def union(self, other: CellBox) -> CellBox:
        if self.empty:
            return other
        if other.empty:
            return self
        return CellBox(
            min(self.col0, other.col0),
            min(self.row0, other.row0),
            max(self.col1, other.col1),
            max(self.row1, other.row1),
        )


EMPTY_BOX = CellBox(0, 0, -1, -1)


@dataclass(frozen=True)
class FusionResult:
    """What one scan changed: ``cells`` updated (each counted once) inside ``box``."""

    cells: int
    box: CellBox


@dataclass(frozen=True)
class CellSample:
    """Per-cell reads of a set of cells: CellState, p_occ (NaN unknown), last_observed [s]."""

    states: np.ndarray
    p_occ: np.ndarray
    last_observed: np.ndarray


class BeliefGrid:
    """A log-odds occupancy grid with per-cell freshness, fused one scan at a time.

    geometry: the grid's size and placement.
    sensor_model: the inverse sensor model and thresholds.
    policy: ``decay`` (default), ``binary``, ``sticky`` or ``dual`` (see ``Policy``).
    decay: half lives and fade bound (used by the ``decay`` policy only).
    max_clearing_range: [m] cap on how far a no-return beam clears (default: the scan's
        own range_max, as REP 117 implies), on top of ``sensor_model.no_return_range``.
    """

    def __init__(
        self,
        geometry: GridGeometry,
        sensor_model: SensorModel | None = None,
        policy: Policy | str = DEFAULT_POLICY,
        decay: DecayParams | None = None,
        max_clearing_range: float = math.inf,
    ) -> None:
        if not max_clearing_range > 0:
            raise FieldError("max_clearing_range", max_clearing_range, "must be positive")
        self.geometry = geometry
        self.sensor_model = sensor_model or SensorModel()
        self.policy = Policy.parse(policy)
        self.decay = decay or DecayParams()
        self.max_clearing_range = float(max_clearing_range)
        m = self.sensor_model
        margin = min(m.l_occupied - m.l0, m.l0 - m.l_free)
        if self.decay.fade_bound >= margin:
            raise FieldError(
                "decay.fade_bound",
                self.decay.fade_bound,
                f"must be below the thresholds' distance from the prior ({margin:.3f} log-odds)",
            )
        self._log_odds = np.full(geometry.size, self.sensor_model.l0, dtype=np.float32)
        self._last_observed = np.full(geometry.size, np.nan, dtype=np.float64)
        self._marks = np.zeros(kernel.marks_size(geometry.size), dtype=np.uint8)
        self._fade_cache = np.empty((kernel.FADE_CACHE_SIZE, 3), dtype=np.float64)
        # The free-space history: one byte per cell under ``dual``, unused (one byte) else.
        history_cells = geometry.size if self.policy is Policy.DUAL else 1
        self._history = np.zeros(history_cells, dtype=np.uint8)
        # The kernel's argument groups (the arrays are only ever updated in place).
        self._kernel_buffers = kernel.KernelBuffers(
            self._log_odds, self._last_observed, self._marks, self._fade_cache, self._history
        )
        # Fixed argument types (an int origin or clamp would be a new signature to
        # compile): every grid runs the kernels ``load_fusion_kernels`` loads.
        g = geometry
        self._kernel_grid = kernel.KernelGrid(
            width=int(g.width),
            height=int(g.height),
            origin_x=float(g.origin_x),
            origin_y=float(g.origin_y),
            resolution=float(g.resolution),
        )
        self._kernel_model = kernel.kernel_model(m, self.decay, self.policy)
        self.stamp = -math.inf  # the latest stamp fused: the map's "now"
        self.scans_fused = 0

    # ----------------------------------------------------------------- fusion
    def fuse(self, scan: Scan) -> FusionResult:
        """Fuse one scan: each observed cell updated once; returns the cells and bbox."""
        return self.fuse_many([scan])[0]

    def fuse_many(self, scans: Sequence[Scan]) -> list[FusionResult]:
        """Fuse scans in order, exactly as one ``fuse`` each, in one kernel call."""
        if not scans:
            return []
        params = np.empty(len(scans), dtype=kernel.SCAN_PARAMS)
        fill_margin, glance_margin = self.fill_margin, self.glance_margin
        release_margin = self.sensor_model.release_margin if self.policy is Policy.DUAL else 0.0
        for k, scan in enumerate(scans):
            std = scan.pose_std
            params[k] = (
                scan.pose.x,
                scan.pose.y,
                scan.pose.yaw,
                scan.angle_min,
                scan.angle_increment,
                scan.range_min,
                scan.range_max,
                self.no_return_clearing(scan.range_max),
                scan.stamp,
                std.xy**2 if std is not None else 0.0,
                std.yaw**2 if std is not None else 0.0,
                fill_margin,
                glance_margin,
                release_margin,
            )
        offsets = np.array([0, *accumulate(s.beam_count for s in scans)], dtype=np.int64)
        if len(scans) == 1:  # no copy when the scan's ranges are float64 already
            ranges = np.ascontiguousarray(scans[0].ranges, dtype=np.float64)
        else:
            ranges = np.concatenate([s.ranges for s in scans])
        boxes = np.empty((len(scans), 4), dtype=np.int64)
        cells = np.empty(len(scans), dtype=np.int64)
        kernel.POLICY_FUSE_BATCH[self._kernel_model.policy](
            self._kernel_buffers, self._kernel_grid, self._kernel_model,
            ranges, offsets, params, boxes, cells,
        )  # fmt: skip
        self.stamp = max(self.stamp, max(s.stamp for s in scans))
        self.scans_fused += len(scans)
        return [  # tolist(): Python ints
            FusionResult(cells=c, box=CellBox(*box))
            for c, box in zip(cells.tolist(), boxes.tolist(), strict=True)
        ]

    @property
    def fill_margin(self) -> float:
        """[m] how far the fill between beams keeps from the surface two neighbouring
        returns outline: one cell, for the log-odds policies with the sensor model's
        ``fill_between_beams``; 0 (no fill) otherwise, and always for ``binary``, the Nav2
        baseline, which traces its beams only (docs/clearing.md)."""
        if self.policy is Policy.BINARY or not self.sensor_model.fill_between_beams:
            return 0.0
        return self.geometry.resolution

    @property
    def glance_margin(self) -> float:
        """[m] how near, square to the surface it hit, a return clears: one cell, for the
        log-odds policies with the sensor model's ``guard_glancing_faces``; 0 (up to its
        endpoint) otherwise, and always for ``binary`` (docs/clearing.md)."""
        if self.policy is Policy.BINARY or not self.sensor_model.guard_glancing_faces:
            return 0.0
        return self.geometry.resolution

    def no_return_clearing(self, range_max: float) -> float:
        """[m] how far a no-return beam of a scan with ``range_max`` [m] clears: out to
        ``no_return_range`` for the log-odds policies (0, not at all, when
        ``p_miss_no_return`` is the prior: no evidence); for ``binary``, the Nav2 baseline
        as the contract's range semantics have it (Nav2's obstacle layer with
        ``inf_is_valid: true``), out to ``range_max``. ``max_clearing_range`` caps both."""
        m = self.sensor_model
        if self.policy is Policy.BINARY:
            return min(range_max, self.max_clearing_range)
        if m.p_miss_no_return == m.prior:
            return 0.0
        return min(range_max, self.max_clearing_range, m.no_return_cap)

    # ------------------------------------------------------------------ reads
    @property
    def full_box(self) -> CellBox:
        return CellBox(0, 0, self.geometry.width - 1, self.geometry.height - 1)

    @property
    def fades(self) -> bool:
        """True when evidence fades with time: under ``decay``, and under ``dual`` that of
        its new cells (``fades_selectively``)."""
        return self.policy in (Policy.DECAY, Policy.DUAL)

    @property
    def fades_selectively(self) -> bool:
        """True when only some cells fade, by their history (``dual``)."""
        return self.policy is Policy.DUAL

    @property
    def occupied_half_life(self) -> float:
        """[s] the fade half life of evidence above the prior: ``decay``'s, or under
        ``dual`` a transient's (``SensorModel.transient_half_life``)."""
        return self._kernel_model.half_life_occupied  # kernel.occupied_half_life

    def history(self) -> np.ndarray:
        """The flat history array (``dual``: one byte per cell; one unused byte else)."""
        return self._history

    def raw_log_odds(self) -> np.ndarray:
        """Stored log-odds, (height, width) float32 view, as of each cell's last_observed."""
        return self._log_odds.reshape(self.geometry.shape)

    def last_observed(self) -> np.ndarray:
        """(height, width) float64 view of last-observed stamps [s]; NaN = never."""
        return self._last_observed.reshape(self.geometry.shape)

    def log_odds_at(self, stamp: float | None = None, box: CellBox | None = None) -> np.ndarray:
        """Log-odds (float32) at ``stamp`` [s] (default: the map's stamp), faded per policy.

        Returns a new (rows, cols) array for ``box`` (default: the whole grid).
        """
        box = box or self.full_box
        raw = self.raw_log_odds()[box.slices]
        t = self.last_observed()[box.slices]
        return self._faded(raw, t, stamp, self._history_window(box))

    def _history_window(self, box: CellBox) -> np.ndarray:
        """The history of ``box``'s cells (``dual``), else the one unused byte."""
        if not self.fades_selectively:
            return self._history
        return self._history.reshape(self.geometry.shape)[box.slices]

    def _faded(
        self, raw: np.ndarray, t: np.ndarray, stamp: float | None, history: np.ndarray
    ) -> np.ndarray:
        """Stored log-odds ``raw`` last observed at ``t``, faded to ``stamp`` (a new array);
        under ``dual`` only the cells whose ``history`` (as ``raw``) says new fade."""
        if not self.fades or not self._has_stamp(stamp):
            return np.array(raw, dtype=np.float32)
        out = np.empty(raw.size, dtype=np.float32)
        kernel.faded_log_odds(
            np.ascontiguousarray(raw).ravel(),
            np.ascontiguousarray(t).ravel(),
            self._resolve_stamp(stamp),
            self.sensor_model.l0,
            self.occupied_half_life,
            self.decay.half_life_free,
            self._fade_cache,
            out,
            np.ascontiguousarray(history).ravel(),
            self.fades_selectively,
        )
        return out.reshape(raw.shape)

    def age_at(self, stamp: float | None = None, box: CellBox | None = None) -> np.ndarray:
        """Freshness view: age [s] of each cell's evidence at ``stamp``; NaN = never observed.

        Ages are ``stamp - last_observed``, negative for evidence newer than ``stamp``.
        """
        box = box or self.full_box
        return self._resolve_stamp(stamp) - self.last_observed()[box.slices]

    def known_mask(self, log_odds: np.ndarray, box: CellBox | None = None) -> np.ndarray:
        """Cells observed and not faded back to the prior, for log-odds read from ``box``."""
        box = box or self.full_box
        return self._known(log_odds, self.last_observed()[box.slices], self._history_window(box))

    def _known(
        self, log_odds: np.ndarray, last_observed: np.ndarray, history: np.ndarray
    ) -> np.ndarray:
        observed = ~np.isnan(last_observed)
        if not self.fades:
            return observed
        unfaded = np.abs(log_odds - self.sensor_model.l0) >= self.decay.fade_bound
        if self.fades_selectively:  # structure and void cells are never unknown again
            unfaded |= history >= kernel.HISTORY_STRUCTURE_SEEN
        return observed & unfaded

    def probability_at(self, stamp: float | None = None, box: CellBox | None = None) -> np.ndarray:
        """Occupancy probability (float32) at ``stamp``; NaN where unknown (never/faded)."""
        lo = self.log_odds_at(stamp, box)
        return self._probability(lo, self.known_mask(lo, box))

    @staticmethod
    def _probability(log_odds: np.ndarray, known: np.ndarray) -> np.ndarray:
        p = (1.0 / (1.0 + np.exp(-log_odds.astype(np.float64)))).astype(np.float32)
        p[~known] = np.nan
        return p

    def states_at(self, stamp: float | None = None, box: CellBox | None = None) -> np.ndarray:
        """CellState per cell (uint8) at ``stamp`` [s] for ``box`` (default: whole grid)."""
        lo = self.log_odds_at(stamp, box)
        return self.states_from_log_odds(lo, self.known_mask(lo, box))

    def sample(self, indices: np.ndarray, stamp: float | None = None) -> CellSample:
        """States, probabilities and stamps of the cells at flat ``indices`` at ``stamp``."""
        idx = np.asarray(indices, dtype=np.int64)
        t = self._last_observed[idx]
        history = self._history[idx] if self.fades_selectively else self._history
        lo = self._faded(self._log_odds[idx], t, stamp, history)
        known = self._known(lo, t, history)
        return CellSample(
            states=self.states_from_log_odds(lo, known),
            p_occ=self._probability(lo, known),
            last_observed=t,
        )

    def states_from_log_odds(self, log_odds: np.ndarray, known: np.ndarray) -> np.ndarray:
        """Classify log-odds by the thresholds; cells not ``known`` are UNKNOWN."""
        m = self.sensor_model
        lo = np.asarray(log_odds, dtype=np.float64)  # compare as the costmap kernel does
        states = np.full(lo.shape, CellState.UNKNOWN, dtype=np.uint8)
        states[known & (lo > m.l_occupied)] = CellState.OCCUPIED
        states[known & (lo < m.l_free)] = CellState.FREE
        return states

    # ------------------------------------------------------------- snapshots
    @property
    def state_names(self) -> tuple[str, ...]:
        """The arrays that make up the grid's state (``state_arrays``)."""
        return state_names(self.policy)

    def void_mask(self) -> np.ndarray:
        """(height, width) bool: cells seen free for good (``dual``; all False otherwise)."""
        if self.policy is not Policy.DUAL:
            return np.zeros(self.geometry.shape, dtype=bool)
        return self._history.reshape(self.geometry.shape) == kernel.HISTORY_VOID

    def structure_mask(self) -> np.ndarray:
        """(height, width) bool: cells confirmed structure (``dual``; all False otherwise)."""
        if self.policy is not Policy.DUAL:
            return np.zeros(self.geometry.shape, dtype=bool)
        history = self._history.reshape(self.geometry.shape)
        return (history == kernel.HISTORY_STRUCTURE) | (history == kernel.HISTORY_STRUCTURE_SEEN)

    def state_arrays(self) -> dict[str, np.ndarray]:
        """Copies of the state arrays named by ``state_names``, each (height, width)."""
        views = {
            "log_odds": self._log_odds,
            "last_observed": self._last_observed,
            "history": self._history,
        }
        return {name: views[name].reshape(self.geometry.shape).copy() for name in self.state_names}

    def load_state(
        self,
        log_odds: np.ndarray,
        last_observed: np.ndarray,
        stamp: float,
        history: np.ndarray | None = None,
    ) -> None:
        """Replace the grid's contents (from a snapshot or another grid); arrays of shape
        (height, width). ``history`` is required under ``dual`` and refused otherwise."""
        shape = self.geometry.shape
        wanted = self.policy is Policy.DUAL
        if (history is not None) != wanted:
            need = "needs a" if wanted else "has no"
            raise ValueError(f"the {self.policy.value} policy {need} history array")
        arrays = {"log_odds": log_odds, "last_observed": last_observed, "history": history}
        for name, arr in arrays.items():
            if arr is not None and np.shape(arr) != shape:
                raise ValueError(f"{name} must have shape {shape}, got {np.shape(arr)}")
        self._log_odds[:] = np.asarray(log_odds, dtype=np.float32).ravel()
        self._last_observed[:] = np.asarray(last_observed, dtype=np.float64).ravel()
        if history is not None:
            self._history[:] = np.asarray(history, dtype=np.uint8).ravel()
        self.stamp = float(stamp)

    def copy_state_from(self, other: BeliefGrid) -> None:
        """Take ``other``'s state (same geometry and policy)."""
        self.load_state(stamp=other.stamp, **other.state_arrays())

    def copy_cells_from(self, other: BeliefGrid, boxes: Sequence[CellBox]) -> None:
        """Take ``other``'s state in ``boxes`` only, and its stamp and scans fused (same
        geometry and policy): a grid that equalled ``other`` before it fused scans whose
        ``FusionResult.box`` lie in ``boxes`` equals it after, cell for cell, at the cost
        of copying those boxes (13 B a cell under ``dual``, 12 else)."""
        if other.geometry != self.geometry or other.policy is not self.policy:
            raise ValueError("copy_cells_from needs a grid of the same geometry and policy")
        pairs = [(self.raw_log_odds(), other.raw_log_odds()),
                 (self.last_observed(), other.last_observed())]  # fmt: skip
        if self.fades_selectively:
            shape = self.geometry.shape
            pairs.append((self._history.reshape(shape), other._history.reshape(shape)))
        for box in boxes:
            box = box.clip(self.geometry.shape)
            if box.empty:
                continue
            for mine, theirs in pairs:
                mine[box.slices] = theirs[box.slices]
        self.stamp = other.stamp
        self.scans_fused = other.scans_fused

    def _has_stamp(self, stamp: float | None) -> bool:
        return stamp is not None or math.isfinite(self.stamp)

    def _resolve_stamp(self, stamp: float | None) -> float:
        return float(self.stamp if stamp is None else stamp)


def state_names(policy: Policy) -> tuple[str, ...]:
    """The arrays a grid's state holds under ``policy`` (a snapshot's arrays): log_odds and
    last_observed, and under ``dual`` the free-space history."""
    if policy is Policy.DUAL:
        return ("log_odds", "last_observed", "history")
    return ("log_odds", "last_observed")


def load_fusion_kernels(policies: Iterable[Policy] = tuple(Policy)) -> float:
    """Compile or load (numba's cache) the fusion kernel of each of ``policies`` (each
    policy has its own, ``fusion_kernel.POLICY_FUSE_BATCH``; default: every policy), once
    per process; returns the seconds it took (about 0 once loaded). The first ``fuse``
    under a policy would do it otherwise, so a caller that times fusion calls this first
    with the policies it fuses under and reports the two apart."""
    start = time.perf_counter()
    warm_up = Scan("warm-up", 0.0, Pose2D(0.5, 0.5, 0.0), 0.0, 0.1, 0.0, 1.0, np.array([0.25]))
    for policy in policies:
        BeliefGrid(GridGeometry(1, 1, 1.0), policy=policy).fuse(warm_up)
    return time.perf_counter() - start
