"""Compiled nearest-edge search of :mod:`heoslice.grading.search`: a bounding-box hierarchy over a ring set's
edges, the chunks within each group's radius, the nearest edge to each point, and the least distance
between two edge sets."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from heoslice.grading.edges_kernels import EdgeArrays, edge_arrays, point_to_edge
from heoslice.jit import JIT, f32, f64, helper, kernel

#: Children per node of the edge hierarchy (:func:`edge_tree`).
FAN = 8


#: Candidate (group, chunk) pairs gathered at most at once by :func:`_nearest_in_batches` (8 bytes each; the
#: candidate list holds at least 16 a group).
_PAIRS = 1 << 23


class EdgeTree(NamedTuple):
    """A ring set's edge hierarchy (:func:`edge_tree`), as the kernels take it."""

    boxes: np.ndarray
    level_start: np.ndarray
    capsules: np.ndarray


@kernel(JIT)
def _candidates(cx, cy, radius, boxes, level_start):  # pragma: no cover - compiled
    """CSR (start (g+1,), chunk (m,)) of the chunks (runs of FAN consecutive edges, the hierarchy's
    level 1) whose bounding box comes within radius[g] of each point (cx[g], cy[g]).

    ``boxes`` are the bounding boxes of a hierarchy (:func:`edge_tree`): level 0 the edges,
    each level above groups FAN consecutive nodes of the one below; a node whose box is
    farther than the radius is skipped with everything under it. Collected into room for 16
    a group, and again into as much room as they need where that was too little (an array
    grown inside the walk would take a reference count at every step of it).
    """
    found = np.empty(max(16 * len(cx), 16), dtype=np.int64)
    start = _collect_candidates(cx, cy, radius, boxes, level_start, found)
    if start[-1] > len(found):
        found = np.empty(start[-1], dtype=np.int64)
        start = _collect_candidates(cx, cy, radius, boxes, level_start, found)
    return start, found[:start[-1]]


@helper(JIT, inline=False)
def _collect_candidates(cx, cy, radius, boxes, level_start, found):  # pragma: no cover - compiled
    """The walk of :func:`_candidates`: start (g+1,) of every group's chunks, counted in full, and the chunks
    themselves written into ``found`` as far as it holds them."""
    groups = len(cx)
    levels = len(level_start) - 1
    start = np.zeros(groups + 1, dtype=np.int64)
    stack = np.empty((64 * levels + FAN * levels + 64, 2), dtype=np.int64)
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
                for child in range(node * FAN, min((node + 1) * FAN, below)):
                    stack[top, 0], stack[top, 1] = level - 1, child
                    top += 1
                continue
            if n < len(found):
                found[n] = node
            n += 1
        start[g + 1] = n
    return start


@helper(JIT)
def _squared(rx, ry, vx, vy, inv):  # pragma: no cover - compiled
    """Squared distance from the offset (rx, ry) (from an edge's first end) to the edge (vx, vy), 1/|v|^2 = inv;
    float32 in, float32 out, written with selects so that the loops calling it vectorise."""
    t = (rx * vx + ry * vy) * inv
    t = np.float32(0.0) if t < np.float32(0.0) else t
    t = np.float32(1.0) if t > np.float32(1.0) else t
    rx -= t * vx
    ry -= t * vy
    return rx * rx + ry * ry


#: Up to this many values :func:`_ascending` sorts by insertion, as numba's argsort does (stable there).
_INSERTION_SORT = 15


@helper(JIT)
def _ascending(values, count, order):  # pragma: no cover - compiled
    """The indices of ``values[:count]`` in ascending order (NaN last), into ``order[:count]``, in the order
    numba's np.argsort gives: as it does, by insertion up to _INSERTION_SORT values (equal values keep their
    order), else by np.argsort itself. Whole arrays and a count, not views: no reference counts per call."""
    if count > _INSERTION_SORT:
        _argsorted_into(values, count, order)
        return
    for i in range(count):
        j = i
        while j > 0 and (values[i] < values[order[j - 1]]
                         or (np.isnan(values[order[j - 1]]) and not np.isnan(values[i]))):
            order[j] = order[j - 1]
            j -= 1
        order[j] = i


