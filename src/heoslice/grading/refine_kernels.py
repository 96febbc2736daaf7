"""Compiled loops of :mod:`heoslice.grading.refine`: the per-cell fit test, the Hessians of s, the rings whose
quadratic serves a cell no plane fits, and eq. 10 per pixel of those cells."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from heoslice.grading.field_kernels import (
    CellPixels,
    LabelTarget,
    inverse_distance,
    nearest_end,
)
from heoslice.grading.edges_kernels import edge_arrays
from heoslice.grading.search_kernels import EdgeTree, _nearest_in_batches
from heoslice.jit import EXACT, JIT, f32, f64, helper, i64, kernel

#: Most per-pixel distances measured and held at once when cells are evaluated per pixel (float32: 16 MB).
MEASURED_VALUES = 1 << 22


class CellField(NamedTuple):
    """s at a lattice's cell centres ((rows, cols)), its gradient ((rows, cols, 2) per mm), where s is
    ``known``, which centres are on the family's ``side`` of every ring, and the ``candidate`` cells
    to test ((rows, cols) bool each)."""

    s: np.ndarray
    grad: np.ndarray
    known: np.ndarray
    side: np.ndarray
    candidate: np.ndarray


class FitTest(NamedTuple):
    """The fit test's terms: the cell (dx, dy mm), the misfit allowed (``tolerance``, mm of s's slope), the
    cosine ``limit`` of a turn, and N_R (``count``)."""

    dx: float
    dy: float
    tolerance: float
    limit: float
    count: float


class RingVertices(NamedTuple):
    """Ring vertices grouped by lattice cell (a CSR: ``start`` (rows * cols + 1,) int), their positions
    (x, y mm), the exact s on their rings, and the lattice's top-left corner (x0, y0 mm)."""

    start: np.ndarray
    x: np.ndarray
    y: np.ndarray
    s: np.ndarray
    x0: float
    y0: float


@kernel(EXACT)
def _vertices_by_cell(x, y, s, x0, y0, dx, dy, rows, cols):  # pragma: no cover - compiled
    """Ring vertices (x, y mm, s) grouped by the lattice cell holding them (x0 + j dx, y0 - i dy its corner):
    (start (rows * cols + 1,) int, x, y, s) of :class:`RingVertices`, each cell's vertices in their given order
    (a stable counting sort); vertices off the lattice are left out."""
    n = len(x)
    key = np.empty(n, dtype=np.int64)
    start = np.zeros(rows * cols + 1, dtype=np.int64)
    for v in range(n):
        col = np.int64(np.floor((x[v] - x0) / dx))
        row = np.int64(np.floor((y0 - y[v]) / dy))
        key[v] = row * cols + col if 0 <= col < cols and 0 <= row < rows else -1
        if key[v] >= 0:
            start[key[v] + 1] += 1
    for cell in range(rows * cols):
        start[cell + 1] += start[cell]
    kept = start[rows * cols]
    vx, vy, vs = np.empty(kept), np.empty(kept), np.empty(kept)
    filled = start[:-1].copy()
    for v in range(n):
        if key[v] >= 0:
            slot = filled[key[v]]
            vx[slot], vy[slot], vs[slot] = x[v], y[v], s[v]
            filled[key[v]] += 1
    return start, vx, vy, vs


def vertices_by_cell(x: np.ndarray, y: np.ndarray, s: np.ndarray, x0: float, y0: float, dx: float, dy: float,
                     rows: int, cols: int) -> RingVertices:
    """The RingVertices of vertices (x, y mm, exact s there; (n,) each) on a lattice of rows x cols cells of dx x
    dy mm whose top-left corner is (x0, y0) (compiled :func:`_vertices_by_cell`)."""
    start, vx, vy, vs = _vertices_by_cell(f64(x), f64(y), f64(s), float(x0), float(y0), float(dx), float(dy),
                                          int(rows), int(cols))
    return RingVertices(start, vx, vy, vs, float(x0), float(y0))


