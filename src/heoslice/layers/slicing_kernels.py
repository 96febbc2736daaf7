"""The slicing's compiled kernel: every (triangle, plane) crossing turned into a directed segment, grouped by
layer, in one pass (numba source, compiled at install: :mod:`heoslice.jit`).

Exact arithmetic (no fast-math): each crossing point is (v_high - v_low) t + v_low with
t = (plane - z_low) / (z_high - z_low) from the edge's lower-numbered vertex, so both triangles sharing an
edge get the same bits (the rule :mod:`heoslice.layers.slicing` describes).
"""

from __future__ import annotations

import numpy as np

from heoslice.jit import EXACT, helper, kernel


@helper(EXACT)
def _crossing(vertices, lone, other, plane):  # pragma: no cover - compiled
    """(lower vertex, higher vertex, t from the lower) of the edge (lone, other) crossing ``plane``."""
    low, high = (other, lone) if other < lone else (lone, other)
    z_low, z_high = vertices[low, 2], vertices[high, 2]
    return low, high, (plane - z_low) / (z_high - z_low)


@kernel(EXACT)
def _layer_segments(vertices, faces, z, first, stop):  # pragma: no cover - compiled
    """The segments of faces (m, 3) crossing planes z[first[f]:stop[f]] (see :func:`layer_segments`)."""
    layers = z.shape[0]
    n = np.int64(vertices.shape[0])
    span = n * n
    offsets = np.zeros(layers + 1, dtype=np.int64)
    for f in range(faces.shape[0]):  # a counting sort by layer: each layer's pairs in face order
        for layer in range(first[f], stop[f]):
            offsets[layer + 1] += 1
    for layer in range(layers):
        offsets[layer + 1] += offsets[layer]
    count = offsets[layers]
    at = offsets[:-1].copy()
    pair_layer = np.empty(count, dtype=np.int64)
    pair_face = np.empty(count, dtype=np.int64)
    start = np.empty((count, 2), dtype=np.float64)
    start_key = np.empty(count, dtype=np.int64)
    end_key = np.empty(count, dtype=np.int64)
    start_edge = np.empty((count, 2), dtype=np.int64)
    end_edge = np.empty((count, 2), dtype=np.int64)
    start_t = np.empty(count, dtype=np.float64)
    end_t = np.empty(count, dtype=np.float64)
    for f in range(faces.shape[0]):
        corners = faces[f]
        for layer in range(first[f], stop[f]):
            plane = z[layer]
            b0, b1, b2 = vertices[corners[0], 2] < plane, vertices[corners[1], 2] < plane, vertices[corners[2], 2] < plane
            lone_below = b0 ^ b1 ^ b2
            lone = 2 if b0 == b1 else (1 if b0 == b2 else 0)
            after, before = (lone + 1) % 3, (lone + 2) % 3
            # right-hand rule: with the lone vertex below, from edge (before, lone) to edge (lone, after)
            start_other, end_other = (before, after) if lone_below else (after, before)
            i = at[layer]
            at[layer] += 1
            low, high, t = _crossing(vertices, corners[lone], corners[start_other], plane)
            start_edge[i, 0], start_edge[i, 1], start_t[i] = low, high, t
            for axis in range(2):
                start[i, axis] = (vertices[high, axis] - vertices[low, axis]) * t + vertices[low, axis]
            start_key[i] = layer * span + low * n + high
            low, high, t = _crossing(vertices, corners[lone], corners[end_other], plane)
            end_edge[i, 0], end_edge[i, 1], end_t[i] = low, high, t
            end_key[i] = layer * span + low * n + high
            pair_layer[i] = layer
            pair_face[i] = f
    return offsets, pair_layer, pair_face, start, start_key, end_key, start_edge, end_edge, start_t, end_t


def layer_segments(vertices: np.ndarray, faces: np.ndarray, z: np.ndarray, first: np.ndarray, stop: np.ndarray):
    """The directed segments where faces ((m, 3) int) of a mesh (vertices (n, 3) float, mm) cross the planes
    z (sorted, mm) from z[first[f]] up to before z[stop[f]], grouped by layer, each layer's in face order:
    (layer offsets (L+1,), layer, face (s,), start point (s, 2) mm, start and end edge keys (s,), start and
    end edges (s, 2) lower vertex first, positions along them (s,) from the lower vertex), as
    :func:`heoslice.layers.slicing.slice_mesh` describes them. Keys are ``layer * n^2 + low * n + high``:
    the caller checks that they fit in int64."""
    return _layer_segments(np.ascontiguousarray(vertices, dtype=np.float64), np.ascontiguousarray(faces, np.int64),
                           np.ascontiguousarray(z, dtype=np.float64), np.ascontiguousarray(first, np.int64),
                           np.ascontiguousarray(stop, np.int64))