@helper(JIT, inline=False)
def _argsorted_into(values, count, order):  # pragma: no cover - compiled
    """np.argsort of ``values[:count]`` into ``order[:count]``: a function of its own, so that its slices take
    reference counts only where it is called, not for every group."""
    order[:count] = np.argsort(values[:count])


@helper(JIT)
def _reach(ox, oy):  # pragma: no cover - compiled
    """The points' greatest distance (float64 mm) from their group's centre, offsets ox, oy ((k,) float32)."""
    reach = 0.0
    for k in range(len(ox)):
        reach = max(reach, np.sqrt(np.float64(ox[k]) ** 2 + np.float64(oy[k]) ** 2))
    return reach


@helper(JIT)
def _most_chunks(start):  # pragma: no cover - compiled
    """The most candidate chunks any group has (CSR ``start``, (g + 1,) int, of :func:`_candidates`)."""
    widest = 0
    for g in range(len(start) - 1):
        widest = max(widest, start[g + 1] - start[g])
    return widest


@helper(JIT, inline=False)
def _nearest_in_chunks(cx, cy, ox, oy, candidates, capsules, edge_set):  # pragma: no cover - compiled
    """The nearest edge of group g's candidate chunks to each point (cx[g] + ox[k], cy[g] + oy[k]):
    (g, k) int32, -1 where none; of equally near edges, the first visited.

    Chunks are visited nearest first by a lower bound of their distance from the group's
    centre (their capsule's: chord distance less radius); a chunk is skipped when no
    point's capsule distance beats its best so far, and the rest once even the farthest
    point (``reach`` from the centre) cannot be nearer to them than its best; within a chunk
    after the first, so is an edge farther from the centre than the points' worst best plus
    ``reach`` (and 1e-4 mm for float32: the same edges either way). Compared in
    float32 from each group's centre (a near tie may pick an edge ~1e-5 mm farther);
    selects, not branches, so the loops over points vectorise.
    """
    start, chunk = candidates
    ex, ey, evx, evy, einv = edge_set
    groups, points, edges = len(cx), len(ox), len(ex)
    reach = _reach(ox, oy)
    best = np.full((groups, points), np.inf, dtype=np.float32)
    which = np.full((groups, points), -1, dtype=np.int32)
    near = np.empty(points, dtype=np.float32)
    # the points' worst best so far is the greatest of ``near``: non-negative float32s order as their bits do as
    # int32s, so an integer reduction finds it, and vectorises (a float max does not, NaN unexcluded)
    near_bits = near.view(np.int32)
    greatest = np.empty(1, dtype=np.float32)
    greatest_bits = greatest.view(np.int32)
    widest = _most_chunks(start)
    bounds = np.empty(widest)
    ranks = np.empty(widest, dtype=np.int64)
    for g in range(groups):
        first, count = start[g], start[g + 1] - start[g]
        for n in range(count):
            c = chunk[first + n]
            bounds[n] = point_to_edge(cx[g], cy[g], capsules[c, 0], capsules[c, 1], capsules[c, 2], capsules[c, 3],
                                       capsules[c, 4]) - capsules[c, 5]
        _ascending(bounds, count, ranks)
        for k in range(points):
            near[k] = np.inf
        farthest = np.inf
        for m in range(count):
            n = ranks[m]
            if bounds[n] - reach > farthest:
                break
            c = chunk[first + n]
            bx, by = np.float32(cx[g] - capsules[c, 0]), np.float32(cy[g] - capsules[c, 1])
            vx, vy = np.float32(capsules[c, 2]), np.float32(capsules[c, 3])
            inv, radius = np.float32(capsules[c, 4]), np.float32(capsules[c, 5])
            if farthest < np.inf:  # every point needs the first chunk visited
                needed = 0
                for k in range(points):
                    gap = np.sqrt(_squared(bx + ox[k], by + oy[k], vx, vy, inv)) - radius
                    needed += gap < near[k]
                if not needed:
                    continue
            for e in range(c * FAN, min(c * FAN + FAN, edges)):
                if farthest < np.inf and (point_to_edge(cx[g], cy[g], ex[e], ey[e], evx[e], evy[e], einv[e]) - reach
                                          > farthest + 1e-4):
                    continue  # no point comes nearer to this edge than to its best so far
                bx, by = np.float32(cx[g] - ex[e]), np.float32(cy[g] - ey[e])
                vx, vy, inv = np.float32(evx[e]), np.float32(evy[e]), np.float32(einv[e])
                edge = np.int32(e)
                for k in range(points):
                    d2 = _squared(bx + ox[k], by + oy[k], vx, vy, inv)
                    closer = d2 < best[g, k]
                    which[g, k] = edge if closer else which[g, k]
                    best[g, k] = d2 if closer else best[g, k]
            for k in range(points):
                near[k] = np.sqrt(best[g, k])
            top = np.int32(0)
            for k in range(points):
                top = max(top, near_bits[k])
            greatest_bits[0] = top
            farthest = np.float64(greatest[0])
    return which


