"""The weld's compiled kernel: rows of bits (coordinates, cell mixes) grouped by one pass over an
open-addressing hash table (numba source, compiled at install: :mod:`heoslice.jit`)."""

from __future__ import annotations

import numpy as np

from heoslice.jit import EXACT, kernel

#: Odd 64-bit multipliers (golden-ratio and xxHash primes) of the row hash (:func:`heoslice.mesh.weld.row_hash`)
#: and of the chaining's key hash.
HASH_MULTIPLIERS = (0x9E3779B97F4A7C15, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9, 0xBF58476D1CE4E5B9)


@kernel(EXACT)
def _first_rows(key, bits):  # pragma: no cover - compiled
    """(row_index (n,) int, first (m,) int) for rows of ``bits`` ((n, c) uint32, a row's bits: coordinates,
    cell mixes):
    first[j] is the input row where the j-th distinct row first occurs (increasing), row_index[i] the j of
    row i's. ``key`` ((n,) uint64, :func:`heoslice.mesh.weld.row_hash`) places rows in a table of at least
    2n slots by its high bits; rows are compared bit for bit, so colliding keys only cost probes."""
    count, columns = bits.shape
    shift = 1
    while (1 << shift) < 2 * count:
        shift += 1
    wrap = (1 << shift) - 1
    down = np.uint64(64 - shift)
    table = np.full(wrap + 1, -1, dtype=np.int64)
    row_index = np.empty(count, dtype=np.int64)
    first = np.empty(count, dtype=np.int64)
    distinct = 0
    for i in range(count):
        slot = np.int64(key[i] >> down)
        while True:
            j = table[slot]
            if j < 0:
                table[slot] = distinct
                first[distinct] = i
                row_index[i] = distinct
                distinct += 1
                break
            earlier = first[j]
            same = True
            for column in range(columns):
                if bits[earlier, column] != bits[i, column]:
                    same = False
                    break
            if same:
                row_index[i] = j
                break
            slot = (slot + 1) & wrap
    return row_index, first[:distinct]
