"""Tests of heoslice.grading.halftone: one material per solid pixel, shares within 2 % over 2 mm x 2 mm, layers decorrelated."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import choose_materials, droplet_masks
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.grading.halftone import TILE, bayer_matrix, layer_tile, thresholds

#: 2 mm at 600 dpi, in pixels.
WINDOW = int(round(2.0 / (25.4 / 600)))


def test_bayer_matrix_holds_every_level_once():
    """The 16 x 16 Bayer matrix is a permutation of 0..255 (each threshold level once per tile)."""
    assert sorted(bayer_matrix(TILE).ravel().tolist()) == list(range(TILE * TILE))
    assert bayer_matrix(2).tolist() == [[0, 2], [3, 1]]
    with pytest.raises(ValueError):
        bayer_matrix(12)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 5), st.integers(0, 10_000), st.integers(0, 2**31 - 1))
def test_every_solid_pixel_gets_exactly_one_material(count, layer, seed):
    """For any fractions and any solid mask, each solid pixel is set in exactly one mask and empty pixels in none."""
    rng = np.random.default_rng(seed)
    fractions = rng.random((count, 37, 53)) ** 3
    fractions /= fractions.sum(axis=0)
    solid = rng.random((37, 53)) < 0.7
    masks = droplet_masks(fractions, solid, layer, origin=(int(rng.integers(0, 99)), int(rng.integers(0, 99))))
    assert masks.shape == (count, 37, 53)
    assert np.array_equal(masks.sum(axis=0), solid.astype(int))


@pytest.mark.parametrize("mix", [(0.5, 0.5), (0.2, 0.35, 0.45), (0.03, 0.97), (0.1, 0.2, 0.3, 0.4), (1.0, 0.0)])
def test_shares_within_two_percent_over_two_millimetres(mix):
    """Over every sampled 2 mm x 2 mm window (47 x 47 px at 600 dpi) of a constant mix, each material's
    share of the pixels is within 2 % of its fraction, on several layers and window positions."""
    rng = np.random.default_rng(7)
    fractions = np.broadcast_to(np.array(mix)[:, None, None], (len(mix), 300, 300))
    solid = np.ones((300, 300), dtype=bool)
    for layer in range(6):
        masks = droplet_masks(fractions, solid, layer)
        for _ in range(40):
            r, c = rng.integers(0, 300 - WINDOW, size=2)
            share = masks[:, r:r + WINDOW, c:c + WINDOW].mean(axis=(1, 2))
            assert np.all(np.abs(share - np.array(mix)) <= 0.02), (layer, share, mix)


def test_unnormalised_fractions_are_normalised():
    """Fractions that do not sum to 1 are taken relative to their sum."""
    solid = np.ones((160, 160), dtype=bool)
    masks = droplet_masks(np.stack([np.full((160, 160), 2.0), np.full((160, 160), 6.0)]), solid, 3)
    assert masks[0].mean() == pytest.approx(0.25, abs=0.01)


def test_layers_are_decorrelated():
    """At a 50/50 mix consecutive layers do not jet the same pattern: the masks of material 0 of layers
    L and L+1 agree on clearly fewer pixels than identical masks would (about half for independent ones)."""
    fractions = np.full((2, 64, 64), 0.5)
    solid = np.ones((64, 64), dtype=bool)
    agreements = []
    for layer in range(20):
        a = droplet_masks(fractions, solid, layer)[0]
        b = droplet_masks(fractions, solid, layer + 1)[0]
        agreements.append((a == b).mean())
    assert np.mean(agreements) < 0.75
    assert len({layer_tile(layer).tobytes() for layer in range(20)}) > 15


def test_every_layers_tile_holds_every_level_and_each_pixel_runs_through_the_quarters():
    """Each layer's ordered tile holds each of the 256 levels once (its shares exact over every aligned tile), and
    over any 4 consecutive layers each pixel's threshold lies once in each quarter of [0, 1), halves alternating
    (so a material of 1/4 or more reaches every pixel at least once every 4 layers)."""
    tiles = np.stack([layer_tile(layer) for layer in range(300)])
    levels = np.rint(tiles * 256 - 0.5).astype(int)
    assert all(sorted(tile.ravel().tolist()) == list(range(256)) for tile in levels)
    quarters = levels // 64
    for first in range(len(tiles) - 3):
        assert (np.sort(quarters[first:first + 4], axis=0) == np.arange(4)[:, None, None]).all(), first
    halves = levels // 128
    assert (halves[1:] != halves[:-1]).all()


def test_threshold_tile_is_anchored_to_the_layer():
    """A box's thresholds are the layer's thresholds at the same pixels, whatever the box's origin."""
    full = thresholds((40, 50), layer=11)
    part = thresholds((10, 20), layer=11, origin=(17, 23))
    assert np.array_equal(full[17:27, 23:43], part)
    assert np.all((full > 0) & (full < 1))


def test_choose_materials_marks_empty_pixels():
    """Pixels outside the solid mask get -1; a pure material gets only that material."""
    fractions = np.zeros((3, 8, 8))
    fractions[1] = 1.0
    solid = np.zeros((8, 8), dtype=bool)
    solid[2:6, 2:6] = True
    chosen = choose_materials(fractions, solid, 0)
    assert np.all(chosen[~solid] == -1)
    assert np.all(chosen[solid] == 1)
