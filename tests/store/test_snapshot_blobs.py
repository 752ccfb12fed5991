"""Snapshot blobs: zstd-compressed npz, and the bare npz of snapshots saved before."""

from __future__ import annotations

import io

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import array_shapes, arrays

from mapserver.store.journal import ZSTD_MAGIC, decode_arrays, encode_arrays

GRIDS = st.dictionaries(
    st.sampled_from(["log_odds", "last_observed", "history"]),
    arrays(
        st.sampled_from([np.float32, np.float64, np.uint8]),
        array_shapes(min_dims=2, max_dims=2, max_side=40),
    ),
    min_size=1,
)


@settings(max_examples=60, deadline=None)
@given(GRIDS)
def test_arrays_come_back_bit_for_bit(grids) -> None:
    blob = encode_arrays(grids)
    assert blob[:4] == ZSTD_MAGIC
    back = decode_arrays(blob)
    assert set(back) == set(grids)
    for name, array in grids.items():
        assert back[name].dtype == array.dtype
        assert back[name].tobytes() == array.tobytes()


def test_a_bare_npz_of_an_older_snapshot_still_decodes() -> None:
    buffer = io.BytesIO()
    np.savez(buffer, log_odds=np.arange(6, dtype=np.float32).reshape(2, 3))
    back = decode_arrays(buffer.getvalue())
    assert back["log_odds"].tolist() == [[0, 1, 2], [3, 4, 5]]


def test_a_uniform_grid_compresses_and_a_damaged_frame_is_refused() -> None:
    grid = {"last_observed": np.full((1000, 2000), -np.inf)}
    blob = encode_arrays(grid)
    assert len(blob) < grid["last_observed"].nbytes / 1000
    with pytest.raises(ValueError, match="zstd"):
        decode_arrays(blob[: len(blob) // 2])
