"""Compiled inner loops of the grading stage (:mod:`heoslice.regions`), by numba.

The grading step's inner loops have no fast numpy form: gathering, for each group of
points, the ring edges within its own radius (a walk down a bounding-box hierarchy),
the nearest of those edges to each point, the expansion of one plane (or quadratic)
per lattice cell to its pixels, the per-cell fit test, the choice of the rings whose
quadratic serves a cell no plane fits, eq. 10 per pixel of those cells (from each
ring's quadratic or measured distance), the halftoning of a labelled layer into
droplet masks, the walk that leaves a ring's straight points out of its edges, and
the winding number of a layer's loops around a disc. As numpy passes they cost ~100 of a
~15 MP layer's ~115 ms (``python benchmarks/bench_grading.py --stages``, before);
compiled, the whole step is under 30 ms. Everything here takes and returns plain
arrays; the geometry (which points, which radius, why it is enough) is argued in
:mod:`heoslice.regions`.

Kernels are compiled on first use and cached on disk (numba's ``cache=True``), so
a process pays the compile (a few seconds) once per installation, not once per run.
"""

from __future__ import annotations

import numba
import numpy as np

#: Compiled with fast-math's reassociation and contraction (to vectorise), not its no-inf/no-NaN
#: assumptions: distances start at inf.
_JIT = {"cache": True, "nogil": True, "error_model": "numpy", "fastmath": {"nsz", "arcp", "contract", "reassoc"}}
#: The halftone reproduces heoslice.halftone's float32 arithmetic exactly: no contraction or reassociation.
_EXACT = {"cache": True, "nogil": True, "error_model": "numpy"}
#: Children per node of the edge hierarchy (:func:`edge_tree`).
_FAN = 8
#: Candidate (group, chunk) pairs gathered at most at once by :func:`nearest_in_groups` (8 bytes each).
_PAIRS = 1 << 23


@numba.njit(**_JIT)
def _candidates(cx, cy, radius, boxes, level_start):  # pragma: no cover - compiled
    """CSR (start (g+1,), chunk (m,)) of the chunks (runs of _FAN consecutive edges, the hierarchy's
    level 1) whose bounding box comes within radius[g] of each point (cx[g], cy[g]).

    ``boxes`` are the bounding boxes of a hierarchy (:func:`edge_tree`): level 0 the edges,
    each level above groups _FAN consecutive nodes of the one below; a node whose box is
    farther than the radius is skipped with everything under it.
    """
    groups = len(cx)
    levels = len(level_start) - 1
    start = np.zeros(groups + 1, dtype=np.int64)
    found = np.empty(max(16 * groups, 16), dtype=np.int64)
    stack = np.empty((64 * levels + _FAN * levels + 64, 2), dtype=np.int64)
    n = 0
    for g in range(groups):
        r2 = radius[g] * radius[g]
        top = 0
        for node in range(level_start[levels] - level_start[levels - 1]):
            stack[top, 0], stack[top, 1] = levels - 1, node
            top += 1
        while top:
            top -= 1
            level, node = stack[top, 0], stack[top, 1]
            box = level_start[level] + node
            gap_x = max(boxes[box, 0] - cx[g], cx[g] - boxes[box, 2], 0.0)
            gap_y = max(boxes[box, 1] - cy[g], cy[g] - boxes[box, 3], 0.0)
            if gap_x * gap_x + gap_y * gap_y > r2:
                continue
            if level > 1:
                below = level_start[level] - level_start[level - 1]
                for child in range(node * _FAN, min((node + 1) * _FAN, below)):
                    stack[top, 0], stack[top, 1] = level - 1, child
                    top += 1
                continue
            if n == len(found):
                grown = np.empty(2 * n, dtype=np.int64)
                grown[:n] = found
                found = grown
            found[n] = node
            n += 1
        start[g + 1] = n
    return start, found[:n]


@numba.njit(inline="always", **_JIT)
def _squared(rx, ry, vx, vy, inv):  # pragma: no cover - compiled
    """Squared distance from the offset (rx, ry) (from an edge's first end) to the edge (vx, vy), 1/|v|^2 = inv;
    float32 in, float32 out, written with selects so that the loops calling it vectorise."""
    t = (rx * vx + ry * vy) * inv
    t = np.float32(0.0) if t < np.float32(0.0) else t
    t = np.float32(1.0) if t > np.float32(1.0) else t
    rx -= t * vx
    ry -= t * vy
    return rx * rx + ry * ry


@numba.njit(**_JIT)
def _nearest_in_chunks(cx, cy, ox, oy, start, chunk, capsules, ex, ey, evx, evy, einv,
                       track):  # pragma: no cover - compiled
    """The nearest edge of group g's candidate chunks to each point (cx[g] + ox[k], cy[g] + oy[k]):
    (squared distance (g, k) float32, inf where none; edge (g, k) int32, -1 where none, or
    (0, 0) without ``track``).

    Chunks are visited nearest first by a lower bound of their distance from the group's
    centre (their capsule's: chord distance less radius); a chunk is skipped when no
    point's capsule distance beats its best so far, and the rest once even the farthest
    point (``reach`` from the centre) cannot be nearer to them than its best. Compared in
    float32 from each group's centre (a near tie may pick an edge ~1e-5 mm farther);
    selects, not branches, so the loops over points vectorise.
    """
    groups, points, edges = len(cx), len(ox), len(ex)
    reach = 0.0
    for k in range(points):
        reach = max(reach, np.sqrt(np.float64(ox[k]) ** 2 + np.float64(oy[k]) ** 2))
    best = np.full((groups, points), np.inf, dtype=np.float32)
    which = np.full((groups, points) if track else (0, 0), -1, dtype=np.int32)
    near = np.empty(points, dtype=np.float32)
    for g in range(groups):
        first, count = start[g], start[g + 1] - start[g]
        bound = np.empty(count)
        for n in range(count):
            c = chunk[first + n]
            bound[n] = _point_to_edge(cx[g], cy[g], capsules[c, 0], capsules[c, 1], capsules[c, 2], capsules[c, 3],
                                      capsules[c, 4]) - capsules[c, 5]
        row_best = best[g]
        near[:] = np.inf
        farthest = np.inf
        for n in np.argsort(bound):
            if bound[n] - reach > farthest:
                break
            c = chunk[first + n]
            bx, by = np.float32(cx[g] - capsules[c, 0]), np.float32(cy[g] - capsules[c, 1])
            vx, vy = np.float32(capsules[c, 2]), np.float32(capsules[c, 3])
            inv, radius = np.float32(capsules[c, 4]), np.float32(capsules[c, 5])
            needed = 0
            for k in range(points):
                gap = np.sqrt(_squared(bx + ox[k], by + oy[k], vx, vy, inv)) - radius
                needed += gap < near[k]
            if not needed:
                continue
            for e in range(c * _FAN, min(c * _FAN + _FAN, edges)):
                bx, by = np.float32(cx[g] - ex[e]), np.float32(cy[g] - ey[e])
                vx, vy, inv = np.float32(evx[e]), np.float32(evy[e]), np.float32(einv[e])
                if track:
                    row_which = which[g]
                    edge = np.int32(e)
                    for k in range(points):
                        d2 = _squared(bx + ox[k], by + oy[k], vx, vy, inv)
                        closer = d2 < row_best[k]
                        row_which[k] = edge if closer else row_which[k]
                        row_best[k] = d2 if closer else row_best[k]
                else:
                    for k in range(points):
                        d2 = _squared(bx + ox[k], by + oy[k], vx, vy, inv)
                        row_best[k] = d2 if d2 < row_best[k] else row_best[k]
            farthest = 0.0
            for k in range(points):
                near[k] = np.sqrt(row_best[k])
                farthest = max(farthest, np.float64(near[k]))
    return best, which


