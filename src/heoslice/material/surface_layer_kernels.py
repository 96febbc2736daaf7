"""Compiled kernel of :mod:`heoslice.material.surface`: r over a layer's solid pixels from the exact distance to a
surface (:mod:`heoslice.material.surface_kernels`' hierarchy) at the corners of cells, each cell settled by a proven
bound on the distance between its corners or halved (:func:`layer_r`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from heoslice.jit import EXACT, helper, kernel
from heoslice.material.surface_kernels import (
    STACK_DEPTH,
    Hierarchy,
    nearest_triangle,
    triangle_distance2,
    triangle_offset,
    triangles_near,
)


class LayerFrame(NamedTuple):
    """Where a layer's pixel centres are: x (mm) of column 0 and its step per column, y of row 0 and its step per
    row (signed), and the layer's height z (mm)."""

    x0: float
    dx: float
    y0: float
    dy: float
    z: float


@helper(EXACT)
def _normalised(d, r0, r1):  # pragma: no cover - compiled
    """r = (d - r0) / (r1 - r0) clipped to [0, 1] (heoslice.material.references.normalise)."""
    return min(max((d - r0) / (r1 - r0), 0.0), 1.0)


@helper(EXACT)
def _solid_at(packed, first, i, j):  # pragma: no cover - compiled
    """Whether pixel (i, j) is solid: bit 7 - j % 8 of packed[i, first + j // 8] (rows packed MSB first)."""
    return ((packed[i, first + (j >> 3)] >> (7 - (j & 7))) & 1) != 0


@helper(EXACT)
def _row_spans(packed, first, cols, spans):  # pragma: no cover - compiled
    """Each row's first and last solid column of the layer whose columns 0:cols are the bits of ``packed`` (h, bytes)
    uint8 from byte ``first`` on, into ``spans`` ((h, 2) int64; (cols, -1) for a row without one), reading each row
    a byte at a time only up to its first and from its last solid pixel."""
    end = min(first + ((cols + 7) >> 3), packed.shape[1])
    for i in range(packed.shape[0]):
        spans[i, 0], spans[i, 1] = cols, -1
        b = first
        while b < end and packed[i, b] == 0:
            b += 1
        if b == end:
            continue
        e = end - 1
        while packed[i, e] == 0:
            e -= 1
        k = 0
        while ((packed[i, b] >> (7 - k)) & 1) == 0:
            k += 1
        start = (b - first) * 8 + k
        k = 7
        while ((packed[i, e] >> (7 - k)) & 1) == 0:
            k -= 1
        stop = min((e - first) * 8 + k, cols - 1)
        if start <= stop:
            spans[i, 0], spans[i, 1] = start, stop


@helper(EXACT)
def _any_solid(packed, first, spans, i0, i1, j0, j1):  # pragma: no cover - compiled
    """Whether the cell rows i0:i1, columns j0:j1 (clipped to the layer) holds a solid pixel: from each row's span
    (:func:`_row_spans`) where it misses the cell or ends inside it, by the row's bits (a byte at a time where it
    can) only where the cell lies inside the span."""
    for i in range(i0, min(i1, packed.shape[0])):
        start, stop = spans[i, 0], spans[i, 1]
        if stop < j0 or start >= j1:
            continue
        if start >= j0 or stop < j1:
            return True
        j = j0
        while j < j1:
            if (j & 7) == 0 and j + 8 <= j1:
                if packed[i, first + (j >> 3)] != 0:
                    return True
                j += 8
            else:
                if _solid_at(packed, first, i, j):
                    return True
                j += 1
    return False


@helper(EXACT)
def _corners_above(cx, cy, cd, ct, z, tree):  # pragma: no cover - compiled
    """min over the corners' nearest triangles T of max over the corners k of d_T(x_k) - d_k: by convexity d <= d_T
    <= B + that over the cell (B the bilinear interpolant of the corners' distances cd (4,) at cx, cy (4,), z)."""
    above = np.inf
    for k in range(4):
        e = 0.0
        for q in range(4):
            if ct[q] != ct[k]:  # at its own corner a triangle's distance is the measured one
                e = max(e, np.sqrt(triangle_distance2(cx[q], cy[q], z, tree.corners[ct[k]])) - cd[q])
        above = min(above, e)
    return above


