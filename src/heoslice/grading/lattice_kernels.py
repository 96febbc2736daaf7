"""Compiled loops of :mod:`heoslice.grading.lattice`: signed distances, gradients and feet at lattice centres,
which centres are inside a ring set, points' distances to given edges, and the passes over a lattice's blocks
(their bounds, which are off the family's side, and the nearest edge of their cells)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from heoslice.grading.edges import RingEdges, following_edges
from heoslice.grading.edges_kernels import EdgeArrays, edge_arrays
from heoslice.grading.search_kernels import EdgeTree, _nearest_in_batches, _nearest_starts
from heoslice.jit import EXACT, JIT, f64, helper, i64, kernel

#: Lattice cells per side of the blocks whose centres share candidate edges
#: (:func:`heoslice.grading.lattice.lattice_edges`).
BLOCK = 8


class LatticeFrame(NamedTuple):
    """Where a lattice's cell centres are: (x0 + (j + 1/2) dx, y0 - (i + 1/2) dy), mm (x0, y0 its top-left corner)."""

    x0: float
    y0: float
    dx: float
    dy: float


def frame_of(lattice) -> LatticeFrame:
    """The LatticeFrame of anything with x0, y0, dx, dy (a :class:`heoslice.grading.lattice.Lattice`)."""
    return LatticeFrame(float(lattice.x0), float(lattice.y0), float(lattice.dx), float(lattice.dy))


@kernel(JIT)
def _signed_feet(edge, frame, edges, inside, encloses):  # pragma: no cover - compiled
    """At every lattice centre (x0 + (j + 1/2) dx, y0 - (i + 1/2) dy): signed distance to its edge
    (> 0 where ``inside`` equals ``encloses``), its unit gradient (0 on the edge) and the foot."""
    x0, y0, dx, dy = frame
    ex, ey, evx, evy, einv = edges
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


