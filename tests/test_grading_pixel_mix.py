"""Per-pixel shares halftoned (grading/pixel_mix.py): every solid pixel jets exactly one material, empty pixels
none, a pixel jets the target exactly where its dither threshold is below its f, and over each aligned 16 x 16
tile of one f the target's share is within 1/512 of f."""

from __future__ import annotations

import numpy as np
import pytest

from heoslice.grading.halftone import thresholds
from heoslice.grading.pixel_mix import fraction_planes, levels_below
from heoslice.layers.rasterising import Grid


def test_levels_below_counts_the_dither_levels_under_f():
    f = np.array([0.0, 0.5 / 256, 0.5 / 256 + 1e-12, 0.5, 1.0])
    levels = (np.arange(256) + 0.5) / 256
    assert levels_below(f).tolist() == [(levels < v).sum() for v in f]


@pytest.mark.parametrize("layer", [0, 7])
@pytest.mark.parametrize("start, target, channels", [(0, 1, 2), (1, 0, 2), (2, 0, 3)])
def test_each_pixel_jets_the_target_where_its_threshold_is_below_f(layer, start, target, channels):
    rng = np.random.default_rng(layer)
    grid = Grid(96, 64, 0.0, 10.0, 0.1, 0.1)
    solid = np.zeros((grid.height, grid.width), dtype=bool)
    solid[:, 16:96] = True
    solid[5, 40] = False
    packed = np.packbits(solid, axis=1)
    tile_f = rng.random((grid.height // 16, grid.width // 16))
    f = np.kron(tile_f, np.ones((16, 16)))
    own = rng.random(f.shape) < 0.01
    f[own] = rng.random(int(own.sum()))  # some pixels of their own f
    planes = fraction_planes(packed, (0, 64, 16, 96), f[:, 16:], grid, layer, start, target, channels)
    masks = np.unpackbits(planes, axis=2, count=grid.width).astype(bool)
    assert (masks.sum(axis=0) == solid).all()
    others = [c for c in range(channels) if c not in (start, target)]
    assert not masks[others].any()
    t = thresholds((grid.height, grid.width), layer)
    assert (masks[target][solid] == (t < f)[solid]).all()
    for i in range(4):
        for j in range(2, 6):
            box = (slice(16 * i, 16 * i + 16), slice(16 * j, 16 * j + 16))
            plain = solid[box] & ~own[box]
            if solid[box].all() and not own[box].any():
                assert abs(masks[target][box].mean() - tile_f[i, j]) <= 1 / 512
            assert (masks[target][box][plain] == (t[box] < tile_f[i, j])[plain]).all()


@pytest.mark.parametrize("method", ["blue-noise", "error-diffusion"])
@pytest.mark.parametrize("share", [0.3, 0.7])
def test_other_halftone_methods_keep_one_material_per_pixel_and_the_share(method, share):
    """With --halftone blue-noise or error-diffusion the field interior's masks still give every solid pixel
    exactly one of its two materials, none to an empty pixel, and deliver the share f within 1 % over a
    constant 256 x 192 box (the halftone of heoslice.grading.halftone.halftone)."""
    from heoslice.grading.diffusion import DiffusionCarry

    grid = Grid(272, 200, 0.0, 10.0, 0.1, 0.1)
    solid = np.zeros((grid.height, grid.width), dtype=bool)
    solid[4:196, 16:272] = True
    planes = fraction_planes(np.packbits(solid, axis=1), (4, 196, 16, 272), np.float32(share), grid, 3, 0, 1, 2,
                             method=method, carry=DiffusionCarry() if method == "error-diffusion" else None)
    masks = np.unpackbits(planes, axis=2, count=grid.width).astype(bool)
    assert (masks.sum(axis=0) == solid).all()
    assert abs(masks[1][solid].mean() - share) <= 0.01
