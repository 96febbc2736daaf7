"""Packed 1-bit rows (np.packbits' layout: MSB first, each row padded to whole bytes) counted: the one count of
solid pixels the slicer writes into a manifest and ``verify`` checks against it."""

from __future__ import annotations

import numpy as np


def count_solid(packed: np.ndarray) -> int:
    """Number of set bits (solid pixels) of a packed mask (any shape, uint8; its padding bits zero), counted 64 bits
    at a time (faster than byte by byte: benchmarks/README.md)."""
    flat = np.ascontiguousarray(packed).reshape(-1)
    whole = flat.size // 8 * 8
    return (int(np.bitwise_count(flat[:whole].view(np.uint64)).sum(dtype=np.int64))
            + int(np.bitwise_count(flat[whole:]).sum(dtype=np.int64)))