@helper(JIT)
def _boundary_within(s, spread, miss, count):  # pragma: no cover - compiled
    """Whether a sub-region boundary (k = clip(floor(s) + 1, 1, count) changing) can lie within ``spread``
    plus ``miss`` of the value ``s``."""
    low = min(max(np.floor(s - spread - miss) + 1.0, 1.0), count)
    high = min(max(np.floor(s + spread + miss) + 1.0, 1.0), count)
    return low != high


@helper(JIT)
def _turns(grad, gx, gy, hx, hm, hy, i, j, dx, dy, limit):  # pragma: no cover - compiled
    """Whether the model's gradient (g + H e, e the offset to a neighbour's centre) points away from some
    neighbour's own direction (grad there, normalised) by more than ``limit`` (a cosine); H = 0 for a plane."""
    rows, cols = grad.shape[0], grad.shape[1]
    for ni in range(max(i - 1, 0), min(i + 2, rows)):
        for nj in range(max(j - 1, 0), min(j + 2, cols)):
            ex, ey = (nj - j) * dx, -(ni - i) * dy
            mx = gx + hx * ex + hm * ey
            my = gy + hm * ex + hy * ey
            nx, ny = grad[ni, nj, 0], grad[ni, nj, 1]
            scale = max(np.sqrt(mx * mx + my * my), 1e-300) * max(np.sqrt(nx * nx + ny * ny), 1e-300)
            if mx * nx + my * ny < limit * scale:
                return True
    return False


@helper(JIT)
def _vertices_fit(vstart, vx, vy, vs, i, j, rows, cols, x0, y0, dx, dy, centre, gx, gy, hx, hm, hy,
                  allowed):  # pragma: no cover - compiled
    """Whether the quadratic of cell (i, j) gives, at every ring vertex in the cells around it (CSR
    vstart over the lattice's cells, positions vx, vy, exact s there vs), s within ``allowed``."""
    if len(vstart) == 0:
        return True
    cx, cy = x0 + (j + 0.5) * dx, y0 - (i + 0.5) * dy
    for ni in range(max(i - 1, 0), min(i + 2, rows)):
        for nj in range(max(j - 1, 0), min(j + 2, cols)):
            cell = ni * cols + nj
            for v in range(vstart[cell], vstart[cell + 1]):
                ex, ey = vx[v] - cx, vy[v] - cy
                guess = centre + gx * ex + gy * ey + 0.5 * (hx * ex * ex + hy * ey * ey) + hm * ex * ey
                if abs(guess - vs[v]) > allowed:
                    return False
    return True


