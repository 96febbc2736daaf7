"""Unsigned distance from points to a triangle surface (the ``surface`` reference feature).

Points (n, 3) and vertices (v, 3) in mm, faces (m, 3) int.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from heoslice.errors import InputError
from heoslice.material.triangles import closest_parameters, point_triangle_distance


@dataclass(frozen=True, eq=False)
class SurfaceIndex:
    """A triangle surface prepared for closest-point queries (see :func:`surface_distance`).

    vertices (v, 3) float64 mm, faces (m, 3) int64; vertex_faces (v, k) and
    vertex_neighbours (v, j) and face_neighbours (m, i) int64 adjacency padded with -1;
    seeds (s,) int64 face of each start point, seed_tree the scipy cKDTree of the start
    points (s, 3) on those faces; seed_spacing: every surface point is within this
    distance (mm) of a start point.
    """

    vertices: np.ndarray
    faces: np.ndarray
    vertex_faces: np.ndarray
    vertex_neighbours: np.ndarray
    face_neighbours: np.ndarray
    seeds: np.ndarray
    seed_tree: object = field(repr=False)
    seed_spacing: float = 0.0


def _padded(groups: np.ndarray, members: np.ndarray, count: int) -> np.ndarray:
    """Rows of ``members`` grouped by ``groups`` (0..count-1), as a (count, width) array padded with -1."""
    order = np.lexsort((members, groups))
    groups, members = groups[order], members[order]
    keep = np.ones(len(groups), dtype=bool)
    keep[1:] = (groups[1:] != groups[:-1]) | (members[1:] != members[:-1])
    groups, members = groups[keep], members[keep]
    sizes = np.bincount(groups, minlength=count)
    width = int(sizes.max(initial=1))
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    table = np.full((count, max(width, 1)), -1, dtype=np.int64)
    table[groups, np.arange(len(groups)) - starts[groups]] = members
    return table


def build_surface_index(vertices: np.ndarray, faces: np.ndarray, seed_count: int = 1024) -> SurfaceIndex:
    """Adjacency tables and a tree of about ``seed_count`` start points for :func:`surface_distance`.

    vertices (v, 3) mm, faces (m, 3). Fewer start points make far queries faster
    (scipy's tree slows down when many points are nearly equidistant) and the downhill
    walks longer; 1024 measured best on benchmarks/bench_color.py.
    """
    from scipy.spatial import cKDTree

    vertices = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0:
        raise InputError("surface: the reference surface has no triangles")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError("surface: the reference surface has face indices outside its vertex list")
    if not np.isfinite(vertices).all():
        raise InputError("surface: the reference surface has NaN or infinite coordinates")
    nv, nf = len(vertices), len(faces)
    corner_face = np.repeat(np.arange(nf), 3)
    vertex_faces = _padded(faces.ravel(), corner_face, nv)
    edges = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    vertex_neighbours = _padded(np.concatenate([edges[:, 0], edges[:, 1]]),
                                np.concatenate([edges[:, 1], edges[:, 0]]), nv)
    around = vertex_faces[faces].reshape(nf, -1)
    rows = np.repeat(np.arange(nf), around.shape[1])
    flat = around.ravel()
    valid = (flat >= 0) & (flat != rows)
    face_neighbours = _padded(rows[valid], flat[valid], nf)
    points, owner, spacing = _seed_points(vertices, faces, seed_count)
    return SurfaceIndex(vertices, faces, vertex_faces, vertex_neighbours, face_neighbours,
                        owner, cKDTree(points), spacing)


def _seed_points(vertices: np.ndarray, faces: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray, float]:
    """About ``count`` start points on the surface: (points (s, 3), face of each (s,), covering radius mm).

    Triangles longer than a grid cell are split into sub-triangles no longer than the cell,
    whose centroids are all kept; the other triangles keep one centroid per grid cell. Every
    surface point is then within the returned radius of a start point.
    """
    corners = vertices[faces]
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    cell = max(math.sqrt(2.0 * max(float(area.sum()), 1e-300) / max(count, 1)), 1e-9)
    splits = np.maximum(np.ceil(longest / cell), 1).astype(np.int64)
    for _ in range(60):  # keep the number of sub-triangles bounded on meshes with huge triangles
        if int((splits ** 2).sum()) <= 4 * count + len(faces):
            break
        cell *= 1.25
        splits = np.maximum(np.ceil(longest / cell), 1).astype(np.int64)
    # sub-triangle centroids: s*(s+1)/2 upward and s*(s-1)/2 downward ones per triangle
    up, down = splits * (splits + 1) // 2, splits * (splits - 1) // 2
    face = np.concatenate([np.repeat(np.arange(len(faces)), up), np.repeat(np.arange(len(faces)), down)])
    rank = np.concatenate([np.arange(up.sum()) - np.repeat(np.cumsum(up) - up, up),
                           np.arange(down.sum()) - np.repeat(np.cumsum(down) - down, down)])
    is_up = np.concatenate([np.ones(up.sum(), bool), np.zeros(down.sum(), bool)])
    size = splits[face] - (~is_up)  # rows of the triangular index grid
    row = (np.floor((np.sqrt(8.0 * rank + 1) - 1) / 2)).astype(np.int64)  # rank -> (row, column)
    row = np.where((row + 1) * (row + 2) // 2 <= rank, row + 1, row)
    row = np.where(row * (row + 1) // 2 > rank, row - 1, row)
    column = rank - row * (row + 1) // 2
    i, j = size - 1 - row, column  # i + j <= size - 1
    offset = np.where(is_up, 1.0 / 3.0, 2.0 / 3.0)
    u = (i + offset) / splits[face]
    v = (j + offset) / splits[face]
    a = corners[face, 0]
    points = a + u[:, None] * (corners[face, 1] - a) + v[:, None] * (corners[face, 2] - a)
    small = splits[face] == 1
    if len(points) <= count:
        return points, face, float((longest / splits).max())  # a point is within an edge of its centroid
    keys = np.floor((points[small] - points.min(axis=0)) / cell).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    keep = np.concatenate([np.nonzero(small)[0][first], np.nonzero(~small)[0]])
    # a point of a small triangle is within its longest edge of the centroid, which is within
    # a cell diagonal of the kept centroid of its cell; split triangles are covered by their own
    radius = float(longest[splits == 1].max(initial=0.0)) + math.sqrt(3.0) * cell
    return points[keep], face[keep], max(radius, cell)


def _face_distance(points: np.ndarray, index: SurfaceIndex, faces: np.ndarray):
    """Distances (n, k) from points (n, 3) to faces (n, k) int (-1 = none: inf), and regions (n, k) int8.

    Regions as :func:`closest_parameters`; -1 where a triangle is degenerate.
    """
    n, k = faces.shape
    tri = index.vertices[index.faces[np.maximum(faces, 0)]].reshape(n * k, 3, 3)
    p = np.repeat(points, k, axis=0)
    a = tri[:, 0]
    ab, ac, ap = tri[:, 1] - a, tri[:, 2] - a, p - a
    s, t, region = closest_parameters(ap, ab, ac)
    gap = ap - s[:, None] * ab - t[:, None] * ac
    d = np.sqrt(np.einsum("ij,ij->i", gap, gap))
    broken = ~np.isfinite(d)
    if broken.any():
        d[broken] = point_triangle_distance(p[broken], tri[broken])
        region[broken] = -1
    d = d.reshape(n, k)
    d[faces < 0] = np.inf
    return d, region.reshape(n, k)


#: For each closest-point region: the triangle corners (0, 1, 2) it touches.
_REGION_CORNERS = np.array([[0, 0], [1, 1], [2, 2], [0, 1], [0, 2], [1, 2]])


def surface_distance(points: np.ndarray, index: SurfaceIndex, seeds_per_point: int = 1,
                     chunk: int = 65536, progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """Unsigned distance (n,) mm from points (n, 3) mm to a triangle surface.

    Each point starts at its nearest start points on the surface (scipy cKDTree over
    about ``seed_count`` points, see :func:`build_surface_index`), walks downhill over the
    vertex graph to a vertex nearer than all its neighbours, takes the nearest of the
    triangles around it and the start triangle (exact point-triangle distances), then
    walks downhill over triangles until no triangle sharing a vertex with the current
    one is nearer. The result is the exact distance to a locally closest triangle, which
    is the global one unless another part of the surface is almost as near: it is never
    below the true distance, and never above the distance to the nearest start point
    (so at most ``index.seed_spacing`` above it). ``progress(done, total)`` follows the chunks.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.empty(len(points))
    k = max(1, min(int(seeds_per_point), len(index.seeds)))
    for start in range(0, len(points), chunk):
        block = points[start:start + chunk]
        _, nearest = index.seed_tree.query(block, k=k)
        nearest = np.asarray(nearest).reshape(len(block), k)
        best = np.full(len(block), np.inf)
        for column in range(k):
            best = np.minimum(best, _descend(block, index, index.seeds[nearest[:, column]]))
        out[start:start + chunk] = best
        if progress is not None:
            progress(min(start + chunk, len(points)), len(points))
    return out


def _descend(points: np.ndarray, index: SurfaceIndex, start_face: np.ndarray) -> np.ndarray:
    """Downhill walk from start faces (n,) to a locally nearest triangle; (n,) distances."""
    vertices = index.vertices
    rows = np.arange(len(points))
    start_d, _ = _face_distance(points, index, start_face[:, None])
    start_d = start_d[:, 0]
    corner = index.faces[start_face]
    gap = points[:, None, :] - vertices[corner]
    corner_d = np.einsum("ijk,ijk->ij", gap, gap)
    current = corner[rows, np.argmin(corner_d, axis=1)]
    current_d = corner_d.min(axis=1)

    def vertex_step(active):
        around = index.vertex_neighbours[current[active]]
        diff = points[active, None, :] - vertices[np.maximum(around, 0)]
        return around, np.where(around >= 0, np.einsum("ijk,ijk->ij", diff, diff), np.inf)

    _walk_downhill(current, current_d, rows, vertex_step)
    ring = index.vertex_faces[current]
    d, region = _face_distance(points, index, ring)
    pick = np.argmin(d, axis=1)
    face, face_d, face_region = ring[rows, pick], d[rows, pick], region[rows, pick]
    # The whole ring of `current` was measured: the nearest point is a local minimum when it is
    # inside the face, or on a corner or edge touching `current` (its neighbourhood is in the ring).
    corners = index.faces[face][rows[:, None], _REGION_CORNERS[np.maximum(face_region, 0) % 6]]
    settled = (face_region == 6) | ((face_region >= 0) & (corners == current[:, None]).any(axis=1))
    # The vertex walk can cross to another sheet (the far wall of a thin part); the start face may be nearer.
    from_start = start_d < face_d
    face[from_start], face_d[from_start] = start_face[from_start], start_d[from_start]
    settled &= ~from_start

    def face_step(active):
        around = index.face_neighbours[face[active]]
        return around, _face_distance(points[active], index, around)[0]

    _walk_downhill(face, face_d, np.nonzero(~settled)[0], face_step)
    return face_d


def _walk_downhill(position: np.ndarray, distance: np.ndarray, active: np.ndarray, step) -> None:
    """Move each active walker to its nearest neighbour while that is nearer, in place, all walkers at once.

    ``step(active)`` returns the candidates ((k, c) int, one row per active walker) and
    their distances ((k, c) float, inf for none); a walker stops when no candidate is
    nearer than where it stands.
    """
    while len(active):
        around, d = step(active)
        pick = np.argmin(d, axis=1)
        d_pick = d[np.arange(len(active)), pick]
        moved = d_pick < distance[active]
        active = active[moved]
        position[active] = around[moved, pick[moved]]
        distance[active] = d_pick[moved]
