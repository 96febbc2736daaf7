"""Exact unsigned distance from points to a triangle surface (the ``surface`` reference feature).

The surface is indexed once by a bounding-volume hierarchy over its triangles
(:mod:`heoslice.material.surface_kernels`); each query returns the exact minimum of the
point-triangle distance over all triangles, for any surface (non-convex, several parts,
thin walls). Points (n, 3) and vertices (v, 3) in mm, faces (m, 3) int.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from heoslice.errors import InputError

if TYPE_CHECKING:  # only a surface reference needs the kernels, so they are imported when used
    from heoslice.material.surface_kernels import Hierarchy


@dataclass(frozen=True, eq=False)
class SurfaceIndex:
    """A triangle surface prepared for nearest-distance queries (see :func:`surface_distance`).

    vertices (v, 3) float64 mm, faces (m, 3) int64; tree: the bounding-volume hierarchy
    over the triangles.
    """

    vertices: np.ndarray
    faces: np.ndarray
    tree: Hierarchy


def build_surface_index(vertices: np.ndarray, faces: np.ndarray) -> SurfaceIndex:
    """Index a triangle surface (vertices (v, 3) mm, faces (m, 3)) for :func:`surface_distance`.

    Raises InputError naming ``surface`` for a surface without triangles, face indices
    outside the vertex list, or coordinates that are not finite.
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0:
        raise InputError("surface: the reference surface has no triangles")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError("surface: the reference surface has face indices outside its vertex list")
    if not np.isfinite(vertices).all():
        raise InputError("surface: the reference surface has NaN or infinite coordinates")
    from heoslice.material.surface_kernels import LEAF_SIZE, Hierarchy, build_nodes

    corners = vertices[faces]
    order, low, high, left, right, first, count = build_nodes(
        corners.mean(axis=1), corners.min(axis=1), corners.max(axis=1), LEAF_SIZE)
    corners = np.ascontiguousarray(corners[order])
    centre = corners.mean(axis=1)
    radius = np.sqrt(np.einsum("ijk,ijk->ij", corners - centre[:, None], corners - centre[:, None]).max(axis=1))
    tree = Hierarchy(low, high, left, right, first, count, corners, np.ascontiguousarray(centre),
                     radius * (1.0 + 1e-12) + 1e-12, _planes(corners))
    return SurfaceIndex(vertices, faces, tree)


#: Sine of a triangle's smallest angle at corner a below which its plane is not used as a bound: the cross
#: product's rounding tilts a unit normal by about 16 eps / sine (4e-11 here), which the plane test's slack covers.
PLANE_SINE = 1e-4


def _planes(corners: np.ndarray) -> np.ndarray:
    """Each triangle's plane (m, 4): unit normal and offset n . a; zeros (no bound) for a sliver whose angle at its
    first corner has a sine under PLANE_SINE, whose computed normal rounding may tilt too far (and for a triangle
    the distance kernel measures as its three edges, :func:`heoslice.material.surface_kernels.triangle_offset`)."""
    ab, ac = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    normal = np.cross(ab, ac)
    length2 = np.einsum("ij,ij->i", normal, normal)
    flat = ~(length2 > PLANE_SINE ** 2 * np.einsum("ij,ij->i", ab, ab) * np.einsum("ij,ij->i", ac, ac))
    normal = normal / np.sqrt(np.where(flat, 1.0, length2))[:, None]
    normal[flat] = 0.0
    return np.ascontiguousarray(np.column_stack([normal, np.einsum("ij,ij->i", normal, corners[:, 0])]))


def _workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def _spread_bits(v: np.ndarray) -> np.ndarray:
    """10-bit integers (n,) uint64 with two zero bits inserted after each bit (for a 3-D Morton code)."""
    v = (v | (v << np.uint64(16))) & np.uint64(0x030000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x0300F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x030C30C3)
    return (v | (v << np.uint64(2))) & np.uint64(0x09249249)


def curve_order(points: np.ndarray) -> np.ndarray:
    """The order (n,) of points (n, 3) along a Morton (Z-order) curve over their box, 1024 cells a side:
    queries in this order start from a nearby point's nearest triangle, a tight first bound."""
    low = points.min(axis=0)
    extent = np.maximum(points.max(axis=0) - low, 1e-300)
    cells = np.clip((points - low) * (1023.0 / extent), 0.0, 1023.0).astype(np.uint64)
    code = _spread_bits(cells[:, 0]) | (_spread_bits(cells[:, 1]) << np.uint64(1)) | (
        _spread_bits(cells[:, 2]) << np.uint64(2))
    return np.argsort(code, kind="stable")


