"""The topology's compiled kernels: the faces' edges grouped by undirected edge, and connected shells by
union-find over the faces that share one (numba source, compiled at install: :mod:`heoslice.jit`)."""

from __future__ import annotations

import numpy as np

from heoslice.jit import EXACT, kernel


@kernel(EXACT)
def _lowest_connected(a, b, count):  # pragma: no cover - compiled
    """(count,) int: the lowest face index connected to each face, faces a[i] and b[i] ((n,) int) being
    connected. Union-find whose root is always a component's lowest index, with path halving."""
    parent = np.arange(count)
    for i in range(a.shape[0]):
        x, y = a[i], b[i]
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        while parent[y] != y:
            parent[y] = parent[parent[y]]
            y = parent[y]
        if x < y:
            parent[y] = x
        elif y < x:
            parent[x] = y
    for face in range(count):
        parent[face] = parent[parent[face]]  # roots precede their members: one step reaches the root
    return parent


#: Edges at one vertex past which they are sorted by a merge sort rather than by insertion (a fan's hub).
_INSERTION_AT_MOST = 32


@kernel(EXACT)
def _edge_runs(faces, vertices):  # pragma: no cover - compiled
    """(order (3m,), starts (e,), forward (3m,) bool) of the edges of faces ((m, 3) int, indices below
    ``vertices``; edge k of face f, entry 3f + k, runs from corner k to corner k + 1): the entries sorted by
    undirected edge (lower vertex, then higher), each edge's in index order. A counting sort by the lower
    vertex, then each vertex's entries sorted stably by their higher vertex: by insertion when they are few
    (a mesh's usual handful), else by a merge sort (the hub of a fan of many triangles)."""
    count = 3 * faces.shape[0]
    bucket = np.zeros(vertices + 1, dtype=np.int64)
    for f in range(faces.shape[0]):
        for k in range(3):
            a, b = faces[f, k], faces[f, (k + 1) % 3]
            bucket[min(a, b) + 1] += 1
    for v in range(vertices):
        bucket[v + 1] += bucket[v]
    cursor = bucket[:-1].copy()
    order = np.empty(count, dtype=np.int64)
    higher = np.empty(count, dtype=np.int64)
    forward = np.empty(count, dtype=np.bool_)
    for f in range(faces.shape[0]):
        for k in range(3):
            a, b = faces[f, k], faces[f, (k + 1) % 3]
            low = min(a, b)
            at = cursor[low]
            cursor[low] += 1
            order[at], higher[at], forward[at] = 3 * f + k, max(a, b), a < b
    starts = np.empty(count, dtype=np.int64)
    runs = 0
    for v in range(vertices):
        first, stop = bucket[v], bucket[v + 1]
        if stop - first > _INSERTION_AT_MOST:
            ranked = first + np.argsort(higher[first:stop], kind="mergesort")
            order[first:stop], higher[first:stop], forward[first:stop] = order[ranked], higher[ranked], forward[ranked]
        else:
            for i in range(first + 1, stop):
                entry, high, ahead = order[i], higher[i], forward[i]
                j = i - 1
                while j >= first and higher[j] > high:
                    order[j + 1], higher[j + 1], forward[j + 1] = order[j], higher[j], forward[j]
                    j -= 1
                order[j + 1], higher[j + 1], forward[j + 1] = entry, high, ahead
        for i in range(first, stop):
            if i == first or higher[i] != higher[i - 1]:
                starts[runs] = i
                runs += 1
    return order, starts[:runs].copy(), forward
