"""heoslice.layers.bits: packed 1-bit rows counted."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.layers.bits import count_solid


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(1, 40), st.integers(1, 23))
def test_count_solid_counts_every_bit_of_any_shape(seed, rows, row_bytes):
    """count_solid equals the number of ones np.unpackbits finds, for byte counts that are not a multiple
    of 8 (the 64-bit words and the tail) and for non-contiguous views."""
    data = np.random.default_rng(seed).integers(0, 256, (rows, row_bytes + 3), dtype=np.uint8)
    view = data[:, 1:row_bytes + 1]
    assert count_solid(view) == int(np.unpackbits(view).sum())
