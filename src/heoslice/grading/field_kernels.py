"""Compiled loops of :mod:`heoslice.grading.field`: eq. 10's band coordinate at lattice centres and the
expansion of one plane (or quadratic) per lattice cell to its pixels."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from heoslice.jit import EXACT, JIT, f64, helper, i64, kernel


class CellPixels(NamedTuple):
    """A lattice's cells in pixels: ``cell`` pixels a side, each pixel px x py mm."""

    cell: int
    px: float
    py: float


class LabelTarget(NamedTuple):
    """Where a kernel writes sub-region labels: ``out`` ((rows, cols) uint8/16/32) covers the layer's pixels
    from (row0, col0); with a ``mask`` ((h, w) bool over the layer; 0 x 0: none) pixels where it is False
    get 0; ``base`` is added to every k (a family's labels in the same pass)."""

    out: np.ndarray
    mask: np.ndarray
    row0: int
    col0: int
    base: float


def label_target(out: np.ndarray, mask: np.ndarray | None = None, origin: tuple[int, int] = (0, 0),
                 base: int = 0) -> LabelTarget:
    """The LabelTarget writing ``out`` from pixel ``origin`` (row, col) of the layer, masked by ``mask``."""
    mask = np.zeros((0, 0), dtype=np.bool_) if mask is None else np.ascontiguousarray(mask)
    return LabelTarget(out, mask, int(origin[0]), int(origin[1]), float(base))


@helper(JIT)
def nearest_end(d, sets):  # pragma: no cover - compiled
    """Index m (1..sets-1) of the ending ring set nearest in |d| (the first of equals), d (sets,) mm."""
    m = 1
    for j in range(2, sets):
        if abs(d[j]) < abs(d[m]):
            m = j
    return m


@helper(JIT)
def inverse_distance(value):  # pragma: no cover - compiled
    """1 / d, with |d| below 1e-12 taken as 1e-12 (a pixel on a ring)."""
    return 1.0 / (value if abs(value) >= 1e-12 else 1e-12)


@kernel(JIT)
def _band_field(d, g, count):  # pragma: no cover - compiled
    """s of eq. 10 (pole-free form, field._band_coordinate) and its gradient at every lattice
    centre, from the signed distances d (sets, rows, cols) and their gradients g (sets, rows,
    cols, 2) of the starting ring set (0) and each ending one; NaN past a pole."""
    sets, rows, cols = d.shape
    s = np.empty((rows, cols))
    grad = np.empty((rows, cols, 2))
    here = np.empty(sets)
    for i in range(rows):
        for j in range(cols):
            for k in range(sets):
                here[k] = d[k, i, j]
            m = nearest_end(here, sets)
            rest, rest_x, rest_y = 0.0, 0.0, 0.0
            for k in range(1, sets):
                if k != m:
                    inverse = inverse_distance(here[k])
                    rest += inverse
                    rest_x -= g[k, i, j, 0] * inverse * inverse
                    rest_y -= g[k, i, j, 1] * inverse * inverse
            dm, d0 = here[m], here[0]
            a = 1.0 + dm * rest
            numerator = d0 * a
            denominator = dm + numerator
            if not denominator > 0:
                s[i, j], grad[i, j, 0], grad[i, j, 1] = np.nan, np.nan, np.nan
                continue
            scale = count / denominator
            s[i, j] = numerator * scale
            for axis, rest_axis in ((0, rest_x), (1, rest_y)):
                grad_a = g[m, i, j, axis] * rest + dm * rest_axis
                grad_numerator = g[0, i, j, axis] * a + d0 * grad_a
                grad[i, j, axis] = (dm * grad_numerator - numerator * g[m, i, j, axis]) * scale / denominator
    return s, grad