@helper(JIT, inline=False)
def _nearest_squared(cx, cy, ox, oy, candidates, edge_set):  # pragma: no cover - compiled
    """The squared distance from each point (cx[g] + ox[k], cy[g] + oy[k]) to the nearest edge of group g's
    candidate chunks ((g, k) float32, inf where none): the least of :func:`_squared` over those edges.

    Only an edge that can be some point's nearest is measured at the points. Every point is within D +
    ``reach`` of the edge nearest the centre (D its distance from the centre), so its own nearest edge is
    no farther; an edge more than D + 2 ``reach`` (and 1e-4 mm for float32) from the centre is farther
    than that from every point, so it is nobody's nearest (the same least either way). That leaves a few
    of a chunk's edges, each measured at every point in one pass, which vectorises."""
    start, chunk = candidates
    ex, ey, evx, evy, einv = edge_set
    groups, points, edges = len(cx), len(ox), len(ex)
    reach = _reach(ox, oy)
    best = np.full((groups, points), np.inf, dtype=np.float32)
    widest = _most_chunks(start)
    apart = np.empty(widest * FAN)
    measured = np.empty(widest * FAN, dtype=np.int64)
    for g in range(groups):
        count = 0
        nearest = np.inf
        for m in range(start[g], start[g + 1]):
            c = chunk[m]
            for e in range(c * FAN, min(c * FAN + FAN, edges)):
                apart[count] = point_to_edge(cx[g], cy[g], ex[e], ey[e], evx[e], evy[e], einv[e])
                measured[count] = e
                if apart[count] < nearest:  # a NaN is never the nearest
                    nearest = apart[count]
                count += 1
        limit = nearest + 2.0 * reach + 1e-4
        for n in range(count):
            if not apart[n] <= limit:  # farther, or not a number (a NaN never wins either way)
                continue
            e = measured[n]
            bx, by = np.float32(cx[g] - ex[e]), np.float32(cy[g] - ey[e])
            vx, vy, inv = np.float32(evx[e]), np.float32(evy[e]), np.float32(einv[e])
            for k in range(points):
                d2 = _squared(bx + ox[k], by + oy[k], vx, vy, inv)
                best[g, k] = d2 if d2 < best[g, k] else best[g, k]
    return best


@helper(JIT, inline=False)
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
    return min(point_to_edge(a[0], a[1], b[0], b[1], b[2], b[3], b[4]),
               point_to_edge(ax1, ay1, b[0], b[1], b[2], b[3], b[4]),
               point_to_edge(b[0], b[1], a[0], a[1], a[2], a[3], a[4]),
               point_to_edge(bx1, by1, a[0], a[1], a[2], a[3], a[4]))


@kernel(JIT)
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
            for e in range(i * FAN, min(i * FAN + FAN, na)):
                for f in range(j * FAN, min(j * FAN + FAN, nb)):
                    best = min(best, point_to_edge(a[e, 0], a[e, 1], b[f, 0], b[f, 1], b[f, 2], b[f, 3], b[f, 4]),
                               point_to_edge(b[f, 0], b[f, 1], a[e, 0], a[e, 1], a[e, 2], a[e, 3], a[e, 4]))
    return best


