"""The chaining's compiled kernel: a layer run's segments linked end to start through the mesh edge they share,
and walked into loops (numba source, compiled at install: :mod:`heoslice.jit`).

Integer work only: a hash table of the segments' start keys, then one walk per loop, so chaining costs a
few passes over the segments instead of a sort of all their keys and rounds of pointer jumping.
"""

from __future__ import annotations

import numpy as np

from heoslice.jit import EXACT, helper, kernel
from heoslice.mesh.weld_kernels import HASH_MULTIPLIERS

#: Odd 64-bit multiplier of the key hash (the golden ratio's, the row hash's first); a key's slot in the
#: table is the product's high bits.
_KEY_MULTIPLIER = HASH_MULTIPLIERS[0]


@helper(EXACT)
def _slot(keys, key, shift):  # pragma: no cover - compiled
    """The slot of ``key`` in the open-addressing table ``keys`` (-1 marks a free slot; keys are never
    negative): where it is, or the free slot where it would go."""
    wrap = np.uint64(keys.shape[0] - 1)
    at = (np.uint64(key) * np.uint64(_KEY_MULTIPLIER)) >> np.uint64(shift)
    while keys[at] != -1 and keys[at] != key:
        at = (at + np.uint64(1)) & wrap
    return at


@kernel(EXACT)
def _chain_loops(start_key, end_key):  # pragma: no cover - compiled
    """(order, loop offsets, closed_by_join) of segments whose ends are named by (s,) int64 keys (see
    :func:`loops_by_keys`). Each key's starts are queued in index order; each end, in index order, takes the
    next start of its key (the k-th end of a key the k-th start). Paths are walked from their heads (no
    predecessor), then cycles from their smallest segment; loops are emitted by smallest segment."""
    count = start_key.shape[0]
    bits = 1
    while (1 << bits) < 2 * count:
        bits += 1
    shift = 64 - bits
    keys = np.full(1 << bits, -1, dtype=np.int64)
    first = np.full(1 << bits, -1, dtype=np.int64)
    queued = np.empty(count, dtype=np.int64)
    for i in range(count - 1, -1, -1):  # pushed in reverse, so each key's queue is in index order
        at = _slot(keys, start_key[i], shift)
        keys[at] = start_key[i]
        queued[i] = first[at]
        first[at] = i
    following = np.full(count, -1, dtype=np.int64)
    before = np.full(count, -1, dtype=np.int64)
    for i in range(count):
        at = _slot(keys, end_key[i], shift)
        j = first[at]
        if j >= 0:
            first[at] = queued[j]
            following[i] = j
            before[j] = i
    walked = np.empty(count, dtype=np.int64)  # the loops one after another, in the order they are found
    begins = np.empty(count + 1, dtype=np.int64)
    loop_at = np.full(count, -1, dtype=np.int64)  # by smallest segment: the loop it is smallest of
    seen = np.zeros(count, dtype=np.bool_)
    loops, filled = 0, 0
    for head in range(count):  # open chains, from their heads
        if before[head] >= 0:
            continue
        begins[loops] = filled
        lowest, j = head, head
        while j >= 0:
            walked[filled] = j
            filled += 1
            seen[j] = True
            lowest = min(lowest, j)
            j = following[j]
        loop_at[lowest] = loops
        loops += 1
    paths = loops
    for root in range(count):  # what is left is cycles; the first unseen segment of one is its smallest
        if seen[root]:
            continue
        begins[loops] = filled
        j = root
        while not seen[j]:
            walked[filled] = j
            filled += 1
            seen[j] = True
            j = following[j]
        loop_at[root] = loops
        loops += 1
    begins[loops] = filled
    order = np.empty(count, dtype=np.int64)
    offsets = np.zeros(loops + 1, dtype=np.int64)
    joined = np.empty(loops, dtype=np.bool_)  # an open chain, closed by joining its ends
    placed, emitted = 0, 0
    for lowest in range(count):
        loop = loop_at[lowest]
        if loop < 0:
            continue
        for k in range(begins[loop], begins[loop + 1]):
            order[placed] = walked[k]
            placed += 1
        joined[emitted] = loop < paths
        emitted += 1
        offsets[emitted] = placed
    return order, offsets, joined


def loops_by_keys(start_key: np.ndarray, end_key: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Order segments into loops by the keys naming their start and end edges ((s,) int64 each, not negative;
    segments sorted by layer, and keys of different layers differ).

    Returns (segment order (s,) int64, loop offsets (loops + 1,) int64, closed_by_join (loops,) bool: the
    chain did not close). A segment is followed by the segment starting on the edge it ends on; where a
    non-manifold edge carries several, the k-th segment (in index order) ending on it is followed by the
    k-th starting on it. Loops are sorted by their smallest segment index (so by layer); a cycle runs from
    its smallest segment, an open chain from its head.
    """
    return _chain_loops(np.ascontiguousarray(start_key, dtype=np.int64),
                        np.ascontiguousarray(end_key, dtype=np.int64))