def signed_feet(edge: np.ndarray, frame: LatticeFrame, edges: EdgeArrays, inside: np.ndarray,
                encloses: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(signed distance (rows, cols) mm, unit gradient (rows, cols, 2), foot (2, rows, cols) mm) of every
    centre of a lattice (``frame``, or a Lattice) from its nearest edge ``edge`` ((rows, cols) int into
    ``edges``, or RingEdges); > 0 where ``inside`` ((rows, cols) bool) equals ``encloses`` (compiled)."""
    return _signed_feet(i64(edge), frame_of(frame), edge_arrays(edges), np.ascontiguousarray(inside), bool(encloses))


@kernel(JIT)
def _inside_centres(edges, end_y, frame, rows, cols):  # pragma: no cover - compiled
    """(rows, cols) bool: lattice centres (x0 + (j + 1/2) dx, y0 - (i + 1/2) dy) inside the closed rings
    whose edges run from (ex, ey) by (evx, evy) to a point at height end_y (the next edge's ey), by the
    parity of the edges crossed to their left (each edge half-open in y, between the very values of its
    two end points, so a vertex at a centre's height is crossed once where the ring passes it)."""
    ex, ey, evx, evy, _ = edges
    x0, y0, dx, dy = frame
    flips = np.zeros((rows, cols + 1), dtype=np.uint8)
    for e in range(len(ex)):
        if end_y[e] == ey[e]:
            continue
        low, high = min(ey[e], end_y[e]), max(ey[e], end_y[e])
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


def _end_heights(edges: RingEdges) -> np.ndarray:
    """(n,) float64: the height each edge ends at, its ring's next edge's start (not y + vy, which rounds)."""
    return f64(edges.y)[following_edges(edges)]


def inside_centres(edges: RingEdges, frame: LatticeFrame, rows: int, cols: int) -> np.ndarray:
    """(rows, cols) bool: the centres of a lattice (``frame``, or a Lattice) inside the closed rings of
    ``edges``, even-odd: inside any of them when they neither cross nor nest (compiled
    :func:`_inside_centres`; each edge ends at the height its ring's next edge starts at, not at
    y + vy, which rounds)."""
    return _inside_centres(edge_arrays(edges), _end_heights(edges), frame_of(frame), int(rows), int(cols))


@kernel(JIT)
def _feet(qx, qy, edge, edges):  # pragma: no cover - compiled
    """Distance from each point to its given edge, and the nearest point on it (the foot)."""
    ex, ey, evx, evy, einv = edges
    n = len(qx)
    distance, fx, fy = np.empty(n), np.empty(n), np.empty(n)
    for i in range(n):
        e = edge[i]
        rx, ry = qx[i] - ex[e], qy[i] - ey[e]
        t = min(max((rx * evx[e] + ry * evy[e]) * einv[e], 0.0), 1.0)
        fx[i], fy[i] = ex[e] + t * evx[e], ey[e] + t * evy[e]
        distance[i] = np.sqrt((qx[i] - fx[i]) ** 2 + (qy[i] - fy[i]) ** 2)
    return distance, fx, fy


def feet(qx: np.ndarray, qy: np.ndarray, edge: np.ndarray, edges: EdgeArrays) -> tuple[np.ndarray, np.ndarray,
                                                                                     np.ndarray]:
    """Distance (n,) mm from points (qx, qy) to the given edges ((n,) int into ``edges``, EdgeArrays or
    RingEdges) and the nearest point on each (foot x, foot y (n,) mm)."""
    return _feet(f64(qx), f64(qy), i64(edge), edge_arrays(edges))


@helper(EXACT)
def _block_centre(frame, i, j):  # pragma: no cover - compiled
    """(x, y) mm of the centre of block (i, j) of BLOCK x BLOCK cells: as the block lattice's
    :meth:`heoslice.grading.lattice.Lattice.centres` computes it, bit for bit."""
    x0, y0, dx, dy = frame
    return x0 + (j + 0.5) * (dx * BLOCK), y0 - (i + 0.5) * (dy * BLOCK)


@kernel(EXACT)
def _block_bounds(edges, tree, frame, rows, cols):  # pragma: no cover - compiled
    """Per block of BLOCK x BLOCK cells of a lattice (``frame``, rows x cols cells): the edge nearest its
    centre, among those within the centre's distance to the nearest chunk's first point (of edges at the
    same least distance, the one the search meets first), and the exact distance to it ((block rows, block
    cols) int, float). The centres and distances are numpy's arithmetic, bit for bit (no fast-math here;
    the search keeps its own)."""
    brows, bcols = -(-rows // BLOCK), -(-cols // BLOCK)
    cx, cy = np.empty(brows * bcols), np.empty(brows * bcols)
    for i in range(brows):
        for j in range(bcols):
            cx[i * bcols + j], cy[i * bcols + j] = _block_centre(frame, i, j)
    reach = _nearest_starts(cx, cy, tree.capsules) * (1 + 1e-6) + 1e-6
    zero = np.zeros(1, dtype=np.float32)
    _, which = _nearest_in_batches(cx, cy, reach, zero, zero, tree, edges, True)
    edge = which[:, 0].astype(np.int64)
    upper = _feet(cx, cy, edge, edges)[0]
    return edge.reshape(brows, bcols), upper.reshape(brows, bcols)


@kernel(EXACT)
def _block_passes(edges, end_y, tree, frame, rows, cols, encloses):  # pragma: no cover - compiled
    """A ring set's passes over a lattice in one: :func:`_block_bounds`, the cell centres inside the rings
    (:func:`_inside_centres`) and the blocks off the family's side of them (see
    :func:`heoslice.grading.lattice.ring_measures`): (edge, upper, inside (rows, cols) bool, far)."""
    x0, y0, dx, dy = frame
    edge, upper = _block_bounds(edges, tree, frame, rows, cols)
    inside = _inside_centres(edges, end_y, frame, rows, cols)
    brows, bcols = edge.shape
    far = np.zeros((brows, bcols), dtype=np.bool_)
    # each block judged at one of its cells, by the way to its farthest cell centre and a cell's diagonal and a half
    blocks = brows * bcols
    qx, qy, radius, margin = np.empty(blocks), np.empty(blocks), np.empty(blocks), np.empty(blocks)
    where = np.empty(blocks, dtype=np.int64)
    count = 0
    diagonal = 1.5 * np.hypot(dx, dy)
    for i in range(brows):
        first_r = i * BLOCK
        rep_r = min(first_r + BLOCK // 2, rows - 1)
        span_r = max(rep_r - first_r, min(first_r + BLOCK - 1, rows - 1) - rep_r) * dy
        y = y0 - (rep_r + 0.5) * dy
        for j in range(bcols):
            first_c = j * BLOCK
            rep_c = min(first_c + BLOCK // 2, cols - 1)
            span_c = max(rep_c - first_c, min(first_c + BLOCK - 1, cols - 1) - rep_c) * dx
            x = x0 + (rep_c + 0.5) * dx
            gap = np.hypot(span_r, span_c) + diagonal
            bx, by = _block_centre(frame, i, j)
            reach = upper[i, j] + np.hypot(x - bx, y - by)
            if inside[rep_r, rep_c] != encloses and reach > gap:
                qx[count], qy[count], margin[count], where[count] = x, y, gap, i * bcols + j
                radius[count] = reach * (1 + 1e-9) + 1e-9
                count += 1
    if count:
        zero = np.zeros(1, dtype=np.float32)
        qx, qy, radius = qx[:count], qy[:count], radius[:count]
        squared, _ = _nearest_in_batches(qx, qy, radius, zero, zero, tree, edges, False)
        for n in range(count):
            far[where[n] // bcols, where[n] % bcols] = squared[n, 0] > margin[n] ** 2
    return edge, upper, inside, far


@kernel(EXACT)
def _block_edges(block_edge, upper, wanted, frame, rows, cols, edges, tree):  # pragma: no cover - compiled
    """(rows, cols) int: the nearest edge of every cell centre of the ``wanted`` blocks ((block rows, block
    cols) bool), among the edges within upper + 2 max a of the block's centre (see
    :func:`heoslice.grading.lattice.lattice_edges`); elsewhere the block's ``block_edge``."""
    _, _, dx, dy = frame
    brows, bcols = block_edge.shape
    points = BLOCK * BLOCK
    ox, oy = np.empty(points), np.empty(points)
    extra = 0.0
    for v in range(BLOCK):
        for u in range(BLOCK):
            ox[v * BLOCK + u] = (u + 0.5 - 0.5 * BLOCK) * dx
            oy[v * BLOCK + u] = -(v + 0.5 - 0.5 * BLOCK) * dy
            extra = max(extra, np.hypot(ox[v * BLOCK + u], oy[v * BLOCK + u]))
    count = 0
    for i in range(brows):
        for j in range(bcols):
            count += wanted[i, j]
    cx, cy, radius = np.empty(count), np.empty(count), np.empty(count)
    slot = np.full((brows, bcols), -1, dtype=np.int64)
    n = 0
    for i in range(brows):
        for j in range(bcols):
            if wanted[i, j]:
                cx[n], cy[n] = _block_centre(frame, i, j)
                radius[n] = upper[i, j] + 2.0 * extra
                slot[i, j] = n
                n += 1
    which = np.zeros((0, points), dtype=np.int32)
    if count:
        _, which = _nearest_in_batches(cx, cy, radius, ox.astype(np.float32), oy.astype(np.float32), tree, edges,
                                       True)
    edge = np.empty((rows, cols), dtype=np.int64)
    for r in range(rows):
        for c in range(cols):
            g = slot[r // BLOCK, c // BLOCK]
            edge[r, c] = block_edge[r // BLOCK, c // BLOCK] if g < 0 else which[g, (r % BLOCK) * BLOCK + c % BLOCK]
    return edge


def _some_edges(edges) -> None:
    """Refuse a ring set without edges (its nearest edge would be none): ValueError."""
    if not len(edges.x):
        raise ValueError("a ring set without edges has no nearest edge")


def block_bounds_of(edges: EdgeArrays, tree, frame: LatticeFrame, rows: int, cols: int) -> tuple[np.ndarray,
                                                                                               np.ndarray]:
    """(edge, upper) per block of a lattice's cells (compiled :func:`_block_bounds`)."""
    _some_edges(edges)
    return _block_bounds(edge_arrays(edges), EdgeTree(*tree), frame_of(frame), int(rows), int(cols))


def block_passes(edges: RingEdges, tree, frame: LatticeFrame, rows: int, cols: int, encloses: bool) -> tuple:
    """(edge, upper, inside, far) of a ring set over a lattice (compiled :func:`_block_passes`)."""
    _some_edges(edges)
    return _block_passes(edge_arrays(edges), _end_heights(edges), EdgeTree(*tree), frame_of(frame), int(rows),
                         int(cols), bool(encloses))


def block_edges(block_edge: np.ndarray, upper: np.ndarray, wanted: np.ndarray, frame: LatticeFrame, rows: int,
                cols: int, edges: EdgeArrays, tree) -> np.ndarray:
    """(rows, cols) int: every cell centre's nearest edge in the wanted blocks (compiled :func:`_block_edges`)."""
    return _block_edges(i64(block_edge), f64(upper), np.ascontiguousarray(wanted, dtype=np.bool_), frame_of(frame),
                        int(rows), int(cols), edge_arrays(edges), EdgeTree(*tree))