@kernel(JIT)
def _refine_flags(field, hessian, test, vertices):  # pragma: no cover - compiled
    """Cells to evaluate per pixel: candidates whose plane (s, gradient) misses s at a neighbour's
    centre (where s is ``known``) by more than ``tolerance`` x the slope, and so does their
    quadratic when a Hessian is given (hxx, hxy, hyy not 0 x 0; zeroed in place where the plane
    is kept), unless the better model's range over the cell widened by its largest miss holds no
    sub-region boundary (one k = clip(floor(s) + 1, 1, count) throughout: a slow or saturated
    field); or, while some neighbour is off the family's ``side`` or its s is not known (next to
    the outline, where features smaller than a cell hide between centres), whose model's gradient
    turns by more than ``limit`` (a cosine) from a neighbour's direction: the plane's own
    direction, or else (where the quadratic fits the values too, and gives s within half the
    tolerance at the ring vertices around the cell: vstart, vx, vy, vs, a CSR over the cells of
    the lattice whose top-left corner is x0, y0; a notch's tip or a slot's corners are vertices)
    the quadratic's gradient at that neighbour, so that a round outline's steady turn is no
    reason to refine; or whose own s is not known, or no
    neighbour's (nothing checks their plane). Neighbours past the lattice's border repeat the
    border cell (offset as a neighbour would be, so a border cell's plane is checked against
    its own centre value; the turn test skips them)."""
    s, grad, known, side, candidate = field
    hxx, hxy, hyy = hessian
    dx, dy, tolerance, limit, count = test
    vstart, vx, vy, vs, x0, y0 = vertices
    rows, cols = s.shape
    curved = hxx.shape[0] > 0
    out = np.zeros((rows, cols), dtype=np.bool_)
    for i in range(rows):
        for j in range(cols):
            if not candidate[i, j]:
                continue
            if not known[i, j]:
                out[i, j] = True
                continue
            gx, gy, centre = grad[i, j, 0], grad[i, j, 1], s[i, j]
            slope = np.sqrt(gx * gx + gy * gy)
            allowed = tolerance * max(slope, 1e-9)
            all_inside = True
            flat, bent, compared = 0.0, 0.0, 0
            hx, hm, hy = (hxx[i, j], hxy[i, j], hyy[i, j]) if curved else (0.0, 0.0, 0.0)
            for di in range(-1, 2):
                ni = min(max(i + di, 0), rows - 1)
                ey = -di * dy
                for dj in range(-1, 2):
                    nj = min(max(j + dj, 0), cols - 1)
                    all_inside = all_inside and side[ni, nj]
                    if not known[ni, nj]:
                        all_inside = False
                        continue
                    compared += di != 0 or dj != 0
                    ex = dj * dx
                    guess = centre + gx * ex + gy * ey - s[ni, nj]
                    flat = max(flat, abs(guess))
                    bent = max(bent, abs(guess + 0.5 * (hx * ex * ex + hy * ey * ey) + hm * ex * ey))
            reach = 0.5 * (abs(gx) * dx + abs(gy) * dy)
            bend = 0.125 * (abs(hx) * dx * dx + 2.0 * abs(hm) * dx * dy + abs(hy) * dy * dy)
            quadratic = curved and allowed < flat and bent < flat
            bent_misses = bent > allowed and _boundary_within(centre, reach + bend, bent, count)
            if quadratic:
                refine = bent_misses
            else:
                refine = flat > allowed and _boundary_within(centre, reach, flat, count)
            refine = refine or compared == 0  # no neighbour to check the plane against
            if not refine and not all_inside and _turns(grad, gx, gy, 0.0, 0.0, 0.0, i, j, dx, dy, limit):
                quadratic = (curved and not bent_misses
                             and not _turns(grad, gx, gy, hx, hm, hy, i, j, dx, dy, limit)
                             and _vertices_fit(vstart, vx, vy, vs, i, j, rows, cols, x0, y0, dx, dy, centre, gx, gy,
                                               hx, hm, hy, 0.5 * allowed))
                refine = not quadratic
            out[i, j] = refine
            if curved and not quadratic:
                hxx[i, j], hxy[i, j], hyy[i, j] = 0.0, 0.0, 0.0
    return out


def refine_flags(field: CellField, test: FitTest, hessian: np.ndarray | None = None,
                 vertices: RingVertices | None = None) -> np.ndarray:
    """(rows, cols) bool: lattice cells whose plane (and quadratic, with a ``hessian``) does not fit
    (see :func:`_refine_flags`); hessian (3, rows, cols) s_xx, s_xy, s_yy per mm^2, zeroed in
    place where the plane is kept; ``vertices`` None: no vertex check."""
    parts = f64(hessian) if hessian is not None else np.zeros((3, 0, 0))
    if vertices is None:
        vertices = RingVertices(np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0), np.zeros(0), 0.0, 0.0)
    vertices = RingVertices(i64(vertices.start), f64(vertices.x), f64(vertices.y), f64(vertices.s),
                            float(vertices.x0), float(vertices.y0))
    field = CellField(f64(field.s), f64(field.grad), *(np.ascontiguousarray(a) for a in field[2:]))
    out = _refine_flags(field, (parts[0], parts[1], parts[2]), FitTest(*(float(value) for value in test)), vertices)
    if hessian is not None and parts is not hessian:
        hessian[...] = parts
    return out


@helper(JIT)
def _difference(lower, upper, steps, step):  # pragma: no cover - compiled
    """(upper - lower) / (steps * step), as numpy.gradient takes it (central inside, one-sided at a border)."""
    return (upper - lower) / (steps * step)


