"""Exact closest points on triangles, vectorised (Ericson, Real-Time Collision Detection, 5.1.5).

Points (n, 3) and triangles (n, 3, 3) in mm; a degenerate (zero-area) triangle is handled
as the closest of its three edges.
"""

from __future__ import annotations

import numpy as np


def closest_parameters(ap: np.ndarray, ab: np.ndarray, ac: np.ndarray):
    """Barycentric (s, t) (n,) of the closest point a + s ab + t ac, and its region (n,) int8.

    Regions: 0 vertex a, 1 vertex b, 2 vertex c, 3 edge ab, 4 edge ac, 5 edge bc, 6 inside.
    Ericson's region test (Real-Time Collision Detection, 5.1.5), vectorised.
    """
    dot = lambda u, v: np.einsum("ij,ij->i", u, v)  # noqa: E731
    d1, d2 = dot(ab, ap), dot(ac, ap)
    abab, abac, acac = dot(ab, ab), dot(ab, ac), dot(ac, ac)
    d3, d4 = d1 - abab, d2 - abac          # ab.(p-b), ac.(p-b)
    d5, d6 = d1 - abac, d2 - acac          # ab.(p-c), ac.(p-c)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        denom = va + vb + vc
        v, w = vb / denom, vc / denom
    region = np.select(
        [(d1 <= 0) & (d2 <= 0), (d3 >= 0) & (d4 <= d3), (d6 >= 0) & (d5 <= d6),
         (vc <= 0) & (d1 >= 0) & (d3 <= 0), (vb <= 0) & (d2 >= 0) & (d6 <= 0),
         (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)],
        [0, 1, 2, 3, 4, 5], default=6).astype(np.int8)
    zero = np.zeros_like(d1)
    s = np.choose(region, [zero, zero + 1.0, zero, t_ab, zero, 1.0 - t_bc, v])
    t = np.choose(region, [zero, zero, zero + 1.0, zero, t_ac, t_bc, w])
    return s, t, region


def closest_points_on_triangles(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Closest point (n, 3) on each triangle (n, 3, 3) to each point (n, 3), all mm.

    A degenerate (zero-area) triangle is handled as the closest of its three edges.
    """
    p = np.asarray(points, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.float64)
    a = triangles[:, 0]
    ab, ac = triangles[:, 1] - a, triangles[:, 2] - a
    s, t, _ = closest_parameters(p - a, ab, ac)
    result = a + s[:, None] * ab + t[:, None] * ac
    broken = ~np.isfinite(result).all(axis=1)
    if broken.any():
        result[broken] = _closest_on_edges(p[broken], triangles[broken])
    return result


def _closest_on_edges(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Closest point on the three edges of (degenerate) triangles; (n, 3)."""
    best = np.empty_like(points)
    best_d = np.full(len(points), np.inf)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        start, seg = triangles[:, i], triangles[:, j] - triangles[:, i]
        length2 = np.einsum("ij,ij->i", seg, seg)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(length2 > 0, np.einsum("ij,ij->i", points - start, seg) / length2, 0.0)
        q = start + np.clip(t, 0.0, 1.0)[:, None] * seg
        d = np.einsum("ij,ij->i", points - q, points - q)
        closer = d < best_d
        best[closer], best_d[closer] = q[closer], d[closer]
    return best


def point_triangle_distance(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Distance (n,) mm from each point (n, 3) to the matching triangle (n, 3, 3)."""
    gap = np.asarray(points, dtype=np.float64) - closest_points_on_triangles(points, triangles)
    return np.sqrt(np.einsum("ij,ij->i", gap, gap))


