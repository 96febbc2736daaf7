"""Tests of heoslice.volume.resample_kernels: _label_codes, which decides the label rule once per piece of a
pixel row between the points where it may change, sets every pixel the rule written out per pixel (a
brute-force numpy reference) would set, except pixels within rounding of such a point."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.volume.resample_kernels import _label_codes

#: Pixels per voxel cell along each axis, and the margin (voxels) within which rounding may decide a pixel.
PER_CELL, TIE = 9, 1e-4


def reference(fields, boost, codes, crack, rows, columns):
    """The rule per pixel: the fields bilinear at each pixel ((L, H, W) float64), the winner by score (field,
    plus boost where positive), solid where a field is positive or the two highest come within ``crack``.
    Returns (code per pixel, -1 where not solid; a (H, W) bool of pixels within TIE of a decision's edge)."""
    cy, fy = rows
    cx, fx = columns
    f = fields.astype(np.float64)
    below = f[:, cy][:, :, cx] + fx * (f[:, cy][:, :, cx + 1] - f[:, cy][:, :, cx])
    above = f[:, cy + 1][:, :, cx] + fx * (f[:, cy + 1][:, :, cx + 1] - f[:, cy + 1][:, :, cx])
    values = below + fy[None, :, None] * (above - below)
    score = np.where(values > 0, values + boost[:, None, None], values)
    winner = np.argmax(score, axis=0)
    ordered = np.sort(values, axis=0)
    top = ordered[-1]
    second = ordered[-2] if len(values) > 1 else np.full_like(top, -np.inf)
    solid = (top > 0) | (second > -crack)
    code = np.where(solid, codes[winner].astype(np.int64), -1)
    gaps = np.abs(values[:, None] - values[None, :]) + np.eye(len(values))[:, :, None, None]
    gaps[np.maximum(values[:, None], values[None, :]) < -crack - TIE] = np.inf  # neither can win nor make solid
    tie = (np.abs(values).min(axis=0) < TIE) | (np.abs(values + crack).min(axis=0) < TIE) | \
        (gaps.min(axis=(0, 1)) < TIE)
    return code, tie


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2 ** 31), st.integers(1, 5), st.booleans())
def test_label_codes_match_the_rule_per_pixel(seed, count, boosted):
    """Random fields of ``count`` labels on a 7 x 8 node grid (some beyond their box, far outside; some labels
    boosted): every pixel's solid bit and material code are the reference's, but for pixels at a tie."""
    rng = np.random.default_rng(seed)
    rows_n, columns_n, crack = 7, 8, 0.25
    fields = rng.uniform(-2.0, 1.5, (count, rows_n, columns_n)).astype(np.float32)
    boxes = np.zeros((count, 4), dtype=np.int64)
    for label in range(count):
        y0, x0 = rng.integers(0, 3, 2)
        y1, x1 = rng.integers(y0 + 2, rows_n + 1), rng.integers(x0 + 2, columns_n + 1)
        boxes[label] = (y0, y1, x0, x1)
        outside = np.ones((rows_n, columns_n), dtype=bool)
        outside[y0:y1, x0:x1] = False
        fields[label][outside] = -1e3
    boost = np.where(rng.random(count) < 0.4, 1e4, 0.0).astype(np.float32) if boosted else np.zeros(count, np.float32)
    codes = rng.integers(0, 4, count).astype(np.uint8)  # 0: the solid mask only
    steps = ((np.arange(PER_CELL) + 0.5) / PER_CELL).astype(np.float32)
    row_cell = np.repeat(np.arange(rows_n - 1), PER_CELL).astype(np.int64)
    row_frac = np.tile(steps, rows_n - 1)
    col_cell = np.repeat(np.arange(columns_n - 1), PER_CELL).astype(np.int64)
    col_frac = np.tile(steps, columns_n - 1)
    cell_start = (np.arange(columns_n) * PER_CELL).astype(np.int64)
    height, width = len(row_cell), len(col_cell)
    planes = np.zeros((4, height, -(-width // 8)), dtype=np.uint8)
    counts = np.zeros(4, dtype=np.int64)
    _label_codes(fields, boost, codes, boxes, crack, row_cell, row_frac, cell_start, col_frac, planes, counts)
    got = np.unpackbits(planes, axis=2, count=width).astype(bool)
    want, tie = reference(fields, boost, codes, crack, (row_cell, row_frac), (col_cell, col_frac))
    assert tie.mean() < 0.02
    settled = ~tie
    assert np.array_equal(got[0][settled], (want >= 0)[settled])
    for code in (1, 2, 3):
        assert np.array_equal(got[code][settled], (want == code)[settled])
    assert np.array_equal(counts, got.reshape(4, -1).sum(axis=1))
    assert not (got[1] & got[2]).any() and not (got[1] & got[3]).any() and not (got[2] & got[3]).any()
