"""Compiled kernels of :mod:`heoslice.material.surface`: building a bounding-volume hierarchy and querying it.

The hierarchy is a binary tree of axis-aligned boxes over triangles (:class:`Hierarchy`).
A query walks it nearest box first and skips every box farther than the nearest
triangle found so far: the distance from a point to a box that contains a set of
triangles is a lower bound of the distance to each of them, so a skipped box cannot
hold a nearer triangle and the result is the exact minimum over all triangles.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from heoslice.jit import EXACT, helper, kernel

#: Triangles per leaf at most.
LEAF_SIZE = 8
#: Depth of the traversal stack; a tree built by halving has depth about log2(m / LEAF_SIZE) + 1.
STACK_DEPTH = 128


class Hierarchy(NamedTuple):
    """A bounding-volume hierarchy over triangles.

    low, high (k, 3) float64 mm: each node's box; left, right (k,) int64: children (-1
    for a leaf); first, count (k,) int64: a leaf's triangles order[first:first + count];
    corners (m, 3, 3) float64 mm: the triangles in leaf order (node 0 is the root);
    centre (m, 3) float64 mm, radius (m,) float64 mm: a sphere around each triangle
    (its corners' mean and the largest corner distance from it).
    """

    low: np.ndarray
    high: np.ndarray
    left: np.ndarray
    right: np.ndarray
    first: np.ndarray
    count: np.ndarray
    corners: np.ndarray
    centre: np.ndarray
    radius: np.ndarray


@kernel(EXACT)
def build_nodes(centroid: np.ndarray, tri_low: np.ndarray, tri_high: np.ndarray, leaf_size: int):  # pragma: no cover
    """Split triangles at the median centroid along their boxes' longest axis until leaves hold <= leaf_size.

    centroid, tri_low, tri_high (m, 3): each triangle's centroid and box. Returns (order (m,),
    low, high, left, right, first, count) as in :class:`Hierarchy`.
    """
    m = centroid.shape[0]
    capacity = 2 * m + 1  # a binary tree with at most m leaves
    low = np.empty((capacity, 3))
    high = np.empty((capacity, 3))
    left = np.full(capacity, -1, np.int64)
    right = np.full(capacity, -1, np.int64)
    first = np.zeros(capacity, np.int64)
    count = np.zeros(capacity, np.int64)
    order = np.arange(m)
    pending = np.empty(capacity, np.int64)
    pending[0] = 0
    first[0], count[0] = 0, m
    todo, nodes = 1, 1
    while todo > 0:
        todo -= 1
        node = pending[todo]
        start, size = first[node], count[node]
        for axis in range(3):
            low[node, axis] = np.inf
            high[node, axis] = -np.inf
        for i in range(start, start + size):
            t = order[i]
            for axis in range(3):
                low[node, axis] = min(low[node, axis], tri_low[t, axis])
                high[node, axis] = max(high[node, axis], tri_high[t, axis])
        if size <= leaf_size:
            continue
        spread_low = np.full(3, np.inf)
        spread_high = np.full(3, -np.inf)
        for i in range(start, start + size):
            for axis in range(3):
                spread_low[axis] = min(spread_low[axis], centroid[order[i], axis])
                spread_high[axis] = max(spread_high[axis], centroid[order[i], axis])
        axis = int(np.argmax(spread_high - spread_low))
        keys = centroid[order[start:start + size], axis]
        local = np.argsort(keys, kind="mergesort")
        order[start:start + size] = order[start:start + size][local]
        half = size // 2
        a, b = nodes, nodes + 1
        nodes += 2
        left[node], right[node] = a, b
        first[a], count[a] = start, half
        first[b], count[b] = start + half, size - half
        pending[todo] = a
        pending[todo + 1] = b
        todo += 2
    return order, low[:nodes], high[:nodes], left[:nodes], right[:nodes], first[:nodes], count[:nodes]


@helper(EXACT)
def _box_distance2(px, py, pz, low, high, node):  # pragma: no cover - compiled
    """Squared distance from a point to a node's box (0 inside)."""
    gx = max(low[node, 0] - px, 0.0, px - high[node, 0])
    gy = max(low[node, 1] - py, 0.0, py - high[node, 1])
    gz = max(low[node, 2] - pz, 0.0, pz - high[node, 2])
    return gx * gx + gy * gy + gz * gz


@helper(EXACT)
def _segment_distance2(px, py, pz, ax, ay, az, bx, by, bz):  # pragma: no cover - compiled
    """Squared distance from a point to the segment a-b (a point when a == b)."""
    ex, ey, ez = bx - ax, by - ay, bz - az
    length2 = ex * ex + ey * ey + ez * ez
    t = 0.0
    if length2 > 0.0:
        t = ((px - ax) * ex + (py - ay) * ey + (pz - az) * ez) / length2
        t = min(max(t, 0.0), 1.0)
    gx, gy, gz = px - (ax + t * ex), py - (ay + t * ey), pz - (az + t * ez)
    return gx * gx + gy * gy + gz * gz