@helper(EXACT)
def _tangent_below(xc, yc, z, cx, cy, cd, tree, found, count, limit):  # pragma: no cover - compiled
    """max(0, max over the triangles found[:count] T and the corners k of d_k - L_T(x_k)), L_T the tangent plane of
    d_T at the cell's centre (xc, yc, z) (0 where d_T is 0 there): each d_T is convex, so d >= min_T L_T over the
    cell when found holds every triangle nearest somewhere in it, and B - L_T is bilinear, largest at a corner; so
    d >= B - that. Stops once it exceeds ``limit``."""
    below = 0.0
    for q in range(count):
        gx, gy, gz = triangle_offset(xc, yc, z, tree.corners[found[q]])
        dc = np.sqrt(gx * gx + gy * gy + gz * gz)
        for k in range(4):
            tangent = 0.0  # d_T >= 0: the bound when the centre lies (to rounding) on T, whose gradient is noise
            if dc > 1e-9 * (1.0 + abs(xc) + abs(yc) + abs(z)):
                tangent = dc + (gx * (cx[k] - xc) + gy * (cy[k] - yc)) / dc
            below = max(below, cd[k] - tangent)
        if below > limit:
            break
    return below


#: Side (pixels) at or below which a cell the bounds leave unsettled is measured pixel by pixel against the
#: triangles that can be nearest anywhere in it; and how many of those it may hold.
NEAR_CELL = 4
NEAR_TRIANGLES = 48
#: Side (pixels) at or below which a cell the second-order bound leaves is tried by the tangent planes of the
#: triangles within reach (:func:`_tangent_below`): any cell of the top size (64 pixels); on the surface-coloured
#: dragon 16 took 7 % more of layer_r's CPU, 32 about 3 % more (benchmarks/README.md).
TANGENT_CELL = 64