@kernel(JIT)
def _hessian_of(grad, dx, dy):  # pragma: no cover - compiled
    """(3, rows, cols) s_xx, s_xy, s_yy from the gradients (rows, cols, 2) at centres dx, dy apart (rows
    downwards, y up): numpy.gradient's differences, zero along an axis one cell wide, all zero where
    any is not finite (see refine.cell_hessians)."""
    rows, cols = grad.shape[0], grad.shape[1]
    out = np.zeros((3, rows, cols))
    for i in range(rows):
        up, down = max(i - 1, 0), min(i + 1, rows - 1)
        for j in range(cols):
            left, right = max(j - 1, 0), min(j + 1, cols - 1)
            hyy = hyx = hxx = hxy = 0.0
            if rows > 1:
                hyy = _difference(grad[up, j, 1], grad[down, j, 1], down - up, -dy)
                hyx = _difference(grad[up, j, 0], grad[down, j, 0], down - up, -dy)
            if cols > 1:
                hxx = _difference(grad[i, left, 0], grad[i, right, 0], right - left, dx)
                hxy = _difference(grad[i, left, 1], grad[i, right, 1], right - left, dx)
                hyx = 0.5 * (hyx + hxy) if rows > 1 else hxy
            if np.isfinite(hxx) and np.isfinite(hyx) and np.isfinite(hyy):
                out[0, i, j], out[1, i, j], out[2, i, j] = hxx, hyx, hyy
    return out


