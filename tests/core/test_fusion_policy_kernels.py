"""Each policy's compiled fusion kernel (``POLICY_FUSE_BATCH``, the policy a compile-time
constant) updates the grid exactly as the one generic kernel that reads the policy at run
time, byte for byte: log-odds, stamps, history, and the marks left all zero."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from test_fusion_properties import GEOMETRY, MODEL, scans

from mapserver.core import fusion_kernel as kernel
from mapserver.core.belief import BeliefGrid, load_fusion_kernels
from mapserver.core.sensor_model import POLICY_CODES, Policy
from tests.kernel_helpers import kernel_arguments


def test_every_policy_has_its_own_compiled_kernel():
    assert set(kernel.POLICY_FUSE_BATCH) == set(POLICY_CODES.values())
    kernels = list(kernel.POLICY_FUSE_BATCH.values())
    assert len({id(k) for k in kernels}) == len(kernels)


@settings(max_examples=40, deadline=None)
@given(st.lists(scans(), min_size=1, max_size=5), st.sampled_from(list(Policy)))
def test_a_policy_kernel_fuses_exactly_as_the_generic_kernel(sequence, policy):
    specialised = BeliefGrid(GEOMETRY, MODEL, policy)
    _, grid, model, ranges, offsets, params, boxes, cells = kernel_arguments(specialised, sequence)
    generic = BeliefGrid(GEOMETRY, MODEL, policy)
    generic_boxes, generic_cells = np.empty_like(boxes), np.empty_like(cells)
    runtime_policy = int(np.int64(model.policy))  # not a constant: the generic compilation
    kernel.fuse_batch(
        generic._kernel_buffers, grid, model, runtime_policy,
        ranges, offsets, params, generic_boxes, generic_cells,
    )  # fmt: skip
    assert np.array_equal(generic_cells, cells)
    assert np.array_equal(generic_boxes, boxes)
    for name, array in specialised.state_arrays().items():
        assert array.tobytes() == generic.state_arrays()[name].tobytes(), name
    assert not specialised._kernel_buffers.marks.any()


def test_loading_the_kernels_loads_the_kernel_of_each_policy_asked_for():
    load_fusion_kernels([Policy.BINARY])
    assert kernel.POLICY_FUSE_BATCH[POLICY_CODES[Policy.BINARY]].signatures
    load_fusion_kernels()  # every policy
    assert all(compiled.signatures for compiled in kernel.POLICY_FUSE_BATCH.values())
