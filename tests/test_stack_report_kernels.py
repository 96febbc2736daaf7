"""The compiled design tally (stack/report_kernels.py, through stack/report.coded_tally): on random layers, masks
and per-pixel designs it finds the same worst window and the same band table as the per-pixel numpy reference
(stack/report.worst_window and band_table over the arrays the codes stand for)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.stack.packed import Bits
from heoslice.stack.report import CodedDesign, WindowGrid, band_table, coded_tally, worst_window


def per_pixel(design: CodedDesign, solid: np.ndarray, masks: int) -> tuple[np.ndarray, np.ndarray]:
    """The designed mix (K, h, w) float32 and the band labels (h, w) the codes stand for, written out per pixel."""
    (r0, r1, c0, c1), last = design.box, len(design.shares) - 1
    codes = np.minimum(design.codes.astype(np.int64), last)
    mix = np.zeros((masks, *solid.shape), np.float32)
    mix[design.target, r0:r1, c0:c1] = design.shares[codes]
    mix[design.start, r0:r1, c0:c1] = np.float32(1.0) - design.shares[codes]
    labels = np.full(solid.shape, -1, np.int64)
    labels[r0:r1, c0:c1] = design.bands[codes]
    return mix * solid, labels


@st.composite
def layers(draw):
    """A layer of random size, solid pixels, K droplet masks (a partition of the solid, or with stray and doubled
    pixels), a box holding the solid, codes and tables, and a window grid smaller or larger than the layer."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    height, width = draw(st.integers(1, 70)), draw(st.integers(1, 90))
    solid = rng.random((height, width)) < draw(st.sampled_from([0.0, 0.3, 0.9, 1.0]))
    count = draw(st.integers(2, 3))
    chosen = rng.integers(0, count, (height, width))
    masks = np.stack([(chosen == k) & solid for k in range(count)])
    if draw(st.booleans()):
        masks |= rng.random(masks.shape) < 0.02
    rows, cols = np.nonzero(solid)
    if len(rows):
        box = (int(rows.min()), int(rows.max()) + 1, 8 * (int(cols.min()) // 8), int(cols.max()) + 1)
    else:
        box = (0, 0, 0, 0)
    n = draw(st.integers(2, 50))
    codes = rng.integers(0, n + 3, (box[1] - box[0], box[3] - box[2])).astype(np.uint16)  # some past the table
    shares = rng.random(n).astype(np.float32)
    bands = np.sort(rng.integers(0, 5, n)).astype(np.int64)
    start, target = (0, 1) if draw(st.booleans()) else (1, 0)
    design = CodedDesign(box, codes, shares, bands, 5, start, target)
    size = (draw(st.integers(3, 30)), draw(st.integers(3, 30)))
    grid = WindowGrid(size, (max(1, size[0] // 4), max(1, size[1] // 4)))
    return solid, masks, design, grid


@settings(max_examples=150, deadline=None)
@given(layers())
def test_the_compiled_tally_is_the_per_pixel_reference(layer):
    """coded_tally's worst window is as far off as worst_window's over the per-pixel arrays (to 1e-9: summed in
    another order) and, unless a tie went the other way by rounding, the same window with the same shares; its band
    table is band_table's; its voxels are the masks' set pixels and its solid the solid's."""
    solid, masks, design, grid = layer
    height, width = solid.shape
    bits = [Bits(np.packbits(solid, axis=1), (0, height))] + [Bits(np.packbits(m, axis=1), (0, height))
                                                              for m in masks]
    tally = coded_tally(7, bits, design, grid, width)
    mix, labels = per_pixel(design, solid, len(masks))
    expected = worst_window(7, solid, masks, mix, grid)
    if expected is None:
        assert tally.worst is None
    else:
        got = tally.worst
        assert got is not None
        assert abs(abs(got.difference) - abs(expected.difference)) <= 1e-9
        if (got.material, got.pixel) == (expected.material, expected.pixel):  # else a tie broken by rounding
            assert (got.layer, got.solid) == (7, expected.solid)
            assert abs(got.designed - expected.designed) <= 1e-9 and abs(got.delivered - expected.delivered) <= 1e-12
    table = band_table(solid, masks, mix, labels, 5)
    assert np.array_equal(tally.bands.solid, table.solid)
    assert np.array_equal(tally.bands.delivered, table.delivered)
    assert np.allclose(tally.bands.designed, table.designed, rtol=0, atol=1e-9)
    assert tally.voxels.tolist() == masks.sum(axis=(1, 2)).tolist() and tally.solid == int(solid.sum())