def surface_distance(points: np.ndarray, index: SurfaceIndex, chunk: int = 65536,
                     progress: Callable[[int, int], None] | None = None, workers: int | None = None) -> np.ndarray:
    """Exact unsigned distance (n,) mm from points (n, 3) mm to the nearest triangle of the surface.

    The points are measured in :func:`curve_order` (each search starts from the previous point's
    nearest triangle), in chunks of ``chunk`` points on ``workers`` threads (default: the usable
    cores; the kernel releases the GIL); ``progress(done, total)`` follows the chunks in order.
    """
    from heoslice.material.surface_kernels import nearest_distances

    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if not len(points):
        return np.empty(0)
    order = curve_order(points)
    ordered = np.ascontiguousarray(points[order])
    measured = np.empty(len(points))
    out = np.empty(len(points))
    starts = list(range(0, len(points), max(1, int(chunk))))

    def measure(start: int) -> int:
        stop = min(start + chunk, len(points))
        nearest_distances(ordered[start:stop], index.tree, measured[start:stop])
        out[order[start:stop]] = measured[start:stop]
        return stop

    threads = max(1, min(workers or _workers(), len(starts)))
    if threads == 1:
        done = map(measure, starts)
        for stop in done:
            if progress is not None:
                progress(stop, len(points))
        return out
    with ThreadPoolExecutor(threads) as pool:
        for stop in pool.map(measure, starts):
            if progress is not None:
                progress(stop, len(points))
    return out


#: Side (pixels) of the cells :func:`layer_r` starts from before halving them.
TOP_CELL = 64


def layer_r(solid: np.ndarray, frame: tuple[float, float, float, float, float], index: SurfaceIndex,
            r_range: tuple[float, float], tolerance: float, top: int = TOP_CELL, with_spread: bool = False,
            steps: int | None = None) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """r (h, w) float64 at the solid pixel centres of a layer (solid (h, w) bool; 0 elsewhere): the exact distance
    to the surface normalised over r_range (R0, R1) mm and clipped to [0, 1], each within tolerance / 2 of its
    true r (:func:`heoslice.material.surface_layer_kernels.layer_r`'s bounds settle cells of up to ``top`` pixels a side,
    the rest is measured pixel by pixel). frame: (x of column 0's centre, x step per column, y of row 0's centre,
    y step per row, z), mm. With ``steps`` (< 65536): each pixel's step round(r steps) (h, w) uint16 instead of r.
    ``with_spread`` also returns each pixel's proven bound on its r's error (h, w)."""
    solid = np.ascontiguousarray(solid, dtype=bool)
    out, spread = _layer_r(np.packbits(solid, axis=1), 0, solid.shape[1], frame, index, r_range, tolerance, top,
                           with_spread, steps)
    outside = ~solid  # the kernel writes anything there
    for written in (out, spread) if with_spread else (out,):
        written[outside] = 0
    return (out, spread) if with_spread else out


def packed_layer_steps(packed: np.ndarray, c0: int, cols: int, frame: tuple[float, float, float, float, float],
                       index: SurfaceIndex, r_range: tuple[float, float], tolerance: float, steps: int) -> np.ndarray:
    """:func:`layer_r`'s steps round(r steps) (h, cols) uint16 (off the solid, anything up to 65535) of the layer whose
    pixels are columns c0:c0 + cols (c0 a multiple of 8) of ``packed`` ((h, bytes) uint8 rows, MSB first), read as
    they are."""
    if c0 % 8:
        raise ValueError(f"a layer's first column is a multiple of 8, not {c0}")
    return _layer_r(np.ascontiguousarray(packed, dtype=np.uint8), c0 // 8, cols, frame, index, r_range, tolerance,
                    TOP_CELL, False, steps)[0]


def _layer_r(packed: np.ndarray, first: int, cols: int, frame: tuple, index: SurfaceIndex,
             r_range: tuple[float, float], tolerance: float, top: int, with_spread: bool,
             steps: int | None) -> tuple[np.ndarray, np.ndarray]:
    """(r or, with ``steps``, r's steps; the bounds or (0, 0)) of the layer of columns 0:cols that are the bits of
    ``packed`` from byte ``first`` on (:func:`heoslice.material.surface_layer_kernels.layer_r`); anything off the solid."""
    from heoslice.material.surface_layer_kernels import LayerFrame
    from heoslice.material.surface_layer_kernels import layer_r as kernel

    coded = steps is not None
    if coded and not 0 < steps < 1 << 16:
        raise ValueError(f"r's steps are 1 to 65535 (the kernel writes them as uint16), not {steps}")
    shape = (packed.shape[0], int(cols))
    r = np.empty((0, 0) if coded else shape)
    codes = np.empty(shape if coded else (0, 0), np.uint16)
    spread = np.empty(shape if with_spread else (0, 0))
    kernel(packed, int(first), int(cols), LayerFrame(*map(float, frame)), index.tree, float(r_range[0]),
           float(r_range[1]), float(tolerance), int(top), r, spread, int(steps or 0), codes)
    return (codes if coded else r), spread