@numba.njit(inline="always", **_JIT)
def _point_to_edge(px, py, ex, ey, vx, vy, inv):  # pragma: no cover - compiled
    """Distance (float64) from a point to the edge from (ex, ey) by (vx, vy), 1/|v|^2 = inv."""
    rx, ry = px - ex, py - ey
    t = min(max((rx * vx + ry * vy) * inv, 0.0), 1.0)
    return np.sqrt((rx - t * vx) ** 2 + (ry - t * vy) ** 2)


@numba.njit(**_JIT)
def _chords_apart(a, b):  # pragma: no cover - compiled
    """Distance between two capsules' chords (rows of :func:`_chunk_capsules`): 0 where they cross,
    else the least of each end's distance to the other chord."""
    ax1, ay1, bx1, by1 = a[0] + a[2], a[1] + a[3], b[0] + b[2], b[1] + b[3]
    side_a0 = a[2] * (b[1] - a[1]) - a[3] * (b[0] - a[0])
    side_a1 = a[2] * (by1 - a[1]) - a[3] * (bx1 - a[0])
    side_b0 = b[2] * (a[1] - b[1]) - b[3] * (a[0] - b[0])
    side_b1 = b[2] * (ay1 - b[1]) - b[3] * (ax1 - b[0])
    if side_a0 * side_a1 <= 0.0 and side_b0 * side_b1 <= 0.0:
        return 0.0
    return min(_point_to_edge(a[0], a[1], b[0], b[1], b[2], b[3], b[4]),
               _point_to_edge(ax1, ay1, b[0], b[1], b[2], b[3], b[4]),
               _point_to_edge(b[0], b[1], a[0], a[1], a[2], a[3], a[4]),
               _point_to_edge(bx1, by1, a[0], a[1], a[2], a[3], a[4]))


@numba.njit(**_JIT)
def _chunks_apart(start, candidate, cap_a, cap_b, a, b, best):  # pragma: no cover - compiled
    """Least vertex-to-edge distance, both ways, between each chunk of edge set ``a`` and its candidate
    chunks of ``b`` (CSR start, candidate), where their capsules can come closer than ``best``
    (an upper bound, returned if nothing is closer). ``a``, ``b``: (n, 5) x, y, vx, vy, 1/|v|^2."""
    na, nb = len(a), len(b)
    for i in range(len(cap_a)):
        for m in range(start[i], start[i + 1]):
            j = candidate[m]
            if _chords_apart(cap_a[i], cap_b[j]) - cap_a[i, 5] - cap_b[j, 5] >= best:
                continue
            for e in range(i * _FAN, min(i * _FAN + _FAN, na)):
                for f in range(j * _FAN, min(j * _FAN + _FAN, nb)):
                    best = min(best, _point_to_edge(a[e, 0], a[e, 1], b[f, 0], b[f, 1], b[f, 2], b[f, 3], b[f, 4]),
                               _point_to_edge(b[f, 0], b[f, 1], a[e, 0], a[e, 1], a[e, 2], a[e, 3], a[e, 4]))
    return best


