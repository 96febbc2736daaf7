"""The topology's compiled kernel: connected shells by union-find over the faces that share an edge (numba
source, compiled at install: :mod:`heoslice.jit`)."""

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
