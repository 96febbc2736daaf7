"""Tests of heoslice.grading.field_kernels: the sub-region labels written from each cell's plane
(expand_planes) or quadratic (curve_cells) against the plain formulas, band_field's s against eq. 10
(helpers.ring_weights) with its gradient against central differences, and cell_classes against the same
classes in numpy."""

from __future__ import annotations

import numpy as np
from helpers import ring_weights
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.grading.field import LABEL_TYPES
from heoslice.grading.field_kernels import (
    CellPixels,
    band_field,
    cell_classes,
    curve_cells,
    curved_cells,
    expand_planes,
    label_target,
)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(2, 16), st.booleans(), st.sampled_from(LABEL_TYPES), st.booleans())
def test_expand_planes_is_the_plane_formula(seed, cell, masked, label_dtype, padded):
    """Each pixel gets clip(floor(s + gx x - gy y) + 1, 1, count) of its cell's plane (x, y its offset
    from the cell centre), except where s sits within float32 rounding of an integer; a flat cell's pixels
    clip(floor(clip(s, -1, count - 1/2)) + 1, 1, count) whatever its gradient; with a mask, 0 off its pixels;
    + base on the others (labels past 127 too, in uint8); every pixel of an empty cell 0. A lattice padded by
    a cell of other values on every side (pad 1) gives what its inner part gives."""
    rng = np.random.default_rng(seed)
    rows, cols, count = int(rng.integers(1, 6)), int(rng.integers(1, 6)), int(rng.integers(1, 50))
    base = int(rng.integers(0, 200))
    s = rng.uniform(-3, count + 3, (rows, cols))
    gx, gy = rng.uniform(-3, 3, (rows, cols)), rng.uniform(-3, 3, (rows, cols))
    empty = rng.random((rows, cols)) < 0.3
    flat = rng.random((rows, cols)) < 0.3
    px, py = 0.04, 0.05
    shape = (rows * cell - int(rng.integers(0, cell)), cols * cell - int(rng.integers(0, cell)))
    mask = rng.random((shape[0] + 5, shape[1] + 4)) < 0.7 if masked else None
    arrays = (s, np.stack([gx, gy], axis=-1), empty, flat)
    if padded:
        # a border of values that would change every pixel, were it read
        arrays = tuple(np.pad(a, [(1, 1), (1, 1)] + [(0, 0)] * (a.ndim - 2), constant_values=value)
                       for a, value in zip(arrays, (count + 7.5, 2.5, False, True)))
    out = expand_planes(arrays[0], arrays[1], CellPixels(cell, px, py), count,
                        label_target(np.full(shape, 255, label_dtype), mask, (3, 2), base), arrays[2], arrays[3],
                        pad=int(padded))
    r, c = np.indices(shape)
    i, j = r // cell, c // cell
    x = (c - j * cell + 0.5 - cell / 2) * px
    y = (r - i * cell + 0.5 - cell / 2) * py
    value = np.where(flat[i, j], np.clip(s[i, j], -1, count - 0.5), s[i, j] + gx[i, j] * x - gy[i, j] * y)
    expected = np.clip(np.floor(value) + 1, 1, count)
    expected = expected + base
    if masked:
        expected = np.where(mask[3:3 + shape[0], 2:2 + shape[1]], expected, 0)
    expected = np.where(empty[i, j], 0, expected)
    clear = (np.abs(value - np.rint(value)) > 1e-3) | empty[i, j]
    assert np.array_equal(out[clear], expected[clear])


