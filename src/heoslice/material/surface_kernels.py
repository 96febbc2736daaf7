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
    (its corners' mean and the largest corner distance from it); planes (m, 4) float64: each
    triangle's plane, unit normal n and offset n . a (zeros for a degenerate triangle).
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
    planes: np.ndarray


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
def _beyond_plane(px, py, pz, planes, radius, j, reach):  # pragma: no cover - compiled
    """Whether the point is farther than ``reach`` (mm) from triangle j's plane, so from the triangle (a lower bound
    that holds where the sphere around it does not: inside a closed surface, most triangles' spheres are as near as
    the nearest triangle). The rounding of the normal (planes holds none for slivers, whose normal it may tilt
    more than 1e-10) moves the triangle off its plane by at most 1e-10 of its size (twice ``radius[j]``), and the
    height's own rounding is far below 1e-10 of the coordinates: both are added to ``reach``."""
    height = abs(planes[j, 0] * px + planes[j, 1] * py + planes[j, 2] * pz - planes[j, 3])
    slack = 1e-10 * (2.0 * radius[j] + abs(px) + abs(py) + abs(pz) + abs(planes[j, 3]))
    return height > reach * (1.0 + 1e-12) + slack


@helper(EXACT)
def _segment_offset(px, py, pz, ax, ay, az, bx, by, bz):  # pragma: no cover - compiled
    """The point minus its nearest point on the segment a-b (a point when a == b): (gx, gy, gz)."""
    ex, ey, ez = bx - ax, by - ay, bz - az
    length2 = ex * ex + ey * ey + ez * ez
    t = 0.0
    if length2 > 0.0:
        t = ((px - ax) * ex + (py - ay) * ey + (pz - az) * ez) / length2
        t = min(max(t, 0.0), 1.0)
    return px - (ax + t * ex), py - (ay + t * ey), pz - (az + t * ez)


@helper(EXACT)
def _nearer(best, gx, gy, gz):  # pragma: no cover - compiled
    """Of two offsets (best: (gx, gy, gz)), the shorter (the first on a tie)."""
    if gx * gx + gy * gy + gz * gz < best[0] * best[0] + best[1] * best[1] + best[2] * best[2]:
        return gx, gy, gz
    return best


@helper(EXACT, inline=False)
def triangle_distance2(px, py, pz, tri):  # pragma: no cover - compiled
    """Squared distance from a point to a triangle (3, 3) (:func:`triangle_offset`)."""
    gx, gy, gz = triangle_offset(px, py, pz, tri)
    return gx * gx + gy * gy + gz * gz


@helper(EXACT)
def triangle_offset(px, py, pz, tri):  # pragma: no cover - compiled
    """The point minus its nearest point on a triangle (3, 3), (gx, gy, gz): Ericson's region test (Real-Time
    Collision Detection, 5.1.5); a degenerate triangle is measured as its three edges."""
    ax, ay, az = tri[0, 0], tri[0, 1], tri[0, 2]
    abx, aby, abz = tri[1, 0] - ax, tri[1, 1] - ay, tri[1, 2] - az
    acx, acy, acz = tri[2, 0] - ax, tri[2, 1] - ay, tri[2, 2] - az
    nx, ny, nz = aby * acz - abz * acy, abz * acx - abx * acz, abx * acy - aby * acx
    scale = (abx * abx + aby * aby + abz * abz) * (acx * acx + acy * acy + acz * acz)
    if not (nx * nx + ny * ny + nz * nz) > 1e-24 * scale:
        best = _segment_offset(px, py, pz, ax, ay, az, tri[1, 0], tri[1, 1], tri[1, 2])
        gx, gy, gz = _segment_offset(px, py, pz, tri[1, 0], tri[1, 1], tri[1, 2], tri[2, 0], tri[2, 1], tri[2, 2])
        best = _nearer(best, gx, gy, gz)
        gx, gy, gz = _segment_offset(px, py, pz, tri[2, 0], tri[2, 1], tri[2, 2], ax, ay, az)
        return _nearer(best, gx, gy, gz)
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
    return apx - s * abx - t * acx, apy - s * aby - t * acy, apz - s * abz - t * acz


@helper(EXACT, inline=False)
def nearest_triangle(px, py, pz, tree, start, stack, bound):  # pragma: no cover - compiled
    """(squared distance, index) of the triangle of ``tree`` nearest the point, searched from triangle
    ``start`` (its distance the first bound; ``stack``, ``bound``: STACK_DEPTH scratch arrays).

    Depth first, the nearer child first; a node is skipped when its box is no nearer than
    the best triangle so far (the box bound), so every triangle not measured is no nearer.
    In a leaf, a triangle whose sphere is no nearer than the best (|p - centre| - radius >= best)
    is not measured: the sphere holds the triangle, so that is a lower bound too; nor one whose plane is
    farther than the best (:func:`_beyond_plane`).
    """
    nearest = start
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
                if cx * cx + cy * cy + cz * cz >= outside * outside or \
                        _beyond_plane(px, py, pz, tree.planes, tree.radius, j, reach):
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
    return best, nearest


@kernel(EXACT)
def nearest_distances(points: np.ndarray, tree: Hierarchy, out: np.ndarray) -> np.ndarray:  # pragma: no cover
    """Exact distance (n,) mm from each point (n, 3) to the nearest triangle of ``tree`` (:func:`nearest_triangle`),
    into ``out`` (returned). Each search starts from the previous point's nearest triangle, an upper bound that is
    tight when neighbouring points come one after the other."""
    stack = np.empty(STACK_DEPTH, np.int64)
    bound = np.empty(STACK_DEPTH)
    nearest = 0
    for i in range(points.shape[0]):
        best, nearest = nearest_triangle(points[i, 0], points[i, 1], points[i, 2], tree, nearest, stack, bound)
        out[i] = np.sqrt(best)
    return out


@helper(EXACT, inline=False)
def triangles_near(px, py, pz, reach, tree, stack, found):  # pragma: no cover - compiled
    """How many triangles of ``tree`` lie within ``reach`` of the point (their indices into found[:count]), or -1
    when more than len(found) do."""
    count = 0
    stack[0] = 0
    top = 1
    reach2 = reach * reach
    while top > 0:
        top -= 1
        node = stack[top]
        if _box_distance2(px, py, pz, tree.low, tree.high, node) > reach2:
            continue
        a = tree.left[node]
        if a >= 0:
            stack[top] = a
            stack[top + 1] = tree.right[node]
            top += 2
            continue
        for j in range(tree.first[node], tree.first[node] + tree.count[node]):
            if not _beyond_plane(px, py, pz, tree.planes, tree.radius, j, reach) and \
                    triangle_distance2(px, py, pz, tree.corners[j]) <= reach2:
                if count == found.shape[0]:
                    return -1
                found[count] = j
                count += 1
    return count