@kernel(EXACT)
def layer_r(packed: np.ndarray, first: int, cols: int, frame: LayerFrame, tree: Hierarchy, r0: float, r1: float,
            tolerance: float, top: int, r: np.ndarray, spread: np.ndarray, steps: int,
            codes: np.ndarray) -> None:  # pragma: no cover - compiled
    """r (h, w) at each solid pixel centre of a layer of h rows, w = ``cols`` columns (its pixels the bits of
    ``packed`` (h, bytes) uint8 from byte ``first`` on, MSB first), normalised from the exact distance to ``tree``
    over (r0, r1) mm, each within spread[i, j] <= tolerance / 2 of its true r (``spread`` (h, w) written too,
    or (0, 0) to skip it); or, where ``codes`` (h, w) uint16 is not (0, 0), instead of r its step k = round(r
    ``steps``) (``steps`` < 65536; off the solid, codes are left as they were). Cells of ``top`` x ``top`` pixels
    are halved until a bound settles them. A cell of pixel rows i0:i1, columns j0:j1 has its corners at the pixel centres (i0, j0), (i0, j1),
    (i1, j0), (i1, j1) (shared with its neighbours), where d is measured exactly (d_k, nearest triangle T_k);
    a = (j1 - j0) px, b = (i1 - i0) py, h = sqrt(a^2 + b^2) / 2 (every point of the cell is within h of a corner):

    - Lipschitz: d is 1-Lipschitz, so d lies in [min d_k - h, max d_k + h]; settled where that maps to r less
      than ``tolerance`` apart (their midpoint).
    - Second order: on the cell d >= m = min d_k - h > 0; each triangle's distance is convex with Hessian
      <= 1 / m there, so d - |x|^2 / 2m (a minimum of concave functions) is concave and, with the bilinear
      weights w_k(x) (>= 0, reproducing x), d(x) >= B(x) - (a^2 t(1 - t) + b^2 s(1 - s)) / 2m, B = sum w_k d_k,
      (t, s) the pixel's place in the cell, so d(x) >= B(x) - (a^2 + b^2) / 8m; by convexity
      d(x) <= d_T(x) <= sum w_k d_T(x_k) <= B(x) + e_T, e_T = max_k (d_T(x_k) - d_k), for each T among the T_k.
      Since B >= min d_k, d >= min d_k - (a^2 + b^2) / 8m on the cell, a larger m where it is: m is raised to it
      (up to three times), each time a smaller bound. Settled where (a^2 + b^2) / 8m + min e_T is at most ``tolerance`` (r1 - r0): each pixel's r is that
      interval's midpoint, clipped (clipping moves it no farther from the true r).
    - Tangent planes: where that lower bound fails (m small or <= 0: near the surface, where d is nearly a plane's
      distance), a cell of at most TANGENT_CELL pixels a side whose upper bound min e_T is below ``tolerance``
      (r1 - r0): d = min over the triangles within max d_k + 2h of its centre c (the set of the Near bullet) of
      d_T >= the tangent plane L_T of d_T at c (convexity), and B - L_T is bilinear, so d(x) >= B(x) - max_{T, k}
      (d_k - L_T(x_k)) (:func:`_tangent_below`); settled and filled as the second-order bound's cells.
    - Near: a cell of at most NEAR_CELL pixels a side is measured exactly pixel by pixel against the triangles
      within max d_k + 2h of its centre (any pixel's nearest triangle is: d(x) <= max d_k + h and |x - c| <= h),
      when there are at most NEAR_TRIANGLES of them; a cell of at most 2 x 2 pixels by the hierarchy search.
    """
    rows = packed.shape[0]
    coded, keep = codes.shape[0] > 0, spread.shape[0] > 0
    stack = np.empty(STACK_DEPTH, np.int64)
    bound = np.empty(STACK_DEPTH)
    found = np.empty(NEAR_TRIANGLES, np.int64)
    cells = np.empty((256, 4), np.int64)
    cell_d = np.empty((256, 4))
    cell_t = np.empty((256, 4), np.int64)
    cd, cx, cy = np.empty(4), np.empty(4), np.empty(4)
    ct = np.empty(4, np.int64)
    grid_d = np.empty((3, 3))
    grid_t = np.empty((3, 3), np.int64)
    width = r1 - r0
    pitch_x, pitch_y = abs(frame.dx), abs(frame.dy)
    nearest = 0
    spans = np.empty((rows, 2), np.int64)
    _row_spans(packed, first, cols, spans)
    # the top cells' corners, measured where a solid pixel needs them
    lattice_rows, lattice_cols = (rows + top - 1) // top + 1, (cols + top - 1) // top + 1
    needed = np.zeros((lattice_rows, lattice_cols), np.bool_)
    for ti in range(lattice_rows - 1):
        for tj in range(lattice_cols - 1):
            if _any_solid(packed, first, spans, ti * top, ti * top + top, tj * top, tj * top + top):
                needed[ti, tj] = needed[ti + 1, tj] = needed[ti, tj + 1] = needed[ti + 1, tj + 1] = True
    # the distances measured inside the top cell at hand, by pixel from its first corner (tagged by the cell)
    memo_tag = np.zeros((top + 1, top + 1), np.int64)
    memo_d = np.empty((top + 1, top + 1))
    memo_t = np.empty((top + 1, top + 1), np.int64)
    lattice_d = np.zeros((lattice_rows, lattice_cols))
    lattice_t = np.zeros((lattice_rows, lattice_cols), np.int64)
    for ti in range(lattice_rows):
        for tj in range(lattice_cols):
            if needed[ti, tj]:
                best, nearest = nearest_triangle(frame.x0 + tj * top * frame.dx, frame.y0 + ti * top * frame.dy,
                                                 frame.z, tree, nearest, stack, bound)
                lattice_d[ti, tj], lattice_t[ti, tj] = np.sqrt(best), nearest
    for ti in range(lattice_rows - 1):
        for tj in range(lattice_cols - 1):
            if not (needed[ti, tj] and needed[ti + 1, tj + 1]):
                continue
            tag = ti * lattice_cols + tj + 1
            cells[0, 0], cells[0, 1], cells[0, 2], cells[0, 3] = ti * top, ti * top + top, tj * top, tj * top + top
            for k in range(4):
                cell_d[0, k] = lattice_d[ti + k // 2, tj + k % 2]
                cell_t[0, k] = lattice_t[ti + k // 2, tj + k % 2]
            pending = 1
            while pending > 0:
                pending -= 1
                i0, i1, j0, j1 = cells[pending, 0], cells[pending, 1], cells[pending, 2], cells[pending, 3]
                if not _any_solid(packed, first, spans, i0, i1, j0, j1):
                    continue
                for k in range(4):
                    cd[k], ct[k] = cell_d[pending, k], cell_t[pending, k]
                    cx[k] = frame.x0 + (j0 if k % 2 == 0 else j1) * frame.dx
                    cy[k] = frame.y0 + (i0 if k < 2 else i1) * frame.dy
                a, b = (j1 - j0) * pitch_x, (i1 - i0) * pitch_y
                half = 0.5 * np.sqrt(a * a + b * b)
                low, high = cd.min(), cd.max()
                slack = 1e-12 * (1.0 + high + abs(r0) + abs(r1))  # rounding of the measured distances
                lo = _normalised(low - half - slack, r0, r1)
                hi = _normalised(high + half + slack, r0, r1)
                if hi - lo <= tolerance:
                    value = 0.5 * (lo + hi)
                    code = np.uint16(int(value * steps + 0.5))
                    for i in range(i0, min(i1, rows)):
                        for j in range(max(j0, spans[i, 0]), min(j1, spans[i, 1] + 1)):
                            if coded:
                                codes[i, j] = code
                            else:
                                r[i, j] = value
                            if keep:
                                spread[i, j] = 0.5 * (hi - lo)
                    continue
                m = low - half - slack
                small = i1 - i0 <= NEAR_CELL and j1 - j0 <= NEAR_CELL
                count = -1
                above, below = np.inf, np.inf
                if m > 0.0 or (i1 - i0 <= TANGENT_CELL and j1 - j0 <= TANGENT_CELL):
                    above = _corners_above(cx, cy, cd, ct, frame.z, tree) + slack
                if m > 0.0:
                    below = (a * a + b * b) / (8.0 * m) + slack
                    for _ in range(3):  # d >= B - below >= low - below on the cell: a larger m, a smaller bound
                        if low - below <= m:
                            break
                        m = low - below
                        below = (a * a + b * b) / (8.0 * m) + slack
                if below + above > tolerance * width and (small or (above < tolerance * width and (
                        i1 - i0 <= TANGENT_CELL and j1 - j0 <= TANGENT_CELL))):
                    xc, yc = 0.5 * (cx[0] + cx[3]), 0.5 * (cy[0] + cy[3])
                    count = triangles_near(xc, yc, frame.z, high + 2.0 * half + slack, tree, stack, found)
                    if count >= 0 and above < tolerance * width:
                        below = _tangent_below(xc, yc, frame.z, cx, cy, cd, tree, found, count,
                                               tolerance * width - above) + slack + 1e-12 * (
                                                   abs(xc) + abs(yc) + abs(frame.z))
                if below + above <= tolerance * width:
                    # r = the clipped midpoint of [B - below, B + above] (clipping keeps it within half the width)
                    scale = 1.0 / width
                    offset = 0.5 * (above - below) - r0
                    for i in range(i0, min(i1, rows)):
                        s = (i - i0) / (i1 - i0)
                        left = (1.0 - s) * cd[0] + s * cd[2] + offset
                        slope = ((1.0 - s) * (cd[1] - cd[0]) + s * (cd[3] - cd[2])) / (j1 - j0)
                        lo_j, hi_j = max(j0, spans[i, 0]), min(j1, spans[i, 1] + 1)
                        if coded:
                            run = codes[i, lo_j:hi_j]  # a loop from 0 over a slice vectorises
                            skip = lo_j - j0
                            for t in range(hi_j - lo_j):
                                run[t] = np.uint16(min(max((left + (skip + t) * slope) * scale, 0.0), 1.0) * steps
                                                   + 0.5)
                        else:
                            for j in range(lo_j, hi_j):
                                r[i, j] = min(max((left + (j - j0) * slope) * scale, 0.0), 1.0)
                        if keep:
                            for j in range(lo_j, hi_j):
                                spread[i, j] = 0.5 * (above + below) * scale
                    continue
                if not small:
                    count = -1
                if count >= 0 or (i1 - i0 <= 2 and j1 - j0 <= 2):
                    for i in range(i0, min(i1, rows)):
                        for j in range(j0, min(j1, cols)):
                            if _solid_at(packed, first, i, j):
                                px, py = frame.x0 + j * frame.dx, frame.y0 + i * frame.dy
                                if count >= 0:
                                    best = np.inf
                                    for q in range(count):
                                        best = min(best, triangle_distance2(px, py, frame.z, tree.corners[found[q]]))
                                else:
                                    best, nearest = nearest_triangle(px, py, frame.z, tree, nearest, stack, bound)
                                value = _normalised(np.sqrt(best), r0, r1)
                                if coded:
                                    codes[i, j] = np.uint16(int(value * steps + 0.5))
                                else:
                                    r[i, j] = value
                                if keep:
                                    spread[i, j] = 0.0
                    continue
                # halve: the new corners at the middles of the sides and the centre, 3 x 3 in all
                im = (i0 + i1) // 2 if i1 - i0 >= 2 else i1
                jm = (j0 + j1) // 2 if j1 - j0 >= 2 else j1
                along_i = (i0, im, i1)
                along_j = (j0, jm, j1)
                for gi in range(3):
                    for gj in range(3):
                        if (gi == 0 or gi == 2) and (gj == 0 or gj == 2):
                            k = (gi // 2) * 2 + gj // 2
                            grid_d[gi, gj], grid_t[gi, gj] = cd[k], ct[k]
                        elif (gi == 1 and im == i1) or (gj == 1 and jm == j1):
                            continue
                        else:
                            li, lj = along_i[gi] - ti * top, along_j[gj] - tj * top
                            if memo_tag[li, lj] != tag:  # a side's middle is its two cells' corner
                                best, nearest = nearest_triangle(frame.x0 + along_j[gj] * frame.dx,
                                                                 frame.y0 + along_i[gi] * frame.dy, frame.z, tree,
                                                                 ct[(gi // 2) * 2 + gj // 2], stack, bound)
                                memo_tag[li, lj], memo_d[li, lj], memo_t[li, lj] = tag, np.sqrt(best), nearest
                            grid_d[gi, gj], grid_t[gi, gj] = memo_d[li, lj], memo_t[li, lj]
                for u in range(2):
                    for v in range(2):
                        ci0, ci1 = along_i[u], along_i[u + 1]
                        cj0, cj1 = along_j[v], along_j[v + 1]
                        if ci1 <= ci0 or cj1 <= cj0:
                            continue
                        gi0, gj0 = u, v
                        gi1 = 2 if im == i1 else u + 1
                        gj1 = 2 if jm == j1 else v + 1
                        cells[pending, 0], cells[pending, 1], cells[pending, 2], cells[pending, 3] = ci0, ci1, cj0, cj1
                        cell_d[pending, 0], cell_t[pending, 0] = grid_d[gi0, gj0], grid_t[gi0, gj0]
                        cell_d[pending, 1], cell_t[pending, 1] = grid_d[gi0, gj1], grid_t[gi0, gj1]
                        cell_d[pending, 2], cell_t[pending, 2] = grid_d[gi1, gj0], grid_t[gi1, gj0]
                        cell_d[pending, 3], cell_t[pending, 3] = grid_d[gi1, gj1], grid_t[gi1, gj1]
                        pending += 1
