"""numba settings shared by the grading kernels, and the one conversion of their array arguments."""

from __future__ import annotations

import numpy as np

#: Compiled with fast-math's reassociation and contraction (to vectorise), not its no-inf/no-NaN
#: assumptions: distances start at inf.
JIT = {"cache": True, "nogil": True, "error_model": "numpy", "fastmath": {"nsz", "arcp", "contract", "reassoc"}}
#: The halftone reproduces the float32 arithmetic of the dither exactly: no contraction or reassociation.
EXACT = {"cache": True, "nogil": True, "error_model": "numpy"}


def f64(array) -> np.ndarray:
    """The array as C-ordered float64 (no copy when it is one already): what the kernels take."""
    return np.ascontiguousarray(array, dtype=np.float64)


def f32(array) -> np.ndarray:
    """The array as C-ordered float32 (no copy when it is one already)."""
    return np.ascontiguousarray(array, dtype=np.float32)


def i64(array) -> np.ndarray:
    """The array as C-ordered int64 (no copy when it is one already)."""
    return np.ascontiguousarray(array, dtype=np.int64)


