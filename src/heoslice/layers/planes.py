"""Plane heights: where the layers of a part are cut, and how many there are.

Layer i is cut at its centre, z_i = z_min + (i + 1/2) h, for i = 0 .. L - 1 with
L = ceil((z_max - z_min) / h) (at least one). This is the one place the layer count is
computed: slicing, the stack's checks and the pipeline's limits all call :func:`layer_count`.
"""

from __future__ import annotations

import math

import numpy as np

from heoslice.errors import InputError

#: How far (in layers) the part's height may exceed a whole number of layers and still count as that
#: number, at the least: a height that is an exact multiple of h up to rounding adds no extra layer.
LAYER_COUNT_TOLERANCE = 1e-9
#: The rounding of a coordinate stored in single precision (float32, as most PLY and STL files hold them),
#: relative to its magnitude: half a unit in the last place.
FLOAT32_ROUNDING = 2.0**-24


def layer_count(z_min: float, z_max: float, layer_height: float, limit: int | None = None) -> int:
    """Layers a part spanning z_min .. z_max (mm) needs at ``layer_height`` (mm): ceil of the height over h,
    at least 1, where a height within the coordinates' rounding of a whole number of layers is that number
    (a part one layer high stored in float32 gets one layer; never more than half a layer). With ``limit``, a count above it (or a ratio
    too large to count) is returned as ``limit + 1`` without being computed."""
    z_min, z_max, layer_height = float(z_min), float(z_max), float(layer_height)
    if not (math.isfinite(layer_height) and layer_height > 0):
        raise InputError(f"layer_height_mm: must be a positive number, got {layer_height}")
    ratio = (z_max - z_min) / layer_height
    if not math.isfinite(ratio) or (limit is not None and ratio > limit + 1):
        if limit is None:
            raise InputError(f"layer_height_mm: {layer_height} mm over z {z_min} .. {z_max} mm is too many layers")
        return limit + 1
    rounding = FLOAT32_ROUNDING * (abs(z_min) + abs(z_max)) / layer_height
    count = max(1, math.ceil(ratio - min(0.5, max(LAYER_COUNT_TOLERANCE, rounding))))
    return count if limit is None else min(count, limit + 1)


def plane_heights(z_min: float, z_max: float, layer_height: float) -> np.ndarray:
    """Slicing planes at layer centres: z_i = z_min + (i + 1/2) h, i = 0 .. :func:`layer_count` - 1.

    Returns (L,) float64, mm.
    """
    return z_min + (np.arange(layer_count(z_min, z_max, layer_height)) + 0.5) * layer_height
