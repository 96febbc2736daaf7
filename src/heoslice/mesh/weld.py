"""Welding: vertices merged by exact coordinate, and faces that repeat an earlier face dropped.

Both find rows' first occurrences by a hash of their bits in one compiled hash table
(:func:`distinct_rows`), which compares the rows themselves, so a collision of hashes only costs time.
"""

from __future__ import annotations

import numpy as np

from heoslice.mesh.weld_kernels import HASH_MULTIPLIERS, _first_rows


def row_hash(bits: np.ndarray) -> np.ndarray:
    """(n,) uint64 hash of the rows of (n, c) uint32 or uint64 bits; its high bits are the well-mixed ones.

    Multiplicative hashing per column (the first column by the first multiplier, the others by the
    second and third in turn), xor-ed, then one xor-shift-multiply round so that every input bit
    reaches the high bits. Collisions only cost time: the callers compare the rows themselves.
    """
    k0, k1, k2, k3 = (np.uint64(k) for k in HASH_MULTIPLIERS)
    # array arithmetic wraps without a warning: no np.errstate, whose context swaps freed objects the
    # parallel slice had frozen for its forks (tests/test_pipeline_parallel.py)
    key = bits[:, 0] * k0
    for column in range(1, bits.shape[1]):
        key ^= bits[:, column] * (k1 if column % 2 else k2)
    key ^= key >> np.uint64(32)
    key *= k3
    return key


def distinct_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(row_index (n,) int, first (m,) int) of the distinct rows of a 2-D array of 4- or 8-byte items, told
    apart by their bits: first[j] is the row where the j-th distinct row first occurs (increasing),
    row_index[i] the j of row i's. One compiled pass over a hash table (:mod:`heoslice.mesh.weld_kernels`)."""
    rows = np.ascontiguousarray(rows)
    words = rows.view(np.uint32 if rows.itemsize == 4 else np.uint64)
    return _first_rows(row_hash(words), words.view(np.uint32).reshape(len(rows), rows.shape[1] * rows.itemsize // 4))


def weld_vertices(vertices: np.ndarray, faces: np.ndarray):
    """Merge vertices with identical coordinates, keeping first occurrences in order.

    Returns (unique_vertices, faces, first_index): unique vertex j is input vertex
    first_index[j]. Rows go into a hash table by a hash of their coordinate bits and are
    compared bit for bit there, in one compiled pass (:mod:`heoslice.mesh.weld_kernels`);
    -0.0 and 0.0 weld. An already welded mesh comes back unchanged.
    """
    rows = np.ascontiguousarray(vertices)
    if rows.dtype not in (np.float32, np.float64):
        rows = rows.astype(np.float64)
    rows = rows + rows.dtype.type(0.0)  # -0.0 and 0.0 weld
    row_index, first = distinct_rows(rows)
    return rows[first].astype(np.float64), row_index[faces], first


def duplicate_faces(faces: np.ndarray) -> np.ndarray:
    """(m,) bool: True for each face that repeats an earlier face with the same orientation.

    faces: (m, 3) int, no repeated vertex within a face. A face and its cyclic rotations
    are the same face; the reversed face (opposite orientation) is not. The first
    occurrence is kept, so dropping the flagged faces keeps the order of the rest.
    """
    rolled = np.take_along_axis(faces, (np.argmin(faces, axis=1)[:, None] + np.arange(3)) % 3, axis=1)
    row_index, first = distinct_rows(np.ascontiguousarray(rolled, dtype=np.int64))
    return first[row_index] != np.arange(len(faces))
