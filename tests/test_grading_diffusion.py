"""Error diffusion of a labelled layer (heoslice.grading.diffusion.diffused_planes): the mix each label's pixels are
given, made in the kernel (from a per-label table, or per cell where a family's cells differ), against the same
diffusion of a per-pixel mix written out here with numpy."""

from __future__ import annotations

import numpy as np
import pytest

from heoslice.grading.diffusion import DiffusionCarry, diffuse_mix, diffused_planes
from heoslice.grading.droplets_kernels import LabelledLayer, LayerMixes

ROWS, COLS, CELL, BASE = 61, 90, 6, 0


def labelled_layer(seed: int, uniform: bool):
    """A labelled layer with holes and labels that change from row to row (blobs of labels 0..6, two families),
    and its mixing: each family's lattice of start mixes all one mix (``uniform``) or a different mix per cell."""
    rng = np.random.default_rng(seed)
    coarse = rng.integers(0, 7, size=(ROWS // 7 + 1, COLS // 5 + 1))
    label = np.kron(coarse, np.ones((7, 5), dtype=np.int64))[:ROWS, :COLS]
    label[rng.random((ROWS, COLS)) < 0.05] = rng.integers(0, 7)  # single pixels of another label
    solid = rng.random((ROWS // 9 + 1, COLS // 9 + 1)) < 0.85
    solid = np.kron(solid, np.ones((9, 9), dtype=bool))[:ROWS, :COLS]
    family_of_label = np.array([0, 0, 0, 0, 1, 1, 1])
    fraction = np.array([0.0, 0.0, 0.25, 0.6, 0.1, 0.5, 1.0])
    cells = (-(-ROWS // CELL), -(-COLS // CELL))
    mixes = []
    for family in range(2):
        first = rng.random(cells) * 0.8 + 0.1 if not uniform else np.full(cells, 0.3 + 0.4 * family)
        mixes.append(np.stack([first, 1 - first], axis=-1).astype(np.float32))
    layout = np.array([(0, 0, CELL, cells[1], family * mixes[0].size) for family in range(2)], dtype=np.int64)
    mixing = LayerMixes(family_of_label, fraction, layout, np.concatenate([m.ravel() for m in mixes]),
                        np.array([0.0, 1.0]))
    return label.astype(np.uint8), solid, mixing, mixes


def per_pixel_mix(label, solid, mixing, mixes) -> np.ndarray:
    """(rows, cols, 2) float32: a labelled solid pixel's family start mix at its cell moved by its label's fraction
    towards the target (eq. 1) in float32, over its total; a pixel without a label all BASE; an empty one 0."""
    rows, cols = np.indices(label.shape)
    family = mixing.family_of_label[label]
    start = np.stack(mixes)[family, rows // CELL, cols // CELL]
    f = mixing.fraction.astype(np.float32)[label][..., None]
    target = mixing.target.astype(np.float32)
    moved = start + f * (target - start)
    total = moved[..., 0] + moved[..., 1]
    first = moved[..., 0] / np.where(total > 0, total, np.float32(1))
    mix = np.stack([first, np.maximum(np.float32(1) - first, np.float32(0))], axis=-1)
    mix[(label == 0) | ~(total > 0)] = np.eye(2, dtype=np.float32)[BASE]
    mix[~solid] = 0
    return mix


@pytest.mark.parametrize("uniform", [True, False])
@pytest.mark.parametrize("seed", [1, 2])
def test_a_labelled_layer_diffuses_as_its_per_pixel_mix_does(uniform, seed):
    """Over two layers (the second taking the error the first left), the labelled layer's masks are those of the
    same diffusion of its per-pixel mix, whether its families' cells all hold one start mix or each its own."""
    label, solid, mixing, mixes = labelled_layer(seed, uniform)
    packed = np.packbits(solid, axis=1)
    mix = per_pixel_mix(label, solid, mixing, mixes)
    assert (mix[solid] > 0).all(axis=-1).mean() > 0.5  # most solid pixels mix both materials
    labelled_carry, mix_carry = DiffusionCarry(), DiffusionCarry()
    for index in (6, 7):
        planes = np.zeros((2, ROWS, packed.shape[1]), dtype=np.uint8)
        diffused = diffused_planes(LabelledLayer(label, 0, 0, packed), mixing, BASE, index, planes, labelled_carry)
        masks = np.unpackbits(diffused, axis=2, count=COLS).view(bool)
        expected = diffuse_mix(mix, index, mix_carry)
        assert np.array_equal(masks, expected)
        assert np.array_equal(masks.sum(axis=0), solid)  # every solid pixel one material, none elsewhere


def test_a_span_widening_again_after_a_new_row_of_cells_takes_that_rows_mixes():
    """A labelled layer whose solid narrows to 8 columns across the boundary between two rows of lattice cells
    (each cell its own start mix) and widens again below it: the widened pixels take the mix of their new row of
    cells, not the one their columns were last given above the boundary (the masks equal the per-pixel mix's)."""
    _, _, mixing, mixes = labelled_layer(3, uniform=False)
    label = np.full((2 * CELL, COLS), 2, dtype=np.uint8)
    solid = np.ones(label.shape, dtype=bool)
    solid[CELL - 1:CELL + 2, 8:] = False
    packed = np.packbits(solid, axis=1)
    planes = np.zeros((2, label.shape[0], packed.shape[1]), dtype=np.uint8)
    diffused = diffused_planes(LabelledLayer(label, 0, 0, packed), mixing, BASE, 4, planes, None)
    masks = np.unpackbits(diffused, axis=2, count=COLS).view(bool)
    assert np.array_equal(masks, diffuse_mix(per_pixel_mix(label, solid, mixing, mixes), 4))