def hessian_of(grad: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """(3, rows, cols) s_xx, s_xy, s_yy per mm^2 from gradients (rows, cols, 2) per mm at lattice centres
    dx, dy (mm) apart (compiled :func:`_hessian_of`)."""
    return _hessian_of(f64(grad), float(dx), float(dy))


@helper(JIT)
def _band_sensitivities(here, sets, count, out):  # pragma: no cover - compiled
    """ds/dd_j of eq. 10's band coordinate (field._band_coordinate) at one point into ``out`` (sets,), from
    the signed distances ``here`` (sets,) mm of the starting ring set (0) and each ending one: with m the
    ending set nearest in |d| and D = d_m + d_0 A, ds/dd_0 = N_R A d_m / D^2, ds/dd_m = -N_R d_0 / D^2,
    ds/dd_k = -N_R d_0 d_m^2 / (d_k^2 D^2); all NaN past a pole (D <= 0)."""
    m = nearest_end(here, sets)
    rest = 0.0
    for k in range(1, sets):
        if k != m:
            rest += inverse_distance(here[k])
    dm, d0 = here[m], here[0]
    a = 1.0 + dm * rest
    denominator = dm + d0 * a
    if not denominator > 0:
        out[:] = np.nan
        return
    scale = count / (denominator * denominator)
    out[0] = a * dm * scale
    for k in range(1, sets):
        inverse = inverse_distance(here[k])
        out[k] = -d0 * scale if k == m else -d0 * dm * dm * inverse * inverse * scale


@kernel(JIT)
def _ring_models(d, g, grad, ci, cj, dx, dy, count, half_diagonal, tolerance):  # pragma: no cover - compiled
    """Per ring set and cell, the quadratic of its signed distance or NaN (refine.fit_ring_models has the
    argument); d (sets, rows, cols) mm, g (sets, rows, cols, 2) and grad (rows, cols, 2) at the
    lattice centres, cells (ci, cj) off the lattice's border."""
    sets = d.shape[0]
    models = np.full((sets, len(ci), 6), np.nan)
    model = np.empty((sets, 6))
    miss = np.empty(sets)
    steepest = np.empty(sets)
    cost = np.empty(sets)
    here = np.empty(sets)
    ds = np.empty(sets)
    order = np.empty(sets, dtype=np.int64)
    for n in range(len(ci)):
        i, j = ci[n], cj[n]
        for k in range(sets):
            hxx = (g[k, i, j + 1, 0] - g[k, i, j - 1, 0]) / (2.0 * dx)
            hyy = (g[k, i - 1, j, 1] - g[k, i + 1, j, 1]) / (2.0 * dy)
            hxy = 0.5 * ((g[k, i - 1, j, 0] - g[k, i + 1, j, 0]) / (2.0 * dy)
                         + (g[k, i, j + 1, 1] - g[k, i, j - 1, 1]) / (2.0 * dx))
            model[k, 0], model[k, 1], model[k, 2] = d[k, i, j], g[k, i, j, 0], g[k, i, j, 1]
            model[k, 3], model[k, 4], model[k, 5] = hxx, hxy, hyy
            worst = 0.0
            for di in range(-1, 2):
                for dj in range(-1, 2):
                    ex, ey = dj * dx, -di * dy
                    guess = (model[k, 0] + model[k, 1] * ex + model[k, 2] * ey + 0.5 * (hxx * ex * ex + hyy * ey * ey)
                             + hxy * ex * ey)
                    gap = abs(guess - d[k, i + di, j + dj])  # NaN only from a NaN model: rejected below
                    if gap > worst:
                        worst = gap
            miss[k] = worst
            steepest[k] = 0.0
        # the largest |ds/dd_k| over the cell and its neighbours (NaN past a pole, as numpy's max)
        weakest = np.inf
        for di in range(-1, 2):
            for dj in range(-1, 2):
                for k in range(sets):
                    here[k] = d[k, i + di, j + dj]
                _band_sensitivities(here, sets, count, ds)
                for k in range(sets):
                    value = abs(ds[k])
                    if np.isnan(value) or np.isnan(steepest[k]):
                        steepest[k] = np.nan
                    elif value > steepest[k]:
                        steepest[k] = value
                steepness = np.hypot(grad[i + di, j + dj, 0], grad[i + di, j + dj, 1])
                if np.isfinite(steepness) and steepness < weakest:
                    weakest = steepness
        # on the family's side, bounds of the sensitivities over the cell's pixels (refine.fit_ring_models)
        nearest = np.inf
        for k in range(1, sets):
            nearest = min(nearest, abs(d[k, i, j]))
        for k in range(sets):
            below = max(abs(d[k, i, j]) - half_diagonal, 0.0)
            bound = count / (4.0 * below) if k == 0 else count * (nearest + half_diagonal) / (4.0 * below * below)
            if np.isnan(steepest[k]) or bound < steepest[k]:
                steepest[k] = bound
            finite = np.isfinite(model[k, 0])
            for e in range(1, 6):
                finite = finite and np.isfinite(model[k, e])
            cost[k] = (steepest[k] if np.isfinite(steepest[k]) else np.inf) * miss[k]
            if not (finite and np.isfinite(cost[k])):
                cost[k] = np.inf
        budget = tolerance * weakest if np.isfinite(weakest) else 0.0
        # cheapest first (ties in ring-set order), while the running sum stays within the budget
        for k in range(sets):
            order[k] = k
            e = k
            while e > 0 and cost[order[e - 1]] > cost[k]:
                order[e] = order[e - 1]
                e -= 1
            order[e] = k
        running = 0.0
        for e in range(sets):
            k = order[e]
            running += cost[k]
            if not running <= budget:
                break
            models[k, n, :] = model[k]
    return models


def ring_models(d: np.ndarray, g: np.ndarray, grad: np.ndarray, ci: np.ndarray, cj: np.ndarray, dx: float, dy: float,
                count: int, half_diagonal: float, tolerance: float) -> np.ndarray:
    """(sets, n, 6) per ring set and lattice cell (ci, cj) ((n,) int, off the border) the quadratic of its
    signed distance (d, d_x, d_y, d_xx, d_xy, d_yy at the centre, mm) where eq. 10's s stays within
    ``tolerance`` (mm of s's slope) with it, else NaN: refine.fit_ring_models' choice, compiled. d (sets,
    rows, cols) mm and g (sets, rows, cols, 2) per ring set, grad (rows, cols, 2) s's gradient at the
    centres, dx, dy the cells (mm), half_diagonal half a cell's diagonal (mm)."""
    return _ring_models(f64(d), f64(g), f64(grad), i64(ci),
                        i64(cj), float(dx), float(dy), float(count),
                        float(half_diagonal), float(tolerance))


@helper(JIT)
def _cell_labels(target, i, j, cell, s, count):  # pragma: no cover - compiled
    """k = clip(floor(s) + 1, 1, count) + base (0 off the mask) at the pixels of cell (i, j) inside
    ``target``, from s at its cell * cell pixels (row-major)."""
    index, mask, r0, c0, base = target
    rows, cols = index.shape
    masked = mask.shape[0] > 0
    height, width = min(cell, rows - i * cell), min(cell, cols - j * cell)
    for v in range(height):
        # whole arrays and indices, not views of a row (a view takes reference counts, per row of every cell);
        # unsigned, so that no index may wrap round from the end and the row's stores vectorise
        r, c = np.uint64(i * cell + v), np.uint64(j * cell)
        if masked:
            mask_row, mask_col = np.uint64(r0) + r, np.uint64(c0) + c
            for u in range(width):
                k = min(max(np.floor(s[v * cell + u]) + 1.0, 1.0), count)
                index[r, c + np.uint64(u)] = int((k + base) * mask[mask_row, mask_col + np.uint64(u)])
        else:
            for u in range(width):
                index[r, c + np.uint64(u)] = int(min(max(np.floor(s[v * cell + u]) + 1.0, 1.0), count) + base)


@kernel(JIT, label_arg=0)
def _band_cells(target, ci, cj, cell_pixels, models, measured, slot, count, length):  # pragma: no cover - compiled
    """Sub-region k of every pixel of whole cells (ci, cj) from each ring set's distance there: the
    ring's quadratic models[j, n] (d, d_x, d_y, d_xx, d_xy, d_yy at the cell centre) or, where
    its d is NaN, measured[slot[j, n], pixel]; s by eq. 10 (pole-free form of field._band_coordinate)
    with ring set 0 starting, or s = d_0 count / length with one ring set. Per cell, each ring
    set's distances fill a row of pixels, and eq. 10 runs over the cell's pixels with the
    nearest ending ring kept as a running minimum (the first of equals), so the loops vectorise."""
    index = target.out
    cell, px, py = cell_pixels
    sets = models.shape[0]
    half = 0.5 * cell
    pixels = cell * cell
    x = np.empty(pixels)
    y = np.empty(pixels)
    for p in range(pixels):
        x[p] = (p % cell + 0.5 - half) * px
        y[p] = -(p // cell + 0.5 - half) * py
    d = np.empty((sets, pixels))
    nearest = np.empty(pixels)
    rest = np.empty(pixels)
    s = np.empty(pixels)
    for n in range(len(ci)):
        for j in range(sets):
            if np.isnan(models[j, n, 0]):
                row = slot[j, n]
                for p in range(pixels):
                    d[j, p] = measured[row, p]
            else:
                m0, m1, m2, m3, m4, m5 = (models[j, n, 0], models[j, n, 1], models[j, n, 2], models[j, n, 3],
                                          models[j, n, 4], models[j, n, 5])
                for p in range(pixels):
                    d[j, p] = (m0 + m1 * x[p] + m2 * y[p] + 0.5 * (m3 * x[p] * x[p] + m5 * y[p] * y[p])
                               + m4 * x[p] * y[p])
        if sets == 1:
            for p in range(pixels):
                s[p] = d[0, p] * count / length
        else:
            nearest[:] = d[1]
            rest[:] = 0.0
            for j in range(2, sets):
                for p in range(pixels):
                    closer = abs(d[j, p]) < abs(nearest[p])
                    rest[p] += inverse_distance(nearest[p] if closer else d[j, p])
                    nearest[p] = d[j, p] if closer else nearest[p]
            for p in range(pixels):
                numerator = d[0, p] * (1.0 + nearest[p] * rest[p])
                denominator = nearest[p] + numerator
                s[p] = count * numerator / denominator if denominator > 0 else count
        _cell_labels(target, ci[n], cj[n], cell, s, count)
    return index


def band_cells(target: LabelTarget, ci: np.ndarray, cj: np.ndarray, pixels: CellPixels, models: np.ndarray,
               measured: np.ndarray, slot: np.ndarray, count: int, length: float) -> np.ndarray:
    """Sub-region k = clip(floor(s) + 1, 1, count) of every pixel of lattice cells (ci, cj) ((n,) int), in
    place, from per ring set (starting rings first) either a quadratic of its distance per cell
    (models (sets, n, 6): d, d_x, d_y, d_xx, d_xy, d_yy, mm, at the cell centre; pixel offsets
    from the centre y up) or, where models[j, n, 0] is NaN, the distance at each pixel
    (measured[slot[j, n]], measured (m, cell * cell) row-major in a cell, slot (sets, n) int);
    s by eq. 10 for two or more ring sets, d count / length for one; written in place in ``target``
    (as :func:`heoslice.grading.field_kernels.expand_planes`)."""
    pixels = CellPixels(int(pixels.cell), float(pixels.px), float(pixels.py))
    return _band_cells(target, i64(ci), i64(cj), pixels, f64(models), f32(measured), i64(slot), float(count),
                       float(length))


@kernel(JIT, label_arg=0)
def _measured_cells(target, ci, cj, cell_pixels, frame, radius, ox, oy, tree, edges, count,
                    length):  # pragma: no cover - compiled
    """:func:`_band_cells` of one ring set measured at every pixel (no model), measuring included: each
    cell's pixels (centre x0 + (j + 1/2) dx, y0 - (i + 1/2) dy of ``frame``, offsets ox, oy) against the
    edges within ``radius`` of its centre (:func:`heoslice.grading.search_kernels._nearest_in_batches`,
    squared float32), then s = d count / length from the float32 root, as the two steps give it."""
    cell = cell_pixels[0]
    x0, y0, dx, dy = frame
    pixels = cell * cell
    s = np.empty(pixels)
    step = max(1, MEASURED_VALUES // pixels)
    for first in range(0, len(ci), step):
        last = min(first + step, len(ci))
        cx = np.empty(last - first)
        cy = np.empty(last - first)
        for n in range(first, last):
            cx[n - first] = x0 + (cj[n] + 0.5) * dx
            cy[n - first] = y0 - (ci[n] + 0.5) * dy
        squared, _ = _nearest_in_batches(cx, cy, radius[first:last], ox, oy, tree, edges, False)
        for n in range(first, last):
            for p in range(pixels):
                s[p] = np.float64(np.sqrt(squared[n - first, p])) * count / length
            _cell_labels(target, ci[n], cj[n], cell, s, count)
    return target.out


def measured_cells(target: LabelTarget, ci: np.ndarray, cj: np.ndarray, pixels: CellPixels,
                   frame: tuple[float, float, float, float], radius: np.ndarray, ox: np.ndarray, oy: np.ndarray,
                   edges, tree, count: int, length: float) -> np.ndarray:
    """k at every pixel of lattice cells (ci, cj) ((n,) int) of a family of one ring set, each pixel from
    its exact distance to the rings' ``edges`` (and their ``tree``) among those within ``radius`` ((n,)
    mm) of its cell's centre: what refine.refine_cells and :func:`band_cells` give for it, in one call.
    ``frame`` (x0, y0, dx, dy) places the lattice (mm), ox, oy ((cell * cell,) mm) are the pixels' offsets
    from their cell's centre; written in place in ``target`` (as :func:`band_cells`)."""
    pixels = CellPixels(int(pixels.cell), float(pixels.px), float(pixels.py))
    return _measured_cells(target, i64(ci), i64(cj), pixels, tuple(float(v) for v in frame), f64(radius), f32(ox),
                           f32(oy), EdgeTree(*tree), edge_arrays(edges), float(count), float(length))