@helper(JIT, inline=False)
def _nearest_starts(cx, cy, capsules):  # pragma: no cover - compiled
    """Distance from each point (cx[g], cy[g]) to the nearest first point of a chunk (its capsule's chord
    start, a vertex of the rings), mm: an upper bound of its distance to the edges."""
    distance = np.empty(len(cx))
    for g in range(len(cx)):
        best = np.inf
        for c in range(len(capsules)):
            rx, ry = cx[g] - capsules[c, 0], cy[g] - capsules[c, 1]
            best = min(best, rx * rx + ry * ry)
        distance[g] = np.sqrt(best)
    return distance


def edge_tree(x0: np.ndarray, y0: np.ndarray, x1: np.ndarray, y1: np.ndarray):
    """Bounding-box hierarchy of edges from (x0, y0) to (x1, y1) ((n,) float, mm), given in ring order
    so that consecutive edges are near each other: (boxes (total, 4) [xmin, ymin, xmax, ymax],
    level_start (levels + 1,), capsules); level 0 the edges, each level above one box per
    FAN boxes below, up to a top level of at most FAN boxes (level 1 always: the chunks of
    :func:`_candidates`). ``capsules`` ((chunks, 6): x, y, vx, vy, 1/|v|^2, radius, mm) hold
    each chunk's edges within ``radius`` of the chord from its first edge's start to its
    last edge's end (a chunk of a smooth ring: within its sagitta), so the chord's distance
    less the radius is a lower bound of the chunk's (:func:`_nearest_in_chunks`)."""
    x0, y0, x1, y1 = f64(x0), f64(y0), f64(x1), f64(y1)
    sizes = [len(x0)]
    while len(sizes) == 1 or sizes[-1] > FAN:
        sizes.append(-(-sizes[-1] // FAN))
    level_start = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    return _tree_boxes(x0, y0, x1, y1, level_start), level_start, _chunk_capsules(x0, y0, x1, y1)


@kernel(JIT)
def _tree_boxes(x0, y0, x1, y1, level_start):  # pragma: no cover - compiled
    """(level_start[-1], 4) boxes of :func:`edge_tree`: the edges', then each level's over FAN below."""
    boxes = np.empty((level_start[-1], 4))
    for e in range(len(x0)):
        boxes[e, 0], boxes[e, 1] = min(x0[e], x1[e]), min(y0[e], y1[e])
        boxes[e, 2], boxes[e, 3] = max(x0[e], x1[e]), max(y0[e], y1[e])
    for level in range(1, len(level_start) - 1):
        below, first = level_start[level - 1], level_start[level]
        for node in range(level_start[level + 1] - first):
            lo, hi = below + node * FAN, min(below + node * FAN + FAN, first)
            box = boxes[first + node]
            box[0], box[1], box[2], box[3] = boxes[lo, 0], boxes[lo, 1], boxes[lo, 2], boxes[lo, 3]
            for child in range(lo + 1, hi):
                box[0], box[1] = min(box[0], boxes[child, 0]), min(box[1], boxes[child, 1])
                box[2], box[3] = max(box[2], boxes[child, 2]), max(box[3], boxes[child, 3])
    return boxes


@kernel(JIT)
def _chunk_capsules(x0, y0, x1, y1):  # pragma: no cover - compiled
    """(chunks, 6) per run of FAN consecutive edges: its chord (start x, y, vector, 1/|v|^2, 0 if
    zero-length) and the largest distance of its edges' ends from the chord, widened by 1e-4 mm
    for float32 comparisons (see :func:`edge_tree`)."""
    count = len(x0)
    chunks = -(-count // FAN)
    out = np.empty((chunks, 6))
    for c in range(chunks):
        first, last = c * FAN, min(c * FAN + FAN, count) - 1
        ox, oy = x0[first], y0[first]
        vx, vy = x1[last] - ox, y1[last] - oy
        length2 = vx * vx + vy * vy
        inv = 1.0 / length2 if length2 > 0 else 0.0
        gap = 0.0
        for e in range(first, last + 1):
            for px, py in ((x0[e], y0[e]), (x1[e], y1[e])):
                gap = max(gap, point_to_edge(px, py, ox, oy, vx, vy, inv))
        out[c, 0], out[c, 1], out[c, 2], out[c, 3], out[c, 4] = ox, oy, vx, vy, inv
        out[c, 5] = gap * (1 + 1e-9) + 1e-4
    return out


@kernel(JIT)
def _nearest_in_batches(cx, cy, radius, ox, oy, tree, edges, track):  # pragma: no cover - compiled
    """:func:`_nearest_in_chunks` (with ``track``) or :func:`_nearest_squared` of groups' candidate chunks
    (:func:`_candidates`), a bounded number of groups at a time (groups deep inside a round part gather most
    of its chunks): at most _PAIRS pairs. (best (g, k) float32, or (0, 0) with ``track``; which (g, k) int32,
    or (0, 0) without.)"""
    groups, points = len(cx), len(ox)
    best = np.full((0, 0) if track else (groups, points), np.inf, dtype=np.float32)
    which = np.full((groups, points) if track else (0, 0), -1, dtype=np.int32)
    step = max(1, _PAIRS // max(16, len(tree.capsules)))  # _candidates sets aside 16 pairs a group at least
    for first in range(0, groups, step):
        last = min(first + step, groups)
        part_x, part_y = cx[first:last], cy[first:last]
        candidates = _candidates(part_x, part_y, radius[first:last], tree.boxes, tree.level_start)
        if track:
            which[first:last] = _nearest_in_chunks(part_x, part_y, ox, oy, candidates, tree.capsules, edges)
        else:
            best[first:last] = _nearest_squared(part_x, part_y, ox, oy, candidates, edges)
    return best, which


def nearest_in_groups(cx: np.ndarray, cy: np.ndarray, radius: np.ndarray, ox: np.ndarray, oy: np.ndarray,
                      edges: EdgeArrays, tree, track: bool = True) -> np.ndarray:
    """The points (cx[g] + ox[k], cy[g] + oy[k]) against the edges of the chunks within radius[g] of
    (cx[g], cy[g]) (every edge within the radius, and maybe a few beyond: exact wherever the
    radius holds each point's nearest edge): with ``track`` the nearest edge ((g, k) int32, -1
    where none), else the squared distance to it ((g, k) float32, mm^2; inf where none). Both in
    float32 from the group's centre (see :func:`_nearest_in_chunks` and :func:`_nearest_squared`).

    ``edges``: EdgeArrays (or RingEdges); ``tree`` is :func:`edge_tree` of the same edges.
    """
    best, which = _nearest_in_batches(f64(cx), f64(cy), f64(radius), f32(ox), f32(oy), EdgeTree(*tree),
                                      edge_arrays(edges), bool(track))
    return which if track else best


def edge_sets_apart(a: np.ndarray, tree_a, b: np.ndarray, tree_b, bound: float) -> float:
    """Least vertex-to-edge distance (mm) both ways between two edge sets ((n, 5) x, y, vx, vy, 1/|v|^2,
    each with its :func:`edge_tree`), given an upper bound ``bound`` of it (returned if nothing is closer):
    chunk pairs whose capsules cannot come that close are skipped (:func:`_chunks_apart`)."""
    capsules_a, capsules_b = tree_a[2], tree_b[2]
    centre_x = capsules_a[:, 0] + 0.5 * capsules_a[:, 2]
    centre_y = capsules_a[:, 1] + 0.5 * capsules_a[:, 3]
    reach = 0.5 * np.hypot(capsules_a[:, 2], capsules_a[:, 3]) + capsules_a[:, 5]
    start, candidate = _candidates(centre_x, centre_y, bound + reach, tree_b[0], tree_b[1])
    return float(_chunks_apart(start, candidate, capsules_a, capsules_b, f64(a),
                               f64(b), float(bound)))