def _numpy_cell_classes(s, grad, d, half_diagonal, count):
    """The cell classes written out in numpy, np.hypot and all: the reference cell_classes must equal."""
    with np.errstate(invalid="ignore", over="ignore"):
        deep = s - np.hypot(grad[..., 0], grad[..., 1]) * half_diagonal >= count
    touched = np.logical_and.reduce(d >= -half_diagonal, axis=0)
    touched[[0, -1], :] = touched[:, [0, -1]] = False
    beyond = deep | ~touched
    known = np.isfinite(s) & np.isfinite(grad[..., 0]) & np.isfinite(grad[..., 1])
    side = np.logical_and.reduce(d >= 0, axis=0)
    return touched, beyond, touched & ~beyond, known, side


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(1, 4), st.sampled_from([1e-200, 1e-3, 1.0, 1e3, 1e160]))
def test_cell_classes_equal_numpy_bit_for_bit(seed, sets, scale):
    """Every class of every cell equals numpy's (the deep test with np.hypot), also where s - |grad| h lands
    within a few units in the last place of N_R (the fast square root cannot decide there), for gradients
    tiny or huge enough to underflow or overflow their squares, and for NaN and infinite values."""
    rng = np.random.default_rng(seed)
    rows, cols, count = int(rng.integers(1, 7)), int(rng.integers(1, 7)), int(rng.integers(1, 300))
    half_diagonal = float(rng.uniform(0.05, 1.0))
    grad = rng.normal(0.0, 1.0, (rows, cols, 2)) * scale
    s = rng.uniform(-2.0, count + 2.0, (rows, cols))
    # s put on the threshold, give or take an ulp or two, mostly where sqrt(gx^2 + gy^2) is not hypot(gx, gy)
    edge = rng.random((rows, cols)) < 0.5
    pool = rng.normal(0.0, 1.0, (4096, 2)) * scale
    with np.errstate(over="ignore", under="ignore"):
        unlike = pool[np.sqrt((pool ** 2).sum(axis=1)) != np.hypot(pool[:, 0], pool[:, 1])]
    if len(unlike):
        grad[edge] = unlike[rng.integers(0, len(unlike), int(edge.sum()))]
    on = count + np.hypot(grad[..., 0], grad[..., 1]) * half_diagonal
    s[edge] = (on + rng.integers(-2, 3, (rows, cols)) * np.spacing(on))[edge]
    special = rng.random((rows, cols, 3)) < 0.08
    values = np.array([np.nan, np.inf, -np.inf])
    s = np.where(special[..., 0], values[rng.integers(0, 3, (rows, cols))], s)
    grad = np.where(special[..., 1:], values[rng.integers(0, 3, (rows, cols, 2))], grad)
    d = rng.uniform(-1.5 * half_diagonal, 1.0, (sets, rows, cols))
    d[rng.random(d.shape) < 0.05] = np.nan
    for got, expected in zip(cell_classes(s, grad, d, half_diagonal, count),
                             _numpy_cell_classes(s, grad, d, half_diagonal, count)):
        assert got.dtype == np.bool_ and np.array_equal(got, expected)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2 ** 32 - 1))
