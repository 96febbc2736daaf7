"""Compiled kernel of :mod:`heoslice.material.field`: a closed-form reference's distance over a layer's solid
pixels, read through a table of codes (the field interior's dither levels of f(r)) in one pass."""

from __future__ import annotations

import numpy as np

from heoslice.jit import EXACT, kernel


@kernel(EXACT)
def quadratic_codes(packed: np.ndarray, c0: int, frame: tuple, square: tuple, r0: float, r1: float,
                    table: np.ndarray, codes: np.ndarray) -> None:  # pragma: no cover - compiled
    """codes[i, j] = table[round(r (n - 1))] at each solid pixel (i, c0 + j) of ``packed`` ((rows, bytes) uint8,
    MSB first; c0 a multiple of 8), codes (rows, cols) uint16, table (n,) uint16, r = (d - r0) / (r1 - r0)
    clipped to [0, 1], d = sqrt(max(Q, 0)), Q = A u^2 + B u v + C v^2 + D u + E v + F (``square``: (A, B, C, D,
    E, F)) with u, v the pixel centre's offsets (mm) from the reference's point along x and y; frame: (u of
    codes' column 0, u step per column, v of row 0, v step per row). Each run of nonzero bytes of a row takes
    its table index in one branch-free loop (it vectorises), then its solid pixels their codes, a full byte's
    eight without a test; the packed rows are read as they are (no array of a byte per pixel)."""
    a, b, c, d, e, f = square
    steps = table.shape[0] - 1
    scale = 1.0 / (r1 - r0)
    cols = codes.shape[1]
    first = c0 >> 3
    last = min(first + ((cols + 7) >> 3), packed.shape[1])
    index = np.empty(cols + 8, dtype=np.int32)  # a run's table indices (int32: the conversion vectorises)
    for i in range(packed.shape[0]):
        v = frame[2] + i * frame[3]
        linear = b * v + d
        constant = (c * v + e) * v + f
        row = packed[i]
        out = codes[i]
        k = first
        while k < last:
            if row[k] == 0:
                k += 1
                continue
            start = k
            while k < last and row[k] != 0:
                k += 1
            lo, hi = (start - first) * 8, min((k - first) * 8, cols)
            for j in range(lo, hi):
                u = frame[0] + j * frame[1]
                q = (a * u + linear) * u + constant
                index[j] = int(min(max((np.sqrt(max(q, 0.0)) - r0) * scale, 0.0), 1.0) * steps + 0.5)
            for byte in range(start, k):
                bits = row[byte]
                j0 = (byte - first) * 8
                if bits == 255 and j0 + 8 <= cols:
                    for j in range(j0, j0 + 8):
                        out[j] = table[index[j]]
                else:
                    for j in range(j0, min(j0 + 8, cols)):
                        if (bits >> (7 - (j - j0))) & 1:
                            out[j] = table[index[j]]
