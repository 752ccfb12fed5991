"""A grid snapshot's arrays checked against the grid before they replace a belief's state.

A snapshot holds the grid's state arrays (``BeliefGrid.state_names``: ``log_odds`` and
``last_observed``, and ``history`` under the ``dual`` policy) of shape (height, width) and
the scalar ``scans_fused``. One that decodes but holds something else (another grid's shape,
a missing array) must not be loaded: start-up then falls back to an older snapshot or to
a full replay of the journal.
"""

from __future__ import annotations

import numpy as np

from mapserver.core.belief import BeliefGrid
from mapserver.store.journal import Snapshot

GRID_ARRAYS = ("log_odds", "last_observed")
"""The arrays every policy's state holds (float); ``history`` (uint8) is ``dual``'s own."""


def snapshot_problem(
    snapshot: Snapshot, shape: tuple[int, int], names: tuple[str, ...] = GRID_ARRAYS
) -> str | None:
    """Why ``snapshot`` cannot be loaded into a grid of ``shape`` (rows, cols) whose state
    is the arrays ``names``, or None."""
    arrays = snapshot.arrays
    for name in names:
        if name not in arrays:
            return f"no {name} array (it holds {sorted(arrays)})"
        array = arrays[name]
        if array.shape != tuple(shape):
            return f"{name} has shape {array.shape}, the grid is {tuple(shape)}"
        kind = np.floating if name in GRID_ARRAYS else np.unsignedinteger
        if not np.issubdtype(array.dtype, kind):
            return f"{name} has dtype {array.dtype}, expected a {kind.__name__} array"
    fused = arrays.get("scans_fused")
    if fused is None or fused.shape != () or not np.issubdtype(fused.dtype, np.integer):
        return f"scans_fused must be an integer scalar, got {fused!r}"
    return None


def load_snapshot_into(belief: BeliefGrid, snapshot: Snapshot) -> None:
    """Replace ``belief``'s state by ``snapshot``'s; ValueError (nothing changed) when
    ``snapshot_problem`` finds one."""
    problem = snapshot_problem(snapshot, belief.geometry.shape, belief.state_names)
    if problem is not None:
        raise ValueError(f"snapshot at seq {snapshot.seq}: {problem}")
    arrays = snapshot.arrays
    belief.load_state(stamp=snapshot.stamp, **{n: arrays[n] for n in belief.state_names})
    belief.scans_fused = int(arrays["scans_fused"])
