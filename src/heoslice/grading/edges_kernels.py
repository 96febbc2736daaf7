"""Compiled loops of :mod:`heoslice.grading.edges`: a point's distance to an edge, the walk that leaves a
ring's straight points out of its edges, the edges between the points kept, and whether rings turn one way
only."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from heoslice.jit import EXACT, JIT, f64, helper, i64, kernel


class EdgeArrays(NamedTuple):
    """Edges of closed rings as the kernels take them: edge i runs from (x[i], y[i]) by (vx[i], vy[i])
    ((n,) float64, mm); ``inv_len2`` is 1 / |v|^2 (0 for a zero-length edge)."""

    x: np.ndarray
    y: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    inv_len2: np.ndarray


def edge_arrays(edges) -> EdgeArrays:
    """The EdgeArrays of anything with those five arrays (a :class:`heoslice.grading.edges.RingEdges`)."""
    return EdgeArrays(f64(edges.x), f64(edges.y), f64(edges.vx), f64(edges.vy), f64(edges.inv_len2))


@helper(JIT)
def point_to_edge(px, py, ex, ey, vx, vy, inv):  # pragma: no cover - compiled
    """Distance (float64) from a point to the edge from (ex, ey) by (vx, vy), 1/|v|^2 = inv."""
    rx, ry = px - ex, py - ey
    t = min(max((rx * vx + ry * vy) * inv, 0.0), 1.0)
    return np.sqrt((rx - t * vx) ** 2 + (ry - t * vy) ** 2)


@helper(JIT)
def _off_segment(x, y, j, a, c):  # pragma: no cover - compiled
    """Distance (mm) from point j to the segment from point a to point c."""
    vx, vy = x[c] - x[a], y[c] - y[a]
    length2 = vx * vx + vy * vy
    return point_to_edge(x[j], y[j], x[a], y[a], vx, vy, 1.0 / length2 if length2 > 0.0 else 0.0)


@kernel(JIT)
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
    x, y = f64(x), f64(y)
    return _straight_runs(x, y, i64(size), float(tolerance), int(longest))


@kernel(EXACT)
def _convex_rings(vx, vy, inv_len2, ring, turn_limit):  # pragma: no cover - compiled
    """Whether every ring (runs of equal ``ring``, each edge followed by the next, the last by the first)
    turns one way only: the cross product of each edge with the next, where its sine exceeds ``turn_limit``,
    has one sign round the ring. Without fast-math: numpy's arithmetic, bit for bit."""
    n = len(ring)
    start = 0
    while start < n:
        end = start
        while end + 1 < n and ring[end + 1] == ring[start]:
            end += 1
        left = right = False
        for e in range(start, end + 1):
            f = e + 1 if e < end else start
            cross = vx[e] * vy[f] - vy[e] * vx[f]
            if abs(cross * np.sqrt(inv_len2[e] * inv_len2[f])) > turn_limit:
                left |= cross > 0.0
                right |= cross < 0.0
        if left and right:
            return False
        start = end + 1
    return True


def convex_turns(vx: np.ndarray, vy: np.ndarray, inv_len2: np.ndarray, ring: np.ndarray, turn_limit: float) -> bool:
    """:func:`_convex_rings` of edges ((n,) float64 vectors, mm, and 1 / |v|^2; ``ring`` (n,) int)."""
    return bool(_convex_rings(f64(vx), f64(vy), f64(inv_len2), i64(ring), float(turn_limit)))


@kernel(EXACT)
def _kept_edges(points, every, sizes, keep, order):  # pragma: no cover - compiled
    """The edges between the kept points of rings (:func:`straight_runs`' ``keep`` and ``order`` of the
    rings' points ``every``, indices into ``points`` (p, 2) mm, ring k the next sizes[k]): per ring its
    kept points in walk order, each edge from one to the next round the ring. Returns (first, second: the
    edges' end points in ``points``; x, y, vx, vy, inv_len2 as :class:`heoslice.grading.edges.RingEdges`;
    ring; counts: kept points per ring). Without fast-math: numpy's arithmetic, bit for bit."""
    kept = 0
    for n in range(len(order)):
        kept += keep[order[n]]
    first, second, ring = np.empty(kept, dtype=np.int64), np.empty(kept, dtype=np.int64), np.empty(kept, np.int64)
    counts = np.zeros(len(sizes), dtype=np.int64)
    n = edge = 0
    for k in range(len(sizes)):
        start = edge
        for _ in range(sizes[k]):
            if keep[order[n]]:
                first[edge], ring[edge] = every[order[n]], k
                edge += 1
            n += 1
        counts[k] = edge - start
        for e in range(start, edge):
            second[e] = first[e + 1] if e + 1 < edge else first[start]
    x, y = np.empty(kept), np.empty(kept)
    vx, vy, inv = np.empty(kept), np.empty(kept), np.empty(kept)
    for e in range(kept):
        x[e], y[e] = points[first[e], 0], points[first[e], 1]
        vx[e], vy[e] = points[second[e], 0] - x[e], points[second[e], 1] - y[e]
        length2 = vx[e] * vx[e] + vy[e] * vy[e]
        inv[e] = 1.0 / length2 if length2 > 0 else 0.0
    return first, second, x, y, vx, vy, inv, ring, counts


def kept_edges(points: np.ndarray, every: np.ndarray, sizes: np.ndarray, keep: np.ndarray, order: np.ndarray
               ) -> tuple:
    """:func:`_kept_edges` of a layer's points ((p, 2) float64, mm) and the rings' points, sizes and
    :func:`straight_runs` walk."""
    return _kept_edges(f64(points), i64(every), i64(sizes), np.ascontiguousarray(keep, dtype=np.bool_), i64(order))
