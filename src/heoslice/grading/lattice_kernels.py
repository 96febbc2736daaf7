"""Compiled loops of :mod:`heoslice.grading.lattice`: signed distances, gradients and feet at lattice centres,
which centres are inside a ring set, and points' distances to given edges."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from heoslice.grading.edges import RingEdges, following_edges
from heoslice.grading.edges_kernels import EdgeArrays, edge_arrays
from heoslice.jit import JIT, f64, i64, kernel


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


def inside_centres(edges: RingEdges, frame: LatticeFrame, rows: int, cols: int) -> np.ndarray:
    """(rows, cols) bool: the centres of a lattice (``frame``, or a Lattice) inside the closed rings of
    ``edges``, even-odd: inside any of them when they neither cross nor nest (compiled
    :func:`_inside_centres`; each edge ends at the height its ring's next edge starts at, not at
    y + vy, which rounds)."""
    end_y = f64(edges.y)[following_edges(edges)]
    return _inside_centres(edge_arrays(edges), end_y, frame_of(frame), int(rows), int(cols))


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