def band_field(d: np.ndarray, g: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """(s (rows, cols), its gradient (rows, cols, 2) per mm) of eq. 10 at lattice centres from the signed
    distances d (sets, rows, cols) mm and gradients g (sets, rows, cols, 2) of the starting ring set
    and each ending one (two or more sets; compiled :func:`_band_field`)."""
    return _band_field(f64(d), f64(g),
                       float(count))


@kernel(EXACT)
def _cell_classes(s, gx, gy, d, half_diagonal, count):  # pragma: no cover - compiled
    """(touched, beyond, candidate, known, side) of :func:`cell_classes`, from the gradient's components
    (gx, gy: contiguous each, so the passes vectorise). The deep test, s - hypot(gx, gy) half_diagonal >=
    count, is numpy's bit for bit: from sqrt(gx^2 + gy^2) first, then, where its few units in the last
    place could change the answer (also for NaN, infinities and squares that overflow: the margin test
    fails there), again from hypot itself (libm's, the one numpy calls, a few times slower). ``~`` of a
    bool is its negation here, as in numpy (not Python's -2)."""
    sets, rows, cols = d.shape
    touched = np.zeros((rows, cols), dtype=np.bool_)
    side = np.ones((rows, cols), dtype=np.bool_)
    touched[1:-1, 1:-1] = True
    for k in range(sets):
        for i in range(rows):
            for j in range(cols):
                touched[i, j] &= d[k, i, j] >= -half_diagonal
                side[i, j] &= d[k, i, j] >= 0.0
    beyond = np.empty((rows, cols), dtype=np.bool_)
    candidate = np.empty((rows, cols), dtype=np.bool_)
    known = np.empty((rows, cols), dtype=np.bool_)
    settled = np.empty((rows, cols), dtype=np.bool_)
    unsettled = 0
    for i in range(rows):
        for j in range(cols):
            value, x, y = s[i, j], gx[i, j], gy[i, j]
            plane = np.sqrt(x * x + y * y) * half_diagonal
            estimate = value - plane
            deep = estimate >= count
            sure = abs(estimate - count) > 1e-12 * (abs(value) + plane + count)
            unsettled += ~sure
            settled[i, j] = sure
            beyond[i, j] = deep | ~touched[i, j]
            candidate[i, j] = touched[i, j] & ~deep
            known[i, j] = np.isfinite(value) & np.isfinite(x) & np.isfinite(y)
    for i in range(rows if unsettled else 0):
        for j in range(cols):
            if not settled[i, j]:
                deep = s[i, j] - np.hypot(gx[i, j], gy[i, j]) * half_diagonal >= count
                beyond[i, j] = deep or not touched[i, j]
                candidate[i, j] = touched[i, j] and not deep
    return touched, beyond, candidate, known, side


def cell_classes(s: np.ndarray, grad: np.ndarray, d: np.ndarray, half_diagonal: float,
                 count: int) -> tuple[np.ndarray, ...]:
    """What each cell of a (padded) lattice is, (rows, cols) bool each, from s and its gradient there ((rows,
    cols), (rows, cols, 2) per mm) and the signed distances d ((sets, rows, cols) mm) to the ring sets:
    ``touched`` (it may hold solid pixels: its centre within ``half_diagonal`` mm of the family's side of
    every set; never on the lattice's border), ``beyond`` (deep enough that every pixel is in the last
    sub-region, s - |grad| half_diagonal >= count, or not touched), ``candidate`` (touched, not beyond),
    ``known`` (s and its gradient finite) and ``side`` (on the family's side of every set)."""
    return _cell_classes(f64(s), f64(grad[..., 0]), f64(grad[..., 1]), f64(d), float(half_diagonal), float(count))


@kernel(JIT, label_arg=7)
def _expand_planes(s, grad, empty, flat, pad, pixels, count, target):  # pragma: no cover - compiled
    """out[i*cell + v, j*cell + u] = clip(floor(s_ij + gx_ij x_u - gy_ij y_v) + 1, 1, count) over the
    part of the lattice that ``out`` covers; x_u, y_v are pixel offsets from the cell centre (mm),
    plus ``base``; with a ``mask`` (not 0 x 0), pixels where mask[r0 + row, c0 + col] is False get
    0. ``empty`` cells (no pixel of the family) get 0 without evaluating; a ``flat`` cell takes
    clip(s_ij, -1, count - 1/2) throughout (s finite). Cell (i, j) is entry (i + pad, j + pad) of s,
    grad (its gx, gy), empty and flat (a padded lattice read in place). Per row of
    cells the column terms are laid out once (float32: s to ~1e-4 of a band), so each pixel
    row is a few long branch-free loops, one per run of cells that are not empty."""
    cell, px, py = pixels
    out, mask, r0, c0, base = target
    rows, cols = out.shape
    masked = mask.shape[0] > 0
    half = 0.5 * cell
    column = np.empty(cols, dtype=np.float32)
    slope = np.empty(cols, dtype=np.float32)
    cells_r, cells_c = s.shape[0] - 2 * pad, s.shape[1] - 2 * pad
    span_from = np.empty(cells_c + 1, dtype=np.int64)
    span_to = np.empty(cells_c + 1, dtype=np.int64)
    low, high, offset = np.float32(1.0), np.float32(count), np.float32(base)
    for i in range(cells_r):
        if i * cell >= rows:
            break
        spans = 0
        for j in range(min(cells_c, -(-cols // cell))):
            if empty[i + pad, j + pad]:
                continue
            first, last = j * cell, min(cols, (j + 1) * cell)
            if spans and span_to[spans - 1] == first:
                span_to[spans - 1] = last
            else:
                span_from[spans], span_to[spans] = first, last
                spans += 1
            level, across, down_slope = s[i + pad, j + pad], grad[i + pad, j + pad, 0], grad[i + pad, j + pad, 1]
            if flat[i + pad, j + pad]:
                level, across, down_slope = min(max(level, -1.0), count - 0.5), 0.0, 0.0
            for c in range(first, last):
                column[c] = level + 1.0 + across * ((c - j * cell + 0.5 - half) * px)
                slope[c] = down_slope * py
        for v in range(min(cell, rows - i * cell)):
            r = i * cell + v
            down = np.float32(v + 0.5 - half)
            line = out[r]
            keep = mask[r0 + r, c0:c0 + cols] if masked else mask[0, 0:0]
            done = 0
            for n in range(spans):
                lo, hi = span_from[n], span_to[n]
                line[done:lo] = 0
                done = hi
                _expand_run(line[lo:hi], column[lo:hi], slope[lo:hi], keep[lo:hi] if masked else keep, down, low,
                            high, offset, masked)
            line[done:] = 0
    return out


@helper(JIT)
def _expand_run(line, column, slope, keep, down, low, high, offset, masked):  # pragma: no cover - compiled
    """One run of a pixel row in :func:`_expand_planes`: a branch-free loop that vectorises."""
    if masked:
        for c in range(len(line)):
            value = column[c] - slope[c] * down
            value = low if value < low else value
            value = high if value > high else value
            line[c] = np.int32((value + offset) * np.float32(keep[c]))
    else:
        for c in range(len(line)):
            value = column[c] - slope[c] * down
            value = low if value < low else value
            value = high if value > high else value
            line[c] = np.int32(value + offset)


def expand_planes(s: np.ndarray, grad: np.ndarray, pixels: CellPixels, count: int, target: LabelTarget,
                  empty: np.ndarray | None = None, flat: np.ndarray | None = None, pad: int = 0) -> np.ndarray:
    """Sub-region k = clip(floor(s) + 1, 1, count) at every pixel of ``target.out`` ((rows, cols),
    rows <= cells_r * cell) from one plane per lattice cell: s (cells_r, cells_c) at the cell
    centre, gradient ``grad`` (cells_r, cells_c, 2) per mm (y up, rows down), written as :class:`LabelTarget`
    says. ``empty`` ((cells_r, cells_c) bool) cells are written 0 throughout; a ``flat`` one (same shape)
    takes its centre's value clipped to [-1, count - 1/2] throughout (s finite there). With ``pad`` 1 the
    four arrays are a lattice padded by a cell on every side, of which the inner part is read (no copy of
    it). Returns ``target.out``."""
    cell, out = int(pixels.cell), target.out
    cells_r, cells_c = np.shape(s)[0] - 2 * pad, np.shape(s)[1] - 2 * pad
    if out.shape[0] > cells_r * cell or out.shape[1] > cells_c * cell:
        raise ValueError(f"expand_planes: {out.shape} pixels exceed {(cells_r, cells_c)} cells of {cell}")
    empty, flat = (np.zeros(np.shape(s), dtype=np.bool_) if cells is None
                   else np.ascontiguousarray(cells, dtype=np.bool_) for cells in (empty, flat))
    pixels = CellPixels(cell, float(pixels.px), float(pixels.py))
    return _expand_planes(f64(s), f64(grad), empty, flat, int(pad), pixels, float(count), target)


@kernel(EXACT)
def _curved_cells(hessian, candidate, refine):  # pragma: no cover - compiled
    """The (row, column) indices of :func:`curved_cells`, counted first, then written."""
    _, rows, cols = hessian.shape
    count = 0
    for _pass in range(2):
        ci = np.empty(count, dtype=np.int64)
        cj = np.empty(count, dtype=np.int64)
        n = 0
        for i in range(1, rows - 1):
            for j in range(1, cols - 1):
                if (candidate[i, j] and not refine[i, j]
                        and (hessian[0, i, j] != 0.0 or hessian[1, i, j] != 0.0 or hessian[2, i, j] != 0.0)):
                    if _pass:
                        ci[n], cj[n] = i - 1, j - 1
                    n += 1
        count = n
    return ci, cj


def curved_cells(hessian: np.ndarray, candidate: np.ndarray, refine: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cells of a padded lattice's inner part that take their quadratic (np.nonzero order, inner
    indices, (n,) int each): candidates not refined whose Hessian ((3, rows, cols), as
    :func:`heoslice.grading.refine.cells_to_refine` left it) is not all zero (NaN counts as not zero)."""
    return _curved_cells(f64(hessian), np.ascontiguousarray(candidate, dtype=np.bool_),
                         np.ascontiguousarray(refine, dtype=np.bool_))


@kernel(JIT, label_arg=0)
def _curve_cells(target, ci, cj, pixels, quadratics, count):  # pragma: no cover - compiled
    """Rewrite whole cells (ci, cj) from their quadratics ((n, 6): s, gx, gy, hxx, hxy, hyy of each, see
    :func:`curve_cells`): along each pixel row of a cell the quadratic is A + (B + C x) x, one branch-free
    loop."""
    index, mask, r0, c0, base = target
    cell, px, py = pixels
    rows, cols = index.shape
    masked = mask.shape[0] > 0
    half = 0.5 * cell
    offsets = (np.arange(cell) + 0.5 - half) * px
    for n in range(len(ci)):
        i, j = ci[n], cj[n]
        height, width = min(cell, rows - i * cell), min(cell, cols - j * cell)
        if height <= 0 or width <= 0:
            continue
        s, gx, gy = quadratics[n, 0], quadratics[n, 1], quadratics[n, 2]
        hxy, hyy = quadratics[n, 4], quadratics[n, 5]
        c = 0.5 * quadratics[n, 3]
        for v in range(height):
            r = i * cell + v
            y = -(v + 0.5 - half) * py
            a = s + 1.0 + gy * y + 0.5 * hyy * y * y
            b = gx + hxy * y
            line = index[r, j * cell:j * cell + width]
            if masked:
                keep = mask[r0 + r, c0 + j * cell:c0 + j * cell + width]
                for u in range(width):
                    x = offsets[u]
                    value = min(max(np.floor(a + (b + c * x) * x), 1.0), count)
                    line[u] = int((value + base) * keep[u])
            else:
                for u in range(width):
                    x = offsets[u]
                    line[u] = int(min(max(np.floor(a + (b + c * x) * x), 1.0), count) + base)
    return index


def curve_cells(target: LabelTarget, ci: np.ndarray, cj: np.ndarray, pixels: CellPixels, s: np.ndarray,
                grad: np.ndarray, hessian: np.ndarray, count: int) -> np.ndarray:
    """Sub-region k of every pixel of lattice cells (ci, cj) ((n,) int) from the cell's quadratic
    s + g.d + d.H.d / 2 (s (rows, cols), grad (rows, cols, 2) per mm, hessian (3, rows, cols)
    s_xx, s_xy, s_yy per mm^2; d the pixel's offset from the cell centre, y up), in place in
    ``target`` (as :func:`expand_planes`). Only the given cells' terms are gathered: the lattice-wide arrays
    may be views of a padded lattice, never copied whole."""
    ci, cj = i64(ci), i64(cj)
    quadratics = np.column_stack([np.asarray(s)[ci, cj], np.asarray(grad)[ci, cj], np.asarray(hessian)[:, ci, cj].T])
    pixels = CellPixels(int(pixels.cell), float(pixels.px), float(pixels.py))
    return _curve_cells(target, ci, cj, pixels, f64(quadratics), float(count))
