"""Per-pixel mixes halftoned (grading/pixel_mix.py): every solid pixel jets exactly one material, empty pixels
none, and over each aligned 16 x 16 tile of one mix each material's share is its fraction within 1/256."""

from __future__ import annotations

import numpy as np
import pytest

from heoslice.grading.pixel_mix import pixel_mix_planes, solid_pixels
from heoslice.layers.rasterising import Grid


@pytest.mark.parametrize("layer", [0, 7])
@pytest.mark.parametrize("base", [0, 1])
def test_each_tile_jets_its_mix(layer, base):
    rng = np.random.default_rng(layer)
    grid = Grid(96, 64, 0.0, 10.0, 0.1, 0.1)
    solid = np.zeros((grid.height, grid.width), dtype=bool)
    solid[:, 16:96] = True
    solid[5, 40] = False
    packed = np.packbits(solid, axis=1)
    rows, cols = solid_pixels(packed, grid.width)
    assert (solid[rows, cols]).all() and len(rows) == solid.sum()
    tile_f = rng.random((grid.height // 16, grid.width // 16))
    f = tile_f[rows // 16, cols // 16]
    mix = np.column_stack([1 - f, f]) if base == 0 else np.column_stack([f, 1 - f])
    planes = pixel_mix_planes(packed, rows, cols, mix, grid, layer, base)
    masks = np.unpackbits(planes, axis=2, count=grid.width).astype(bool)
    assert (masks.sum(axis=0) == solid).all()
    target = masks[1 - base]
    for i in range(grid.height // 16):
        for j in range(1, grid.width // 16):
            box = (slice(16 * i, 16 * i + 16), slice(16 * j, 16 * j + 16))
            share = target[box][solid[box]].mean()
            assert abs(share - tile_f[i, j]) <= 1.5 / 256 + (1 / solid[box].sum() if not solid[box].all() else 0)