@helper(EXACT, inline=False)
def triangle_distance2(px, py, pz, tri):  # pragma: no cover - compiled
    """Squared distance from a point to a triangle (3, 3): Ericson's region test (Real-Time Collision
    Detection, 5.1.5); a degenerate triangle is measured as its three edges."""
    ax, ay, az = tri[0, 0], tri[0, 1], tri[0, 2]
    abx, aby, abz = tri[1, 0] - ax, tri[1, 1] - ay, tri[1, 2] - az
    acx, acy, acz = tri[2, 0] - ax, tri[2, 1] - ay, tri[2, 2] - az
    nx, ny, nz = aby * acz - abz * acy, abz * acx - abx * acz, abx * acy - aby * acx
    scale = (abx * abx + aby * aby + abz * abz) * (acx * acx + acy * acy + acz * acz)
    if not (nx * nx + ny * ny + nz * nz) > 1e-24 * scale:
        d = _segment_distance2(px, py, pz, ax, ay, az, tri[1, 0], tri[1, 1], tri[1, 2])
        d = min(d, _segment_distance2(px, py, pz, tri[1, 0], tri[1, 1], tri[1, 2], tri[2, 0], tri[2, 1], tri[2, 2]))
        return min(d, _segment_distance2(px, py, pz, tri[2, 0], tri[2, 1], tri[2, 2], ax, ay, az))
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    s, t = 0.0, 0.0
    if d1 <= 0.0 and d2 <= 0.0:
        s, t = 0.0, 0.0
    else:
        abab = abx * abx + aby * aby + abz * abz
        abac = abx * acx + aby * acy + abz * acz
        acac = acx * acx + acy * acy + acz * acz
        d3, d4 = d1 - abab, d2 - abac
        d5, d6 = d1 - abac, d2 - acac
        va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
        if d3 >= 0.0 and d4 <= d3:
            s, t = 1.0, 0.0
        elif d6 >= 0.0 and d5 <= d6:
            s, t = 0.0, 1.0
        elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
            s, t = d1 / (d1 - d3), 0.0
        elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
            s, t = 0.0, d2 / (d2 - d6)
        elif va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
            w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
            s, t = 1.0 - w, w
        else:
            denominator = va + vb + vc
            s, t = vb / denominator, vc / denominator
    gx = apx - s * abx - t * acx
    gy = apy - s * aby - t * acy
    gz = apz - s * abz - t * acz
    return gx * gx + gy * gy + gz * gz


@kernel(EXACT)
def nearest_distances(points: np.ndarray, tree: Hierarchy, out: np.ndarray) -> np.ndarray:  # pragma: no cover
    """Exact distance (n,) mm from each point (n, 3) to the nearest triangle of ``tree``, into ``out`` (returned).

    Depth first, the nearer child first; a node is skipped when its box is no nearer than
    the best triangle so far (the box bound), so every triangle not measured is no nearer.
    The search starts from the distance to the previous point's nearest triangle (an upper
    bound that is tight when neighbouring points come one after the other). In a leaf, a
    triangle whose sphere is no nearer than the best (|p - centre| - radius >= best) is not
    measured: the sphere holds the triangle, so that is a lower bound too.
    """
    stack = np.empty(STACK_DEPTH, np.int64)
    bound = np.empty(STACK_DEPTH)
    nearest = 0
    for i in range(points.shape[0]):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        best = triangle_distance2(px, py, pz, tree.corners[nearest])
        reach = np.sqrt(best)
        stack[0] = 0
        bound[0] = _box_distance2(px, py, pz, tree.low, tree.high, 0)
        top = 1
        while top > 0:
            top -= 1
            node = stack[top]
            if bound[top] >= best:
                continue
            a = tree.left[node]
            if a < 0:
                for j in range(tree.first[node], tree.first[node] + tree.count[node]):
                    cx, cy, cz = px - tree.centre[j, 0], py - tree.centre[j, 1], pz - tree.centre[j, 2]
                    outside = reach + tree.radius[j]
                    if cx * cx + cy * cy + cz * cz >= outside * outside:
                        continue
                    d = triangle_distance2(px, py, pz, tree.corners[j])
                    if d < best:
                        best, nearest = d, j
                        reach = np.sqrt(best)
                continue
            b = tree.right[node]
            da = _box_distance2(px, py, pz, tree.low, tree.high, a)
            db = _box_distance2(px, py, pz, tree.low, tree.high, b)
            if da > db:
                a, b, da, db = b, a, db, da
            if db < best:
                stack[top], bound[top] = b, db
                top += 1
            if da < best:
                stack[top], bound[top] = a, da
                top += 1
        out[i] = np.sqrt(best)
    return out
