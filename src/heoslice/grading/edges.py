"""The edges of a layer's rings, without the points on the straight line between their neighbours.

Points where a plane crosses a flat quad's diagonal lie on the line between their
neighbours: leaving them out gives the layers of an extruded part the same edges, so a
family may take the previous layer's field (:mod:`heoslice.grading.cache`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from heoslice.grading.edges_kernels import convex_turns, kept_edges, straight_runs

#: Largest distance (mm) of a ring point from the edge that replaces it for it to be left out of the ring's edges.
_STRAIGHT_MM = 1e-5


@dataclass(frozen=True)
class RingEdges:
    """The edges of some closed rings, flattened: edge i runs from (x[i], y[i]) by (vx[i], vy[i]) (mm).

    ``inv_len2`` is 1 / |v|^2 (0 for a zero-length edge), ``ring`` the ring (position in
    the list given), ``first``/``second`` the indices of its end points in the layer's points.
    Points on the straight line between their neighbours (a plane crossing the diagonal of a
    flat quad, repeated points) are left out: an edge may span several of the layer's
    points. Each ring's edges start at its lowest point in x, then y, wherever its points
    start. ``knots`` ((m,) float) places every point of the rings, and each ring's first
    edge's start again at its end, along the edges: edge i + ring[i] + t at fraction t of
    edge i; ``knot_point`` ((m,) int) is that point's index in the layer's points.
    """

    x: np.ndarray
    y: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    inv_len2: np.ndarray
    ring: np.ndarray
    first: np.ndarray
    second: np.ndarray
    knots: np.ndarray
    knot_point: np.ndarray


def following_edges(edges: RingEdges) -> np.ndarray:
    """(n,) int: the edge after each edge round its ring (a ring's last edge is followed by its first)."""
    last = np.r_[np.flatnonzero(np.diff(edges.ring)), len(edges.ring) - 1]
    following = np.arange(1, len(edges.ring) + 1)
    following[last] = np.r_[0, last[:-1] + 1]
    return following


def convex_rings(edges: RingEdges) -> bool:
    """Whether every ring of the edges turns one way only (no reflex vertex; turns under 1e-9 rad ignored;
    compiled, :func:`heoslice.grading.edges_kernels.convex_turns`)."""
    return convex_turns(edges.vx, edges.vy, edges.inv_len2, edges.ring, 1e-9)


def _loop_points(offsets: np.ndarray, loops: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The indices of the given loops' points in the layer, loop after loop ((n,) int), and their sizes ((l,))."""
    begin = offsets[loops]
    sizes = offsets[loops + 1] - begin
    return np.repeat(begin - (np.cumsum(sizes) - sizes), sizes) + np.arange(int(sizes.sum())), sizes


def _kept(points: np.ndarray, offsets: np.ndarray, loops) -> tuple:
    """The given loops' edges between the points :func:`heoslice.grading.edges_kernels.straight_runs` keeps:
    (the loops' points in the layer, loop after loop, their knots and knot_at, and
    :func:`heoslice.grading.edges_kernels.kept_edges` of them)."""
    every, sizes = _loop_points(offsets, np.asarray(loops, dtype=np.int64))
    keep, order, knots, knot_at = straight_runs(points[every, 0], points[every, 1], sizes, _STRAIGHT_MM)
    return every, knots, knot_at, kept_edges(points, every, sizes, keep, order)


def ring_geometry(points: np.ndarray, offsets: np.ndarray, loop_sets) -> list[tuple[bytes, bytes, bytes]]:
    """Each given set of loops' edges (what :func:`ring_edges` keeps) as bytes, the same as their RingEdges'
    :func:`edges_key`: equal for two layers exactly when their edges are (an extruded part's layers).
    One pass for all the sets (the straight runs of each loop are its own)."""
    if not loop_sets:
        return []
    _, _, _, (_, _, x, y, _, _, _, _, counts) = _kept(points, offsets, [loop for loops in loop_sets for loop in loops])
    start = np.concatenate([[0], np.cumsum(counts)])
    keys, first = [], 0
    for loops in loop_sets:
        edges = slice(start[first], start[first + len(loops)])
        ring = np.repeat(np.arange(len(loops)), counts[first:first + len(loops)])
        keys.append((x[edges].tobytes(), y[edges].tobytes(), ring.tobytes()))
        first += len(loops)
    return keys


def edges_key(edges: RingEdges) -> tuple[bytes, bytes, bytes]:
    """Edges as bytes (starts x and y, ring of each edge): the key of what another layer measured of them."""
    return edges.x.tobytes(), edges.y.tobytes(), edges.ring.tobytes()


def ring_edges(points: np.ndarray, offsets: np.ndarray, loops) -> RingEdges:
    """Edges (float64) of the given loops (indices into offsets) of a layer's points ((p, 2) float, mm), without
    points within _STRAIGHT_MM of the straight line between their neighbours, each ring's from its
    lowest point in x then y round (:func:`_kept`)."""
    every, knots, knot_at, (first, second, x, y, vx, vy, inv, ring, _) = _kept(points, offsets, loops)
    return RingEdges(x=x, y=y, vx=vx, vy=vy, inv_len2=inv, ring=ring, first=first, second=second, knots=knots,
                     knot_point=every[knot_at])
