"""The lattice fit of a family graded from one ring set (no holes: the common family of a scan's layer) in
one compiled call, from its starting rings' exact distances at the padded lattice's centres to the label of
every pixel of its box: the steps :func:`heoslice.grading.field._lattice_index` takes one by one for several
ring sets (eq. 8-10), without a Python step between them."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from heoslice.grading.field_kernels import _cell_classes, _curve_cells, _curved_cells, _expand_planes
from heoslice.grading.refine_kernels import _hessian_of, _measured_cells, _refine_flags, _vertices_by_cell
from heoslice.jit import EXACT, f64, kernel


class OneRingFit(NamedTuple):
    """What the fit of a one-ring family takes besides its distances: the cells (dx, dy mm), half a cell's
    diagonal and a whole one (mm), the fit test's ``tolerance`` (mm of s's slope) and turn ``limit`` (a
    cosine, :func:`heoslice.grading.refine.fit_test`), N_R (``count``), L_S (``length``, mm), and the padded
    lattice's top-left corner (x0, y0 mm)."""

    dx: float
    dy: float
    half_diagonal: float
    diagonal: float
    tolerance: float
    limit: float
    count: float
    length: float
    x0: float
    y0: float


@kernel(EXACT, label_arg=0)
def _one_ring_labels(target, d, g, fit, pixels, frame, ox, oy, tree, edges):  # pragma: no cover - compiled
    """:func:`one_ring_labels`: s = d N_R / L_S and its gradient at the centres, the cells' classes, their
    Hessians, the fit test with the ring's vertices, the planes expanded, the quadratic cells rewritten and
    the refined cells measured per pixel, each by the kernel field._lattice_index calls for it. Exact
    arithmetic (no fast-math): the steps between the kernels give what numpy gives."""
    dx, dy, half_diagonal, diagonal, tolerance, limit, count, length, x0, y0 = fit
    rows, cols = d.shape
    scale = count / length
    s = d * scale
    grad = g * scale
    gx = np.ascontiguousarray(grad[:, :, 0])
    gy = np.ascontiguousarray(grad[:, :, 1])
    touched, beyond, candidate, known, side = _cell_classes(s, gx, gy, d.reshape((1, rows, cols)), half_diagonal,
                                                            count)
    hessian = _hessian_of(grad, dx, dy)
    start, vx, vy, vs = _vertices_by_cell(edges[0], edges[1], np.zeros(len(edges[0])), x0, y0, dx, dy, rows, cols)
    refine = _refine_flags((s, grad, known, side, candidate), (hessian[0], hessian[1], hessian[2]),
                           (dx, dy, tolerance, limit, count), (start, vx, vy, vs, x0, y0))
    refined = 0
    for i in range(rows):
        for j in range(cols):
            refined += refine[i, j]
    ci, cj = np.empty(refined, dtype=np.int64), np.empty(refined, dtype=np.int64)
    n = 0
    for i in range(rows):
        for j in range(cols):
            if refine[i, j]:
                ci[n], cj[n] = i - 1, j - 1  # never on the padded lattice's border: its cells are no candidates
                n += 1
    curved_i, curved_j = _curved_cells(hessian, candidate, refine)
    unknown = False
    for i in range(1, rows - 1):
        for j in range(1, cols - 1):
            unknown |= not known[i, j]
    if unknown:
        # cells without s are refined or hold no solid pixel: expanded from 0
        for i in range(rows):
            for j in range(cols):
                if not known[i, j]:
                    s[i, j], grad[i, j, 0], grad[i, j, 1] = 0.0, 0.0, 0.0
    _expand_planes(s, grad, np.logical_not(touched), beyond, 1, pixels, count, target)
    if len(curved_i):
        quadratics = np.empty((len(curved_i), 6))
        for n in range(len(curved_i)):
            i, j = curved_i[n] + 1, curved_j[n] + 1
            quadratics[n, 0], quadratics[n, 1], quadratics[n, 2] = s[i, j], grad[i, j, 0], grad[i, j, 1]
            quadratics[n, 3], quadratics[n, 4], quadratics[n, 5] = hessian[0, i, j], hessian[1, i, j], hessian[2, i, j]
        _curve_cells(target, curved_i, curved_j, pixels, quadratics, count)
    if refined:
        radius = np.empty(refined)
        for n in range(refined):
            radius[n] = abs(d[ci[n] + 1, cj[n] + 1]) + diagonal
        _measured_cells(target, ci, cj, pixels, frame, radius, ox, oy, tree, edges, count, length)
    return target.out


def one_ring_labels(target, d: np.ndarray, g: np.ndarray, fit: OneRingFit, pixels, frame: tuple, ox: np.ndarray,
                    oy: np.ndarray, tree, edges) -> np.ndarray:
    """k at every pixel of a one-ring family's box, written in ``target`` (a LabelTarget of the box) from the
    signed distance d ((rows, cols) mm) and its gradient g ((rows, cols, 2)) to the starting rings at the
    centres of the padded lattice; ``pixels`` a CellPixels, ``frame`` the unpadded lattice (x0, y0, dx, dy
    mm), ox, oy ((cell * cell,) float32 mm) the pixels' offsets from their cell's centre, ``tree`` and
    ``edges`` (an EdgeTree and EdgeArrays) the starting rings' (compiled :func:`_one_ring_labels`)."""
    return _one_ring_labels(target, f64(d), f64(g), OneRingFit(*(float(value) for value in fit)), pixels,
                            tuple(float(value) for value in frame), ox, oy, tree, edges)
