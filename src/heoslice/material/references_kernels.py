"""Compiled kernel of :mod:`heoslice.material.field`: a closed-form reference's distance over a layer's solid
pixels, read through a table of codes (the field interior's dither levels of f(r)) in one pass."""

from __future__ import annotations

import numpy as np

from heoslice.jit import EXACT, kernel


@kernel(EXACT)
def quadratic_codes(solid: np.ndarray, frame: tuple, square: tuple, r0: float, r1: float, table: np.ndarray,
                    codes: np.ndarray) -> None:  # pragma: no cover - compiled
    """codes[i, j] = table[round(r (n - 1))] at each solid pixel of ``solid`` (h, w) bool, table (n,) uint16,
    r = (d - r0) / (r1 - r0) clipped to [0, 1], d = sqrt(max(Q, 0)), Q = A u^2 + B u v + C v^2 + D u + E v + F
    (``square``: (A, B, C, D, E, F)) with u, v the pixel centre's offsets (mm) from the reference's point along
    x and y; frame: (u of column 0, u step per column, v of row 0, v step per row)."""
    a, b, c, d, e, f = square
    steps = table.shape[0] - 1
    scale = 1.0 / (r1 - r0)
    for i in range(solid.shape[0]):
        v = frame[2] + i * frame[3]
        linear = b * v + d
        constant = (c * v + e) * v + f
        for j in range(solid.shape[1]):
            if solid[i, j]:
                u = frame[0] + j * frame[1]
                q = (a * u + linear) * u + constant
                r = min(max((np.sqrt(max(q, 0.0)) - r0) * scale, 0.0), 1.0)
                codes[i, j] = table[int(r * steps + 0.5)]