def test_curved_cells_are_numpys_nonzero(seed):
    """curved_cells gives np.nonzero of the inner part's candidates, not refined, whose Hessian is not all
    zero (NaN is not zero), in the same order, as inner indices."""
    rng = np.random.default_rng(seed)
    rows, cols = int(rng.integers(1, 9)), int(rng.integers(1, 9))
    hessian = np.where(rng.random((3, rows, cols)) < 0.4, rng.normal(size=(3, rows, cols)), 0.0)
    hessian[rng.random(hessian.shape) < 0.05] = np.nan
    candidate, refine = rng.random((rows, cols)) < 0.6, rng.random((rows, cols)) < 0.3
    inner = (slice(1, -1), slice(1, -1))
    expected = np.nonzero((hessian[:, 1:-1, 1:-1] != 0).any(axis=0) & candidate[inner] & ~refine[inner])
    got = curved_cells(hessian, candidate, refine)
    assert all(np.array_equal(a, b) for a, b in zip(got, expected))


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(2, 6))
def test_band_field_is_eq10_and_its_gradient(seed, sets):
    """With distances to circles (signed, > 0 on the family's side: inside the first, outside the others),
    band_field's s is (1 - w_start) N_R of eq. 10 (helpers.ring_weights) wherever every distance is
    positive, its gradient matches central differences of s, and s is NaN where the continuation passes
    its pole (d_m + d_start A <= 0)."""

    rng = np.random.default_rng(seed)
    centres = np.vstack([[0.0, 0.0], rng.uniform(-5, 5, (sets - 1, 2))])
    radii = np.concatenate([[9.0], rng.uniform(0.3, 1.5, sets - 1)])
    count = int(rng.integers(2, 30))

    def field(x, y):
        rho = np.hypot(x[None] - centres[:, 0, None, None], y[None] - centres[:, 1, None, None])
        sign = np.where(np.arange(sets) == 0, -1.0, 1.0)[:, None, None]
        d = sign * (rho - radii[:, None, None])
        g = np.stack([x[None] - centres[:, 0, None, None], y[None] - centres[:, 1, None, None]], axis=-1)
        return d, g * (sign / rho)[..., None]

    x, y = np.meshgrid(np.linspace(-8, 8, 23), np.linspace(-8, 8, 19))
    with np.errstate(invalid="ignore", divide="ignore"):
        d, g = field(x, y)
    s, grad = band_field(d, g, count)
    positive = (d > 0).all(axis=0)
    expected = (1.0 - ring_weights(np.moveaxis(d, 0, -1)[positive])[:, 0]) * count
    np.testing.assert_allclose(s[positive], expected, rtol=1e-9)
    h = 1e-6
    numeric_x = (band_field(*field(x + h, y), count)[0] - band_field(*field(x - h, y), count)[0]) / (2 * h)
    numeric_y = (band_field(*field(x, y + h), count)[0] - band_field(*field(x, y - h), count)[0]) / (2 * h)
    smooth = positive & np.isfinite(g).all(axis=(0, 3))  # not at a circle's centre, where its gradient is 0 / 0
    np.testing.assert_allclose(grad[smooth, 0], numeric_x[smooth], rtol=1e-4, atol=1e-4 * count)
    np.testing.assert_allclose(grad[smooth, 1], numeric_y[smooth], rtol=1e-4, atol=1e-4 * count)
    far = np.full((sets, 1, 1), 1.0)
    far[0] = -50.0  # deep off the family's side: d_m + d_start A = 1 - 50 A < 0
    assert np.isnan(band_field(far, np.zeros((sets, 1, 1, 2)), count)[0]).all()


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.booleans(), st.sampled_from(LABEL_TYPES))
def test_curve_cells_is_the_quadratic_formula(seed, masked, label_dtype):
    """curve_cells writes clip(floor(s + g.d + d.H.d / 2) + 1, 1, count) at every pixel of the given cells
    (d the pixel's offset from the cell centre, y up), + base (labels past 127 too, in uint8), and 0 off the
    mask's pixels, and leaves every other pixel alone."""
    rng = np.random.default_rng(seed)
    cell, rows, cols, count, base = 6, 4, 5, 30, int(rng.integers(0, 220))
    s = rng.uniform(-2, count + 2, (rows, cols))
    grad = rng.uniform(-4, 4, (rows, cols, 2))
    hessian = rng.uniform(-9, 9, (3, rows, cols))
    px = py = 0.05
    index = np.full((rows * cell - 2, cols * cell - 1), 255, dtype=label_dtype)
    mask = rng.random(index.shape) < 0.6 if masked else None
    ci, cj = np.array([0, 3, 2]), np.array([1, 4, 0])
    curve_cells(label_target(index, mask, (0, 0), base), ci, cj, CellPixels(cell, px, py), s, grad, hessian, count)
    r, c = np.indices(index.shape)
    i, j = r // cell, c // cell
    x = (c - j * cell + 0.5 - cell / 2) * px
    y = -(r - i * cell + 0.5 - cell / 2) * py
    g, h = grad[i, j], hessian[:, i, j]
    value = s[i, j] + g[..., 0] * x + g[..., 1] * y + 0.5 * (h[0] * x * x + h[2] * y * y) + h[1] * x * y
    expected = np.clip(np.floor(value) + 1, 1, count) + base
    if masked:
        expected = np.where(mask, expected, 0)
    chosen = np.zeros((rows, cols), bool)
    chosen[ci, cj] = True
    inside = chosen[i, j]
    clear = np.abs(value - np.rint(value)) > 1e-9
    assert np.array_equal(index[inside & clear], expected[inside & clear])
    assert (index[~inside] == 255).all()
