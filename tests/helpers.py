"""Test helpers: slice a trimesh in memory, random rings, and independent references to compare against."""

from __future__ import annotations

import manifold3d
import numpy as np
import shapely

from heoslice.layers.contours import Contours, build_contours
from heoslice.regions import ring_edges
from heoslice.regions_compiled import edge_tree
from heoslice.layers import plane_heights, slice_mesh


def contours_of(mesh, layer_height: float) -> tuple[np.ndarray, Contours]:
    """Planes and contours of a trimesh-like (vertices, faces) at layer centres."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    z = plane_heights(vertices[:, 2].min(), vertices[:, 2].max(), layer_height)
    return z, build_contours(slice_mesh(vertices, np.asarray(mesh.faces), z))


def manifold_areas(vertices: np.ndarray, faces: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Per-plane cross-section areas from manifold3d's slice, in double precision (the reference)."""
    solid = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.ascontiguousarray(vertices, np.float64),
                                                  tri_verts=np.ascontiguousarray(faces, np.uint64)))
    assert solid.status() == manifold3d.Error.NoError, solid.status()
    return np.array([solid.slice(float(height)).area() for height in z])


def layer_loops(contours: Contours, layer: int) -> tuple[np.ndarray, np.ndarray]:
    """(points, offsets) of one layer's loops, offsets starting at 0."""
    first, last = contours.layer_offsets[layer], contours.layer_offsets[layer + 1]
    start = contours.offsets[first]
    return contours.points[start:contours.offsets[last]], contours.offsets[first:last + 1] - start


def winding_reference(points: np.ndarray, offsets: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Winding number of closed loops at points (x, y) by shapely point-in-polygon, one loop at a time."""
    winding = np.zeros(np.shape(x), dtype=np.int64)
    for start, stop in zip(offsets[:-1], offsets[1:]):
        ring = points[start:stop]
        if len(ring) < 3:
            continue
        sign = 1 if _shoelace(ring) > 0 else -1
        winding += sign * shapely.contains_xy(shapely.Polygon(ring), x, y)
    return winding


def near_contour(points: np.ndarray, offsets: np.ndarray, x: np.ndarray, y: np.ndarray,
                 tolerance: float = 1e-6) -> np.ndarray:
    """Points (x, y) within ``tolerance`` mm of any loop edge."""
    rings = [shapely.LinearRing(points[a:b]) for a, b in zip(offsets[:-1], offsets[1:]) if b - a >= 3]
    if not rings:
        return np.zeros(np.shape(x), dtype=bool)
    boundary = shapely.union_all(rings)
    return shapely.dwithin(boundary, shapely.points(x, y), tolerance)


def _shoelace(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def random_rings(rng, rings: int):
    """Edges of ``rings`` random star-shaped rings (3 to 300 points each) in a 100 mm square."""
    points, sizes = [], []
    for _ in range(rings):
        count = int(rng.integers(3, 300))
        angle = np.sort(rng.uniform(0, 2 * np.pi, count))
        radius = rng.uniform(0.5, 30.0) * rng.uniform(0.6, 1.0, count)
        centre = rng.uniform(-50, 50, 2)
        points.append(centre + np.column_stack([radius * np.cos(angle), radius * np.sin(angle)]))
        sizes.append(count)
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    return ring_edges(np.concatenate(points), offsets, list(range(rings)))


def brute_squared(qx, qy, edges):
    """(n, e) squared distance from every point to every edge, float64."""
    rx = qx[:, None] - edges.x[None, :]
    ry = qy[:, None] - edges.y[None, :]
    t = np.clip((rx * edges.vx + ry * edges.vy) * edges.inv_len2, 0.0, 1.0)
    return (rx - t * edges.vx) ** 2 + (ry - t * edges.vy) ** 2


def tree_of(edges):
    """The edge tree of RingEdges (:func:`heoslice.regions_compiled.edge_tree`)."""
    return edge_tree(edges.x, edges.y, edges.x + edges.vx, edges.y + edges.vy)