@numba.njit(**_JIT)
def _expand_planes(s, gx, gy, empty, cell, px, py, count, out, mask, r0, c0, base):  # pragma: no cover - compiled
    """out[i*cell + v, j*cell + u] = clip(floor(s_ij + gx_ij x_u - gy_ij y_v) + 1, 1, count) over the
    part of the lattice that ``out`` covers; x_u, y_v are pixel offsets from the cell centre (mm),
    plus ``base``; with a ``mask`` (not 0 x 0), pixels where mask[r0 + row, c0 + col] is False get
    0. ``empty`` cells (no pixel of the family) get 0 without evaluating. Per row of
    cells the column terms are laid out once (float32: s to ~1e-4 of a band), so each pixel
    row is a few long branch-free loops, one per run of cells that are not empty."""
    rows, cols = out.shape
    masked = mask.shape[0] > 0
    half = 0.5 * cell
    column = np.empty(cols, dtype=np.float32)
    slope = np.empty(cols, dtype=np.float32)
    span_from = np.empty(s.shape[1] + 1, dtype=np.int64)
    span_to = np.empty(s.shape[1] + 1, dtype=np.int64)
    low, high, offset = np.float32(1.0), np.float32(count), np.float32(base)
    for i in range(s.shape[0]):
        if i * cell >= rows:
            break
        spans = 0
        for j in range(min(s.shape[1], -(-cols // cell))):
            if empty[i, j]:
                continue
            first, last = j * cell, min(cols, (j + 1) * cell)
            if spans and span_to[spans - 1] == first:
                span_to[spans - 1] = last
            else:
                span_from[spans], span_to[spans] = first, last
                spans += 1
            for c in range(first, last):
                column[c] = s[i, j] + 1.0 + gx[i, j] * ((c - j * cell + 0.5 - half) * px)
                slope[c] = gy[i, j] * py
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


@numba.njit(inline="always", **_JIT)
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


@numba.njit(inline="always", **_JIT)
def _boundary_within(s, spread, miss, count):  # pragma: no cover - compiled
    """Whether a sub-region boundary (k = clip(floor(s) + 1, 1, count) changing) can lie within ``spread``
    plus ``miss`` of the value ``s``."""
    low = min(max(np.floor(s - spread - miss) + 1.0, 1.0), count)
    high = min(max(np.floor(s + spread + miss) + 1.0, 1.0), count)
    return low != high


@numba.njit(inline="always", **_JIT)
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


@numba.njit(inline="always", **_JIT)
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


@numba.njit(**_JIT)
def _refine_flags(s, grad, hxx, hxy, hyy, known, side, candidate, dx, dy, tolerance, limit,
                  count, vstart, vx, vy, vs, x0, y0):  # pragma: no cover - compiled
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


@numba.njit(inline="always", **_JIT)
def _difference(lower, upper, steps, step):  # pragma: no cover - compiled
    """(upper - lower) / (steps * step), as numpy.gradient takes it (central inside, one-sided at a border)."""
    return (upper - lower) / (steps * step)


@numba.njit(**_JIT)
def _hessian_of(grad, dx, dy):  # pragma: no cover - compiled
    """(3, rows, cols) s_xx, s_xy, s_yy from the gradients (rows, cols, 2) at centres dx, dy apart (rows
    downwards, y up): numpy.gradient's differences, zero along an axis one cell wide, all zero where
    any is not finite (see regions._hessian)."""
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


@numba.njit(**_JIT)
def _signed_feet(edge, x0, y0, dx, dy, ex, ey, evx, evy, einv, inside, encloses):  # pragma: no cover - compiled
    """At every lattice centre (x0 + (j + 1/2) dx, y0 - (i + 1/2) dy): signed distance to its edge
    (> 0 where ``inside`` equals ``encloses``), its unit gradient (0 on the edge) and the foot."""
    rows, cols = edge.shape
    signed = np.empty((rows, cols))
    gradient = np.empty((rows, cols, 2))
    foot = np.empty((2, rows, cols))
    for i in range(rows):
        y = y0 - (i + 0.5) * dy
        for j in range(cols):
            x = x0 + (j + 0.5) * dx
            e = edge[i, j]
            rx, ry = x - ex[e], y - ey[e]
            t = min(max((rx * evx[e] + ry * evy[e]) * einv[e], 0.0), 1.0)
            fx, fy = ex[e] + t * evx[e], ey[e] + t * evy[e]
            distance = np.sqrt((x - fx) ** 2 + (y - fy) ** 2)
            sign = 1.0 if inside[i, j] == encloses else -1.0
            scale = sign / distance if distance > 0 else 0.0
            signed[i, j] = sign * distance
            gradient[i, j, 0], gradient[i, j, 1] = (x - fx) * scale, (y - fy) * scale
            foot[0, i, j], foot[1, i, j] = fx, fy
    return signed, gradient, foot


@numba.njit(**_JIT)
def _inside_centres(ex, ey, evx, evy, x0, y0, dx, dy, rows, cols):  # pragma: no cover - compiled
    """(rows, cols) bool: lattice centres (x0 + (j + 1/2) dx, y0 - (i + 1/2) dy) inside the closed rings
    whose edges run from (ex, ey) by (evx, evy), by the parity of the edges crossed to their left
    (each edge half-open in y)."""
    flips = np.zeros((rows, cols + 1), dtype=np.uint8)
    for e in range(len(ex)):
        if evy[e] == 0.0:
            continue
        low, high = min(ey[e], ey[e] + evy[e]), max(ey[e], ey[e] + evy[e])
        first = max(int(np.ceil((y0 - high) / dy - 0.5)) - 1, 0)
        last = min(int(np.floor((y0 - low) / dy - 0.5)) + 1, rows - 1)
        for i in range(first, last + 1):
            y = y0 - (i + 0.5) * dy
            if y < low or y >= high:
                continue
            x = ex[e] + (y - ey[e]) / evy[e] * evx[e]
            k = min(max(int(np.ceil((x - x0) / dx - 0.5)), 0), cols)
            flips[i, k] ^= 1
    inside = np.empty((rows, cols), dtype=np.bool_)
    for i in range(rows):
        parity = 0
        for j in range(cols):
            parity ^= flips[i, j]
            inside[i, j] = parity == 1
    return inside


@numba.njit(**_JIT)
def _feet(qx, qy, edge, ex, ey, evx, evy, einv):  # pragma: no cover - compiled
    """Distance from each point to its given edge, and the nearest point on it (the foot)."""
    n = len(qx)
    distance, fx, fy = np.empty(n), np.empty(n), np.empty(n)
    for i in range(n):
        e = edge[i]
        rx, ry = qx[i] - ex[e], qy[i] - ey[e]
        t = min(max((rx * evx[e] + ry * evy[e]) * einv[e], 0.0), 1.0)
        fx[i], fy[i] = ex[e] + t * evx[e], ey[e] + t * evy[e]
        distance[i] = np.sqrt((qx[i] - fx[i]) ** 2 + (qy[i] - fy[i]) ** 2)
    return distance, fx, fy


@numba.njit(**_JIT)
def _curve_cells(index, ci, cj, cell, s, gx, gy, hxx, hxy, hyy, px, py, count, mask, r0, c0,
                 base):  # pragma: no cover - compiled
    """Rewrite whole cells (ci, cj) from their quadratics (see :func:`curve_cells`): along each pixel
    row of a cell the quadratic is A + (B + C x) x, one branch-free loop."""
    rows, cols = index.shape
    masked = mask.shape[0] > 0
    half = 0.5 * cell
    offsets = (np.arange(cell) + 0.5 - half) * px
    for n in range(len(ci)):
        i, j = ci[n], cj[n]
        height, width = min(cell, rows - i * cell), min(cell, cols - j * cell)
        if height <= 0 or width <= 0:
            continue
        c = 0.5 * hxx[i, j]
        for v in range(height):
            r = i * cell + v
            y = -(v + 0.5 - half) * py
            a = s[i, j] + 1.0 + gy[i, j] * y + 0.5 * hyy[i, j] * y * y
            b = gx[i, j] + hxy[i, j] * y
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


@numba.njit(inline="always", **_JIT)
def _nearest_end(d, sets):  # pragma: no cover - compiled
    """Index m (1..sets-1) of the ending ring set nearest in |d| (the first of equals), d (sets,) mm."""
    m = 1
    for j in range(2, sets):
        if abs(d[j]) < abs(d[m]):
            m = j
    return m


@numba.njit(inline="always", **_JIT)
def _inverse(value):  # pragma: no cover - compiled
    """1 / d, with |d| below 1e-12 taken as 1e-12 (a pixel on a ring)."""
    return 1.0 / (value if abs(value) >= 1e-12 else 1e-12)


@numba.njit(**_JIT)
def _band_field(d, g, count):  # pragma: no cover - compiled
    """s of eq. 10 (pole-free form, regions._band_coordinate) and its gradient at every lattice
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
            m = _nearest_end(here, sets)
            rest, rest_x, rest_y = 0.0, 0.0, 0.0
            for k in range(1, sets):
                if k != m:
                    inverse = _inverse(here[k])
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



@numba.njit(inline="always", **_JIT)
def _band_sensitivities(here, sets, count, out):  # pragma: no cover - compiled
    """ds/dd_j of eq. 10's band coordinate (regions._band_coordinate) at one point into ``out`` (sets,), from
    the signed distances ``here`` (sets,) mm of the starting ring set (0) and each ending one: with m the
    ending set nearest in |d| and D = d_m + d_0 A, ds/dd_0 = N_R A d_m / D^2, ds/dd_m = -N_R d_0 / D^2,
    ds/dd_k = -N_R d_0 d_m^2 / (d_k^2 D^2); all NaN past a pole (D <= 0)."""
    m = _nearest_end(here, sets)
    rest = 0.0
    for k in range(1, sets):
        if k != m:
            rest += _inverse(here[k])
    dm, d0 = here[m], here[0]
    a = 1.0 + dm * rest
    denominator = dm + d0 * a
    if not denominator > 0:
        out[:] = np.nan
        return
    scale = count / (denominator * denominator)
    out[0] = a * dm * scale
    for k in range(1, sets):
        inverse = _inverse(here[k])
        out[k] = -d0 * scale if k == m else -d0 * dm * dm * inverse * inverse * scale


@numba.njit(**_JIT)
def _ring_models(d, g, grad, ci, cj, dx, dy, count, half_diagonal, tolerance):  # pragma: no cover - compiled
    """Per ring set and cell, the quadratic of its signed distance or NaN (regions._ring_models has the
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
        # on the family's side, bounds of the sensitivities over the cell's pixels (regions._ring_models)
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

@numba.njit(**_JIT)
def _band_cells(index, ci, cj, cell, px, py, models, measured, slot, count, length, mask, r0, c0,
                base):  # pragma: no cover - compiled
    """Sub-region k of every pixel of whole cells (ci, cj) from each ring set's distance there: the
    ring's quadratic models[j, n] (d, d_x, d_y, d_xx, d_xy, d_yy at the cell centre) or, where
    its d is NaN, measured[slot[j, n], pixel]; s by eq. 10 (pole-free form of regions._band_coordinate)
    with ring set 0 starting, or s = d_0 count / length with one ring set. Per cell, each ring
    set's distances fill a row of pixels, and eq. 10 runs over the cell's pixels with the
    nearest ending ring kept as a running minimum (the first of equals), so the loops vectorise."""
    rows, cols = index.shape
    masked = mask.shape[0] > 0
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
            model = models[j, n]
            if np.isnan(model[0]):
                d[j] = measured[slot[j, n]]
            else:
                for p in range(pixels):
                    d[j, p] = (model[0] + model[1] * x[p] + model[2] * y[p]
                               + 0.5 * (model[3] * x[p] * x[p] + model[5] * y[p] * y[p]) + model[4] * x[p] * y[p])
        if sets == 1:
            for p in range(pixels):
                s[p] = d[0, p] * count / length
        else:
            nearest[:] = d[1]
            rest[:] = 0.0
            for j in range(2, sets):
                for p in range(pixels):
                    closer = abs(d[j, p]) < abs(nearest[p])
                    rest[p] += _inverse(nearest[p] if closer else d[j, p])
                    nearest[p] = d[j, p] if closer else nearest[p]
            for p in range(pixels):
                numerator = d[0, p] * (1.0 + nearest[p] * rest[p])
                denominator = nearest[p] + numerator
                s[p] = count * numerator / denominator if denominator > 0 else count
        height, width = min(cell, rows - ci[n] * cell), min(cell, cols - cj[n] * cell)
        for v in range(height):
            r, c = ci[n] * cell + v, cj[n] * cell
            line = index[r, c:c + width]
            if masked:
                keep = mask[r0 + r, c0 + c:c0 + c + width]
                for u in range(width):
                    k = min(max(np.floor(s[v * cell + u]) + 1.0, 1.0), count)
                    line[u] = int((k + base) * keep[u])
            else:
                for u in range(width):
                    line[u] = int(min(max(np.floor(s[v * cell + u]) + 1.0, 1.0), count) + base)
    return index


@numba.njit(inline="always", **_EXACT)
def _chunk_word(words, line, k, spread):  # pragma: no cover - compiled
    """The pattern word of chunk k (16 pixels of ``line``): each pixel's label word (``words`` by label)
    masked to its own column in every 16-bit field (``spread``: a 1 in the low bit of each field used)."""
    value = np.int64(0)
    for j in range(16):
        value |= words[line[16 * k + j]] & (spread << (15 - j))
    return value


@numba.njit(inline="always", **_EXACT)
def _chunk_solid(solid, k):  # pragma: no cover - compiled
    """(high byte, low byte, 16-bit mask) of chunk k's solid pixels, from the packed solid row ``solid``."""
    high = np.int64(solid[2 * k])
    low = np.int64(solid[2 * k + 1])
    return high, low, (high << 8) | low


@numba.njit(**_EXACT)
def _droplet_run(line, solid, pattern, first, planes, count, channels):  # pragma: no cover - compiled
    """The common case of :func:`_droplet_bits`: ``count`` chunks of 16 pixels of a row, from chunk
    ``first``, all inside the labels, K <= 4 channels (one pattern word: ``pattern`` (blocks,
    labels) int64 at the row's tile phase); ``line`` (labels), ``solid`` and ``planes`` ((K,
    bytes)) start at chunk ``first``. Returns how many chunks it wrote: it stops before the first
    one with a solid pixel whose label has no table entry (left to the per-pixel mix). A small
    kernel of its own, so the 16-pixel loop keeps its registers; K = 2 writes the second plane
    as the solid byte less the first."""
    wrap = pattern.shape[0] - 1
    if channels == 2:
        for k in range(count):
            high, low, mask = _chunk_solid(solid, k)
            if mask == 0:
                continue
            value = _chunk_word(pattern[np.uint64((first + k) & wrap)], line, k, np.int64(0x10001))
            if (value >> 16) & mask:
                return k
            value &= mask
            if high:
                planes[0, 2 * k] = value >> 8
                planes[1, 2 * k] = high ^ (value >> 8)
            if low:
                planes[0, 2 * k + 1] = value & 255
                planes[1, 2 * k + 1] = low ^ (value & 255)
        return count
    spread = np.int64(0x0001000100010001)
    for k in range(count):
        high, low, mask = _chunk_solid(solid, k)
        if mask == 0:
            continue
        value = _chunk_word(pattern[np.uint64((first + k) & wrap)], line, k, spread)
        if (value >> (16 * (channels - 1))) & mask:
            return k
        union = np.int64(0)
        for m in range(channels):
            v = mask & ~union if m == channels - 1 else (value >> (16 * m)) & mask
            if high:
                planes[m, 2 * k] = v >> 8
            if low:
                planes[m, 2 * k + 1] = v & 255
            union |= v
    return count


@numba.njit(**_EXACT)
def _droplet_bits(label, r0, c0, packed, family_of_label, fraction, layout, mixes, target, tile, base_channel,
                  planes, table, level):  # pragma: no cover - compiled
    """Set one bit per solid pixel in the plane of the material it jets (see :func:`droplet_bits`).

    The table is first turned into bit patterns: per tile row, block of 16 columns and label,
    one 16-bit field per channel but the last (the block's columns where the label jets it)
    and one more for the columns without a table entry, four fields to an int64 word. A row
    is then halftoned 16 pixels at a time, OR-ing each pixel's word masked to its own column
    (no branch, no compare per channel); the last channel's byte is the solid byte less the
    others', and the pixels without a table entry take the general per-pixel mix. With one
    word (K <= 4), the chunks inside the labels go to :func:`_droplet_run` until one has such
    a pixel; after it, the run resumes past the next chunk without any (no call per chunk
    along a family of per-pixel mixes)."""
    channels = planes.shape[0]
    size = tile.shape[0]
    wrap = size - 1
    blocks = max(size, 16) // 16
    words = (channels + 3) // 4
    rows, cols = label.shape
    width = packed.shape[1]
    spread = np.int64(0x0001000100010001)
    pattern = np.empty((size, words, blocks, table.shape[0]), dtype=np.int64)
    for number in range(table.shape[0]):
        entries = table[number]
        for phase in range(size):
            for block in range(blocks):
                for w in range(words):
                    value = np.int64(0)
                    for j in range(16):
                        got = np.int64(entries[level[phase, (block * 16 + j) & wrap]])
                        slot = channels - 1 if got < 0 else got
                        value |= np.int64(got != channels - 1 and slot >> 2 == w) << (16 * (slot & 3) + 15 - j)
                    pattern[phase, w, block, number] = value
    outside = np.zeros(words, dtype=np.int64)
    if base_channel < channels - 1:
        outside[base_channel >> 2] = np.int64(0xFFFF) << (16 * (base_channel & 3))
    acc = np.zeros(words, dtype=np.int64)
    extra = np.zeros(channels, dtype=np.int64)
    mix = np.empty(channels, dtype=np.float32)
    zero, one = np.float32(0.0), np.float32(1.0)
    empty = label.ravel()[:0]
    for row in range(packed.shape[0]):
        solid = packed[row]
        first, last = 0, width - 1
        while first + 16 <= width:
            seen = 0
            for k in range(16):
                seen |= solid[first + k]
            if seen:
                break
            first += 16
        while first <= last and solid[first] == 0:
            first += 1
        if first > last:
            continue
        while last - 16 >= first:
            seen = 0
            for k in range(16):
                seen |= solid[last - k]
            if seen:
                break
            last -= 16
        while solid[last] == 0:
            last -= 1
        r = row - r0
        inside = 0 <= r < rows
        line = label[r] if inside else empty
        left, right = (c0, c0 + cols) if inside else (0, 0)
        phase = row & wrap
        thresholds = tile[phase]
        chunk, end = first >> 1, (last >> 1) + 1
        run_from, run_to = end, end
        if words == 1 and inside:
            run_from = max(chunk, (c0 + 15) >> 4)
            run_to = min(end, (c0 + cols) >> 4, width >> 1)
        while chunk < end:
            if chunk == run_from < run_to:
                chunk += _droplet_run(line[16 * chunk - c0:], solid[2 * chunk:], pattern[phase, 0], chunk,
                                      planes[:, row, 2 * chunk:], run_to - chunk, channels)
                run_from = chunk + 1
                continue
            high = np.int64(solid[2 * chunk])
            low = np.int64(solid[2 * chunk + 1]) if 2 * chunk + 1 < width else np.int64(0)
            mask = (high << 8) | low
            if mask == 0:
                chunk += 1
                continue
            col = chunk * 16
            block = chunk & (blocks - 1)
            if left <= col and col + 16 <= right:
                pixels = line[col - c0:col - c0 + 16]
                for w in range(words):
                    bits = pattern[phase, w, block]
                    value = np.int64(0)
                    for j in range(16):
                        value |= bits[pixels[j]] & (spread << (15 - j))
                    acc[w] = value
            else:
                for w in range(words):
                    bits = pattern[phase, w, block]
                    value = np.int64(0)
                    for j in range(16):
                        c = col + j
                        value |= (bits[line[c - c0]] if left <= c < right else outside[w]) & (spread << (15 - j))
                    acc[w] = value
            missing = (acc[(channels - 1) >> 2] >> (16 * ((channels - 1) & 3))) & mask
            if missing:
                for bit in range(16):
                    if not (missing >> (15 - bit)) & 1:
                        continue
                    c = col + bit
                    number = line[c - c0]
                    family = family_of_label[number]
                    cell = layout[family, 2]
                    j = (c - layout[family, 1]) // cell
                    start = layout[family, 4] + (((row - layout[family, 0]) // cell) * layout[family, 3] + j) * channels
                    f = fraction[number]
                    total = zero
                    for m in range(channels):
                        mix[m] = mixes[start + m] + f * (target[m] - mixes[start + m])
                        total += mix[m]
                    t = thresholds[c & wrap] * (total if total > zero else one)
                    pick = channels - 1
                    running = zero
                    for m in range(channels - 1):
                        running += mix[m]
                        if t < running:
                            pick = m
                            break
                    extra[pick] |= 32768 >> bit
            union = np.int64(0)
            for m in range(channels):
                value = mask & ~union if m == channels - 1 else ((acc[m >> 2] >> (16 * (m & 3))) | extra[m]) & mask
                if high:
                    planes[m, row, 2 * chunk] = value >> 8
                if low:
                    planes[m, row, 2 * chunk + 1] = value & 255
                union |= value
            if missing:
                extra[:] = 0
                if run_from == chunk + 1:
                    run_from += 1
            chunk += 1
    return planes


@numba.njit(inline="always", **_JIT)
def _off_segment(x, y, j, a, c):  # pragma: no cover - compiled
    """Distance (mm) from point j to the segment from point a to point c."""
    vx, vy = x[c] - x[a], y[c] - y[a]
    length2 = vx * vx + vy * vy
    return _point_to_edge(x[j], y[j], x[a], y[a], vx, vy, 1.0 / length2 if length2 > 0.0 else 0.0)



@numba.njit(**_EXACT)
def _disc_winding(points, offsets, loops, cx, cy, reach):  # pragma: no cover - compiled
    """The winding number of the loops around the point (cx, cy), or None when an edge comes within
    ``reach`` of it."""
    winding = 0
    for loop in loops:
        first, last = offsets[loop], offsets[loop + 1]
        for i in range(first, last):
            j = i + 1 if i + 1 < last else first
            ax, ay = points[i, 0] - cx, points[i, 1] - cy
            bx, by = points[j, 0] - cx, points[j, 1] - cy
            vx, vy = bx - ax, by - ay
            length2 = vx * vx + vy * vy
            if _point_to_edge(0.0, 0.0, ax, ay, vx, vy, 1.0 / length2 if length2 > 0.0 else 0.0) <= reach:
                return None
            left = ax * by - bx * ay
            if ay <= 0.0 < by and left > 0.0:
                winding += 1
            elif by <= 0.0 < ay and left < 0.0:
                winding -= 1
    return winding

@numba.njit(**_JIT)
def _straight_runs(x, y, size, tolerance, longest):  # pragma: no cover - compiled
    """(keep (n,) bool, order (n,), knots (n + rings,), knot_at (n + rings,)) of :func:`straight_runs`."""
    n, rings = len(x), len(size)
    keep = np.ones(n, dtype=np.bool_)
    order = np.empty(n, dtype=np.int64)
    knots = np.empty(n + rings)
    knot_at = np.empty(n + rings, dtype=np.int64)
    begin = 0
    edge = 0
    for k in range(rings):
        m = size[k]
        end = begin + m
        # the ring's lowest point in x then y (the first of equal ones) is a corner of its convex hull: walks
        # and edges start there, so that where the ring starts (say where a plane crosses a quad's diagonal)
        # decides nothing
        anchor = 0
        for i in range(1, m):
            if x[begin + i] < x[begin + anchor] or (x[begin + i] == x[begin + anchor]
                                                    and y[begin + i] < y[begin + anchor]):
                anchor = i
        if m > 3:
            a = anchor
            bound = 0.0  # the run's points before i lie within this of the segment from a to i
            for step in range(1, m):
                i = (anchor + step) % m
                c = (i + 1) % m
                run = (i - a) % m
                # that segment lies within i's distance of the one from a to c (they share a), so the run's
                # points lie within the sum of it: no recheck while the run is straight however long
                reach = _off_segment(x, y, begin + i, begin + a, begin + c) + (bound if run > 1 else 0.0)
                if reach > tolerance and run <= longest:
                    reach = 0.0
                    for back in range(run):
                        reach = max(reach, _off_segment(x, y, begin + (a + 1 + back) % m, begin + a, begin + c))
                if reach <= tolerance:
                    keep[begin + i] = False
                    bound = reach
                else:
                    a = i
            if keep[begin:end].sum() < 3:
                keep[begin:end] = True
        # knots from the anchor round the ring: each point at its edge + ring + fraction along the edge
        following = anchor
        ahead = np.empty(m, dtype=np.int64)
        for step in range(m - 1, -1, -1):
            i = (anchor + step) % m
            ahead[i] = following
            if keep[begin + i]:
                following = i
        last = -1.0
        a = anchor
        for step in range(m):
            i = (anchor + step) % m
            order[begin + step] = begin + i
            if keep[begin + i]:
                a = i
                position = float(edge + k)
                edge += 1
            else:
                c = ahead[a]
                vx, vy = x[begin + c] - x[begin + a], y[begin + c] - y[begin + a]
                length2 = vx * vx + vy * vy
                rx, ry = x[begin + i] - x[begin + a], y[begin + i] - y[begin + a]
                t = (rx * vx + ry * vy) / length2 if length2 > 0.0 else 0.0
                position = edge - 1 + k + min(max(t, 0.0), 1.0)
            last = max(last, position)
            knots[begin + k + step] = last
            knot_at[begin + k + step] = begin + i
        knots[end + k] = edge + k
        knot_at[end + k] = begin + anchor
        begin = end
    return keep, order, knots, knot_at



def disc_winding(points: np.ndarray, offsets: np.ndarray, loops: np.ndarray, centre: np.ndarray,
                 reach: float) -> int | None:
    """How many times the given loops (indices into ``offsets``, of points (p, 2) mm) wind around a disc
    (``centre`` (2,), radius ``reach``, mm), counter-clockwise positive: the same at every point of it,
    since None is returned when any of their edges comes within ``reach`` of the centre (compiled)."""
    return _disc_winding(np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(offsets, dtype=np.int64),
                         np.ascontiguousarray(loops, dtype=np.int64), float(centre[0]), float(centre[1]), float(reach))

def straight_runs(x: np.ndarray, y: np.ndarray, size: np.ndarray, tolerance: float, longest: int = 16
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points of closed rings ((n,) mm, ring k the next size[k] points) that can be left out because
    every point of their run lies within ``tolerance`` of the segment between the kept points on
    either side (rings that would keep fewer than three points keep all), walked from each ring's
    anchor, its lowest point in x then y (always kept). A run is bounded as it grows (exactly
    straight runs of any length cost one test per point) and rechecked point by point only while
    at most ``longest`` points long: a slowly bending run stops there.

    Returns keep (n,) bool; order (n,), the points ring by ring from each anchor round (the kept
    ones in this order are the edges' starts); knots (n + rings,), each point's place along the
    edges so numbered, edge + ring + fraction along it, from each ring's anchor round to it again
    (knot_at (n + rings,): which point)."""
    x, y = np.ascontiguousarray(x, dtype=np.float64), np.ascontiguousarray(y, dtype=np.float64)
    return _straight_runs(x, y, np.ascontiguousarray(size, dtype=np.int64), float(tolerance), int(longest))


def edge_tree(x0: np.ndarray, y0: np.ndarray, x1: np.ndarray, y1: np.ndarray):
    """Bounding-box hierarchy of edges from (x0, y0) to (x1, y1) ((n,) float, mm), given in ring order
    so that consecutive edges are near each other: (boxes (total, 4) [xmin, ymin, xmax, ymax],
    level_start (levels + 1,), capsules); level 0 the edges, each level above one box per
    _FAN boxes below, up to a top level of at most _FAN boxes (level 1 always: the chunks of
    :func:`_candidates`). ``capsules`` ((chunks, 6): x, y, vx, vy, 1/|v|^2, radius, mm) hold
    each chunk's edges within ``radius`` of the chord from its first edge's start to its
    last edge's end (a chunk of a smooth ring: within its sagitta), so the chord's distance
    less the radius is a lower bound of the chunk's (:func:`_nearest_in_chunks`)."""
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    x0, y0, x1, y1 = f64(x0), f64(y0), f64(x1), f64(y1)
    sizes = [len(x0)]
    while len(sizes) == 1 or sizes[-1] > _FAN:
        sizes.append(-(-sizes[-1] // _FAN))
    level_start = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    return _tree_boxes(x0, y0, x1, y1, level_start), level_start, _chunk_capsules(x0, y0, x1, y1)


@numba.njit(**_JIT)
def _tree_boxes(x0, y0, x1, y1, level_start):  # pragma: no cover - compiled
    """(level_start[-1], 4) boxes of :func:`edge_tree`: the edges', then each level's over _FAN below."""
    boxes = np.empty((level_start[-1], 4))
    for e in range(len(x0)):
        boxes[e, 0], boxes[e, 1] = min(x0[e], x1[e]), min(y0[e], y1[e])
        boxes[e, 2], boxes[e, 3] = max(x0[e], x1[e]), max(y0[e], y1[e])
    for level in range(1, len(level_start) - 1):
        below, first = level_start[level - 1], level_start[level]
        for node in range(level_start[level + 1] - first):
            lo, hi = below + node * _FAN, min(below + node * _FAN + _FAN, first)
            box = boxes[first + node]
            box[0], box[1], box[2], box[3] = boxes[lo, 0], boxes[lo, 1], boxes[lo, 2], boxes[lo, 3]
            for child in range(lo + 1, hi):
                box[0], box[1] = min(box[0], boxes[child, 0]), min(box[1], boxes[child, 1])
                box[2], box[3] = max(box[2], boxes[child, 2]), max(box[3], boxes[child, 3])
    return boxes


@numba.njit(**_JIT)
def _chunk_capsules(x0, y0, x1, y1):  # pragma: no cover - compiled
    """(chunks, 6) per run of _FAN consecutive edges: its chord (start x, y, vector, 1/|v|^2, 0 if
    zero-length) and the largest distance of its edges' ends from the chord, widened by 1e-4 mm
    for float32 comparisons (see :func:`edge_tree`)."""
    count = len(x0)
    chunks = -(-count // _FAN)
    out = np.empty((chunks, 6))
    for c in range(chunks):
        first, last = c * _FAN, min(c * _FAN + _FAN, count) - 1
        ox, oy = x0[first], y0[first]
        vx, vy = x1[last] - ox, y1[last] - oy
        length2 = vx * vx + vy * vy
        inv = 1.0 / length2 if length2 > 0 else 0.0
        gap = 0.0
        for e in range(first, last + 1):
            for px, py in ((x0[e], y0[e]), (x1[e], y1[e])):
                gap = max(gap, _point_to_edge(px, py, ox, oy, vx, vy, inv))
        out[c, 0], out[c, 1], out[c, 2], out[c, 3], out[c, 4] = ox, oy, vx, vy, inv
        out[c, 5] = gap * (1 + 1e-9) + 1e-4
    return out


def nearest_in_groups(cx: np.ndarray, cy: np.ndarray, radius: np.ndarray, ox: np.ndarray, oy: np.ndarray,
                      ex: np.ndarray, ey: np.ndarray, evx: np.ndarray, evy: np.ndarray, einv: np.ndarray,
                      tree, track: bool = True) -> np.ndarray:
    """The points (cx[g] + ox[k], cy[g] + oy[k]) against the edges of the chunks within radius[g] of
    (cx[g], cy[g]) (every edge within the radius, and maybe a few beyond: exact wherever the
    radius holds each point's nearest edge): with ``track`` the nearest edge ((g, k) int32, -1
    where none), else the squared distance to it ((g, k) float32, mm^2; inf where none). Both in
    float32 from the group's centre (see :func:`_nearest_in_chunks`).

    Edges run from (ex, ey) by (evx, evy) ((n,) float, mm), einv = 1 / |v|^2 (0 for a
    zero-length edge); ``tree`` is :func:`edge_tree` of the same edges.
    """
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731 - one conversion, many arrays
    f32 = lambda a: np.ascontiguousarray(a, dtype=np.float32)  # noqa: E731
    cx, cy, radius, ex, ey, evx, evy, einv = (f64(a) for a in (cx, cy, radius, ex, ey, evx, evy, einv))
    ox, oy = f32(ox), f32(oy)
    boxes, level_start, capsules = tree
    parts = []
    # groups deep inside a round part gather most of its chunks: a bounded number at a time
    step = max(1, _PAIRS // max(1, len(capsules)))
    for first in range(0, max(len(cx), 1), step):
        group = slice(first, first + step)
        start, chunk = _candidates(cx[group], cy[group], radius[group], boxes, level_start)
        best, which = _nearest_in_chunks(cx[group], cy[group], ox, oy, start, chunk, capsules, ex, ey, evx, evy, einv,
                                         track)
        parts.append(which if track else best)
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def edge_sets_apart(a: np.ndarray, tree_a, b: np.ndarray, tree_b, bound: float) -> float:
    """Least vertex-to-edge distance (mm) both ways between two edge sets ((n, 5) x, y, vx, vy, 1/|v|^2,
    each with its :func:`edge_tree`), given an upper bound ``bound`` of it (returned if nothing is closer):
    chunk pairs whose capsules cannot come that close are skipped (:func:`_chunks_apart`)."""
    capsules_a, capsules_b = tree_a[2], tree_b[2]
    centre_x = capsules_a[:, 0] + 0.5 * capsules_a[:, 2]
    centre_y = capsules_a[:, 1] + 0.5 * capsules_a[:, 3]
    reach = 0.5 * np.hypot(capsules_a[:, 2], capsules_a[:, 3]) + capsules_a[:, 5]
    start, candidate = _candidates(centre_x, centre_y, bound + reach, tree_b[0], tree_b[1])
    return float(_chunks_apart(start, candidate, capsules_a, capsules_b, np.ascontiguousarray(a, dtype=np.float64),
                               np.ascontiguousarray(b, dtype=np.float64), float(bound)))


def expand_planes(s: np.ndarray, gx: np.ndarray, gy: np.ndarray, cell: int, px: float, py: float,
                  count: int, out: np.ndarray, mask: np.ndarray | None = None, origin: tuple[int, int] = (0, 0),
                  base: int = 0, empty: np.ndarray | None = None) -> np.ndarray:
    """Sub-region k = clip(floor(s) + 1, 1, count) at every pixel of ``out`` ((rows, cols) int16/int32,
    rows <= cells_r * cell) from one plane per lattice cell: s (cells_r, cells_c) at the cell
    centre, gradient (gx, gy) per mm (y up, rows down), plus ``base``: a family's labels in the
    same pass. With ``mask`` ((h, w) bool, C order; ``out`` covers rows/columns from ``origin``
    of it) pixels where it is False get 0. ``empty`` ((cells_r, cells_c) bool) cells are written
    0 throughout."""
    if out.shape[0] > np.shape(s)[0] * cell or out.shape[1] > np.shape(s)[1] * cell:
        raise ValueError(f"expand_planes: {out.shape} pixels exceed {np.shape(s)} cells of {cell}")
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    mask = np.zeros((0, 0), dtype=np.bool_) if mask is None else np.ascontiguousarray(mask)
    empty = np.zeros(np.shape(s), dtype=np.bool_) if empty is None else np.ascontiguousarray(empty, dtype=np.bool_)
    return _expand_planes(f64(s), f64(gx), f64(gy), empty, int(cell), float(px), float(py), float(count), out, mask,
                          int(origin[0]), int(origin[1]), int(base))


def refine_flags(s: np.ndarray, grad: np.ndarray, known: np.ndarray, side: np.ndarray, candidate: np.ndarray,
                 dx: float, dy: float, tolerance: float, limit: float, count: int,
                 hessian: np.ndarray | None = None, vertices: tuple | None = None) -> np.ndarray:
    """(rows, cols) bool: lattice cells whose plane (and quadratic, with a ``hessian``) does not fit
    (see :func:`_refine_flags`); s (rows, cols), grad (rows, cols, 2) per mm, known/side/candidate
    (rows, cols) bool, dx/dy the cell (mm), count N_R; hessian (3, rows, cols) s_xx, s_xy, s_yy
    per mm^2, zeroed in place where the plane is kept. ``vertices``: (start (rows * cols + 1,),
    x, y, s, x0, y0), the ring vertices in each cell (a CSR), their exact s, and the lattice's
    top-left corner (mm); None: no vertex check."""
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    parts = f64(hessian) if hessian is not None else np.zeros((3, 0, 0))
    if vertices is None:
        vertices = (np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0), np.zeros(0), 0.0, 0.0)
    vstart, vx, vy, vs, x0, y0 = vertices
    out = _refine_flags(f64(s), f64(grad), parts[0], parts[1], parts[2],
                        np.ascontiguousarray(known), np.ascontiguousarray(side), np.ascontiguousarray(candidate),
                        float(dx), float(dy), float(tolerance), float(limit), float(count),
                        np.ascontiguousarray(vstart, dtype=np.int64), f64(vx), f64(vy), f64(vs), float(x0), float(y0))
    if hessian is not None and parts is not hessian:
        hessian[...] = parts
    return out


def hessian_of(grad: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """(3, rows, cols) s_xx, s_xy, s_yy per mm^2 from gradients (rows, cols, 2) per mm at lattice centres
    dx, dy (mm) apart (compiled :func:`_hessian_of`)."""
    return _hessian_of(np.ascontiguousarray(grad, dtype=np.float64), float(dx), float(dy))


def signed_feet(edge: np.ndarray, x0: float, y0: float, dx: float, dy: float, ex: np.ndarray, ey: np.ndarray,
                evx: np.ndarray, evy: np.ndarray, einv: np.ndarray, inside: np.ndarray,
                encloses: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(signed distance (rows, cols) mm, unit gradient (rows, cols, 2), foot (2, rows, cols) mm) of every
    centre of a lattice (x0, y0 its top-left corner, dx, dy its cells, mm) from its nearest edge ``edge``
    ((rows, cols) int); > 0 where ``inside`` ((rows, cols) bool) equals ``encloses`` (compiled)."""
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    return _signed_feet(np.ascontiguousarray(edge, dtype=np.int64), float(x0), float(y0), float(dx), float(dy),
                        f64(ex), f64(ey), f64(evx), f64(evy), f64(einv), np.ascontiguousarray(inside), bool(encloses))


def inside_centres(ex: np.ndarray, ey: np.ndarray, evx: np.ndarray, evy: np.ndarray, x0: float, y0: float,
                   dx: float, dy: float, rows: int, cols: int) -> np.ndarray:
    """(rows, cols) bool: the centres of a lattice (x0, y0 its top-left corner, dx, dy its cells, mm) inside
    the closed rings of the edges from (ex, ey) by (evx, evy) ((n,) mm), even-odd: inside any of
    them when they neither cross nor nest (compiled :func:`_inside_centres`)."""
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    return _inside_centres(f64(ex), f64(ey), f64(evx), f64(evy), float(x0), float(y0), float(dx), float(dy),
                           int(rows), int(cols))


def feet(qx: np.ndarray, qy: np.ndarray, edge: np.ndarray, ex: np.ndarray, ey: np.ndarray, evx: np.ndarray,
         evy: np.ndarray, einv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance (n,) mm from points (qx, qy) to the given edges ((n,) int) and the nearest point on each
    (foot x, foot y (n,) mm); edges as in :func:`nearest_in_groups`."""
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    return _feet(f64(qx), f64(qy), np.ascontiguousarray(edge, dtype=np.int64), f64(ex), f64(ey), f64(evx), f64(evy),
                 f64(einv))



def band_field(d: np.ndarray, g: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """(s (rows, cols), its gradient (rows, cols, 2) per mm) of eq. 10 at lattice centres from the signed
    distances d (sets, rows, cols) mm and gradients g (sets, rows, cols, 2) of the starting ring set
    and each ending one (two or more sets; compiled :func:`_band_field`)."""
    return _band_field(np.ascontiguousarray(d, dtype=np.float64), np.ascontiguousarray(g, dtype=np.float64),
                       float(count))



def ring_models(d: np.ndarray, g: np.ndarray, grad: np.ndarray, ci: np.ndarray, cj: np.ndarray, dx: float, dy: float,
                count: int, half_diagonal: float, tolerance: float) -> np.ndarray:
    """(sets, n, 6) per ring set and lattice cell (ci, cj) ((n,) int, off the border) the quadratic of its
    signed distance (d, d_x, d_y, d_xx, d_xy, d_yy at the centre, mm) where eq. 10's s stays within
    ``tolerance`` (mm of s's slope) with it, else NaN: regions._ring_models' choice, compiled. d (sets,
    rows, cols) mm and g (sets, rows, cols, 2) per ring set, grad (rows, cols, 2) s's gradient at the
    centres, dx, dy the cells (mm), half_diagonal half a cell's diagonal (mm)."""
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    return _ring_models(f64(d), f64(g), f64(grad), np.ascontiguousarray(ci, dtype=np.int64),
                        np.ascontiguousarray(cj, dtype=np.int64), float(dx), float(dy), float(count),
                        float(half_diagonal), float(tolerance))

def band_cells(index: np.ndarray, ci: np.ndarray, cj: np.ndarray, cell: int, px: float, py: float,
               models: np.ndarray, measured: np.ndarray, slot: np.ndarray, count: int, length: float,
               mask: np.ndarray | None = None, origin: tuple[int, int] = (0, 0), base: int = 0) -> np.ndarray:
    """Sub-region k = clip(floor(s) + 1, 1, count) of every pixel of lattice cells (ci, cj) ((n,) int), in
    place, from per ring set (starting rings first) either a quadratic of its distance per cell
    (models (sets, n, 6): d, d_x, d_y, d_xx, d_xy, d_yy, mm, at the cell centre; pixel offsets
    from the centre y up) or, where models[j, n, 0] is NaN, the distance at each pixel
    (measured[slot[j, n]], measured (m, cell * cell) row-major in a cell, slot (sets, n) int);
    s by eq. 10 for two or more ring sets, d count / length for one; ``mask``, ``origin`` and
    ``base`` as in :func:`expand_planes`."""
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    mask = np.zeros((0, 0), dtype=np.bool_) if mask is None else np.ascontiguousarray(mask)
    return _band_cells(index, np.ascontiguousarray(ci, dtype=np.int64), np.ascontiguousarray(cj, dtype=np.int64),
                       int(cell), float(px), float(py), f64(models), np.ascontiguousarray(measured, dtype=np.float32),
                       np.ascontiguousarray(slot, dtype=np.int64), float(count), float(length), mask,
                       int(origin[0]), int(origin[1]), float(base))


def droplet_bits(label: np.ndarray, origin: tuple[int, int], packed: np.ndarray, family_of_label: np.ndarray,
                 fraction: np.ndarray, layout: np.ndarray, mixes: np.ndarray, target: np.ndarray, tile: np.ndarray,
                 base_channel: int, planes: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Halftone a labelled layer into bit-packed droplet masks, in place in ``planes`` ((K, h, ceil(w/8)) uint8).

    label ((rows, cols) int, 0 empty) covers the layer from pixel ``origin``; a labelled
    pixel's mix is its family's start mix at its lattice cell (``mixes`` flat, family f's
    cells from layout[f, 4], cells of layout[f, 2] pixels from row layout[f, 0], column
    layout[f, 1], layout[f, 3] cells per row) moved by fraction[label] towards ``target``
    (eq. 1); the pixel jets the first material whose running sum of the mix exceeds the
    ordered-dither threshold ``tile``[row % n, col % n] (n a power of two) times the mix's total
    (:func:`heoslice.halftone.choose_materials`, in the same float32 arithmetic, so the
    masks agree bit for bit). ``packed`` is the layer's solid mask ((h, ceil(w/8)) uint8,
    rows MSB first, padding bits clear); its solid pixels without a label jet
    ``base_channel``. ``table`` ((labels, n * n) int8) short-cuts all that for a label
    whose entry at the pixel's threshold level is not -1 (the level of threshold t is
    t n^2 - 1/2: the tile holds the ordered-dither values (k + 1/2) / n^2); its row 0 (no
    label) must hold ``base_channel``. Labels are read as unsigned (none is negative); bytes
    of ``planes`` without a solid pixel are left as they are. About 0.55 ns per solid pixel where
    the table has entries (an organ layer of ``slice --channels``, K = 2), ~20 ns where it has none.
    """
    size = tile.shape[0]
    # C order whichever symmetry the layer's tile has (a transposed one is Fortran-ordered): one compiled signature
    level = np.ascontiguousarray(np.rint(np.asarray(tile, dtype=np.float64) * size * size - 0.5).astype(np.int64))
    label = np.ascontiguousarray(label)
    if label.dtype.kind == "i":
        label = label.view(f"u{label.itemsize}")
    return _droplet_bits(label, int(origin[0]), int(origin[1]), np.ascontiguousarray(packed),
                         np.ascontiguousarray(family_of_label, dtype=np.int64),
                         np.ascontiguousarray(fraction, dtype=np.float32), np.ascontiguousarray(layout, dtype=np.int64),
                         np.ascontiguousarray(mixes, dtype=np.float32), np.ascontiguousarray(target, dtype=np.float32),
                         np.ascontiguousarray(tile, dtype=np.float32), int(base_channel), planes,
                         np.ascontiguousarray(table, dtype=np.int8), level)


def curve_cells(index: np.ndarray, ci: np.ndarray, cj: np.ndarray, cell: int, s: np.ndarray, grad: np.ndarray,
                hessian: np.ndarray, px: float, py: float, count: int, mask: np.ndarray | None = None,
                origin: tuple[int, int] = (0, 0), base: int = 0) -> np.ndarray:
    """Sub-region k of every pixel of lattice cells (ci, cj) ((n,) int) from the cell's quadratic
    s + g.d + d.H.d / 2 (s (rows, cols), grad (rows, cols, 2) per mm, hessian (3, rows, cols)
    s_xx, s_xy, s_yy per mm^2; d the pixel's offset from the cell centre, y up), in place;
    ``mask``, ``origin`` and ``base`` as in :func:`expand_planes`."""
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    mask = np.zeros((0, 0), dtype=np.bool_) if mask is None else np.ascontiguousarray(mask)
    return _curve_cells(index, np.ascontiguousarray(ci, dtype=np.int64), np.ascontiguousarray(cj, dtype=np.int64),
                        int(cell), f64(s), f64(grad[..., 0]), f64(grad[..., 1]), f64(hessian[0]),
                        f64(hessian[1]), f64(hessian[2]), float(px), float(py), float(count), mask,
                        int(origin[0]), int(origin[1]), float(base))
