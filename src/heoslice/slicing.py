"""Slicing: intersect every triangle with the layer planes it crosses, for all layers at once.

The paper's section IV.A-B, vectorised with numpy:

* global intersection filter (Table 2): each triangle's z-range is located among
  the sorted plane heights with ``searchsorted``, so a triangle is touched only for
  the planes it crosses, and the (triangle, plane) pairs are grouped by layer;
* local topology: each intersection point is named by the mesh edge it lies on,
  and each segment is directed by the right-hand rule, from the edge that goes down
  through the plane to the edge that goes up, so that outer contours run
  counter-clockwise seen from +z and holes clockwise. :mod:`heoslice.contours`
  chains the segments into loops through those shared edge names.

A vertex exactly on a plane counts as above it (the comparison is ``z < plane``
for below), so every crossed triangle has exactly two crossing edges, and the
intersection of an edge is computed from its lower-numbered vertex, making the
point bit-identical in both triangles that share the edge.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from heoslice.errors import InputError


@dataclass(frozen=True)
class Sections:
    """The directed intersection segments of all layers, grouped by layer.

    Segment i runs from ``start[i]`` to ``end[i]`` ((s, 2) float, mm) in layer
    ``layer[i]`` (sorted); segments of layer k are ``offsets[k]:offsets[k+1]``.
    ``start_key``/``end_key`` ((s,) int64) name the mesh edge each end lies on,
    unique within a layer. ``start_edge``/``end_edge`` ((s, 2) int64) are that
    edge's vertex indices (lower first) and ``start_t``/``end_t`` ((s,) float) the
    position along it, for interpolating vertex attributes (colour, material).
    ``face`` ((s,) int64) is the triangle each segment came from.
    """

    z: np.ndarray
    offsets: np.ndarray
    layer: np.ndarray
    face: np.ndarray
    start: np.ndarray
    end: np.ndarray
    start_key: np.ndarray
    end_key: np.ndarray
    start_edge: np.ndarray
    end_edge: np.ndarray
    start_t: np.ndarray
    end_t: np.ndarray

    @property
    def layer_count(self) -> int:
        return int(len(self.z))

    def layer_slice(self, index: int) -> slice:
        """Index range of layer ``index``'s segments."""
        return slice(int(self.offsets[index]), int(self.offsets[index + 1]))


def plane_heights(z_min: float, z_max: float, layer_height: float) -> np.ndarray:
    """Slicing planes at layer centres: z_i = z_min + (i + 1/2) h, i = 0 .. ceil((z_max - z_min) / h) - 1.

    Returns (L,) float64, mm.
    """
    if not layer_height > 0:
        raise InputError(f"layer height must be positive, got {layer_height}")
    count = int(np.ceil((z_max - z_min) / layer_height - 1e-9))
    return z_min + (np.arange(max(count, 1)) + 0.5) * layer_height


def _intersect_edges(vertices: np.ndarray, a: np.ndarray, b: np.ndarray, z: np.ndarray):
    """Points where edges (a, b) cross heights z, computed from the lower-numbered vertex.

    Returns (key-ordered vertex pairs (k, 2) int64, t (k,) float along lo->hi, xy (k, 2) float).
    """
    lo = np.minimum(a, b)
    hi = np.maximum(a, b)
    z_lo = vertices[lo, 2]
    z_hi = vertices[hi, 2]
    t = (z - z_lo) / (z_hi - z_lo)
    xy = vertices[lo, :2] + t[:, None] * (vertices[hi, :2] - vertices[lo, :2])
    return np.stack([lo, hi], axis=1), t, xy


def slice_mesh(vertices: np.ndarray, faces: np.ndarray, z: np.ndarray) -> Sections:
    """Intersect a triangle mesh with horizontal planes at heights z, for all planes at once.

    vertices: (n, 3) float, mm; faces: (m, 3) int, outward-oriented; z: (L,) float,
    sorted ascending, mm. Returns the directed segments grouped by layer.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    z = np.asarray(z, dtype=np.float64)
    n_vertices = len(vertices)
    face_z = vertices[faces, 2]  # (m, 3)

    # Global intersection filter: planes p with z_min < p <= z_max cross the triangle.
    first = np.searchsorted(z, face_z.min(axis=1), side="right")
    stop = np.searchsorted(z, face_z.max(axis=1), side="right")
    counts = stop - first
    crossed = np.nonzero(counts)[0]
    counts = counts[crossed]
    pair_face = np.repeat(crossed, counts)
    run_start = np.repeat(np.cumsum(counts) - counts, counts)
    pair_layer = np.repeat(first[crossed], counts) + (np.arange(len(pair_face)) - run_start)
    order = np.argsort(pair_layer, kind="stable")
    pair_face = pair_face[order]
    pair_layer = pair_layer[order]

    # Local topology: the lone vertex (alone on its side of the plane) and its two edges.
    plane = z[pair_layer]
    tri = faces[pair_face]  # (s, 3)
    below = face_z[pair_face] < plane[:, None]
    lone_below = below.sum(axis=1) == 1
    lone = np.where(lone_below, np.argmax(below, axis=1), np.argmin(below, axis=1))
    rows = np.arange(len(tri))
    v_lone = tri[rows, lone]
    v_next = tri[rows, (lone + 1) % 3]
    v_prev = tri[rows, (lone + 2) % 3]
    # Directed edge lone->next goes up when the lone vertex is below; the segment runs
    # from the point on the downward edge to the point on the upward edge.
    start_a = np.where(lone_below, v_prev, v_lone)
    start_b = np.where(lone_below, v_lone, v_next)
    end_a = np.where(lone_below, v_lone, v_prev)
    end_b = np.where(lone_below, v_next, v_lone)
    start_edge, start_t, start = _intersect_edges(vertices, start_a, start_b, plane)
    end_edge, end_t, end = _intersect_edges(vertices, end_a, end_b, plane)

    span = np.int64(n_vertices) * np.int64(n_vertices)
    if len(z) * float(span) >= 2.0**62:
        raise InputError(f"mesh too large to slice: {n_vertices} vertices x {len(z)} layers")
    start_key = pair_layer * span + start_edge[:, 0] * n_vertices + start_edge[:, 1]
    end_key = pair_layer * span + end_edge[:, 0] * n_vertices + end_edge[:, 1]
    offsets = np.searchsorted(pair_layer, np.arange(len(z) + 1), side="left")
    return Sections(
        z=z,
        offsets=offsets,
        layer=pair_layer,
        face=pair_face,
        start=start,
        end=end,
        start_key=start_key,
        end_key=end_key,
        start_edge=start_edge,
        end_edge=end_edge,
        start_t=start_t,
        end_t=end_t,
    )


def interpolate_at(values: np.ndarray, edge: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Per-vertex values ((n,) or (n, k)) interpolated at points t along edges (k, 2): (1 - t) v_lo + t v_hi."""
    values = np.asarray(values, dtype=np.float64)
    lo = values[edge[:, 0]]
    hi = values[edge[:, 1]]
    weight = t if values.ndim == 1 else t[:, None]
    return lo + weight * (hi - lo)
