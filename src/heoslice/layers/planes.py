"""Plane heights: where the layers of a part are cut, and how many there are.

Layer i is cut at its centre, z_i = z_min + (i + 1/2) h, for i = 0 .. L - 1 with
L = ceil((z_max - z_min) / h) (at least one). This is the one place the layer count is
computed: slicing, the stack's checks and the pipeline's limits all call :func:`layer_count`.
"""

from __future__ import annotations

import numpy as np

from heoslice.errors import InputError

#: How far (in layers) the part's height may exceed a whole number of layers and still count as that
#: number: a height that is an exact multiple of h up to floating-point rounding adds no extra layer.
LAYER_COUNT_TOLERANCE = 1e-9


def layer_count(z_min: float, z_max: float, layer_height: float) -> int:
    """Layers a part spanning z_min .. z_max (mm) needs at ``layer_height`` (mm): ceil of the height over h,
    less :data:`LAYER_COUNT_TOLERANCE`, and at least 1."""
    if not layer_height > 0:
        raise InputError(f"layer_height_mm: must be positive, got {layer_height}")
    return max(1, int(np.ceil((z_max - z_min) / layer_height - LAYER_COUNT_TOLERANCE)))


def plane_heights(z_min: float, z_max: float, layer_height: float) -> np.ndarray:
    """Slicing planes at layer centres: z_i = z_min + (i + 1/2) h, i = 0 .. :func:`layer_count` - 1.

    Returns (L,) float64, mm.
    """
    return z_min + (np.arange(layer_count(z_min, z_max, layer_height)) + 0.5) * layer_height
