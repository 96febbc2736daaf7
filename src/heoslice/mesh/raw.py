"""The raw mesh every format reader returns, and the polygon triangulation the strict readers share."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from heoslice.errors import InputError
from heoslice.mesh.limits import MAX_TRIANGLES

#: Name of the per-vertex float property carrying the material fraction in [0, 1].
MATERIAL_PROPERTY = "material"



@dataclass(frozen=True)
class RawMesh:
    """A triangle mesh as one file holds it, before welding, checks and orientation.

    vertices: (n, 3) float64 coordinates as written (float32 for binary STL, widened after
    the weld). faces: (m, 3) int64 indices into vertices. vertex_colors: (n, 3) uint8
    RGB given per vertex, or None. face_colors: (m, 3) uint8 RGB given per face, or None.
    color_source: 'vertex' or 'face' (what the file's colours belong to), or None.
    vertex_properties: the file's other per-vertex scalar columns by name, (n,) arrays
    (the material fraction written by ``heoslice color`` among them). comments: the file's header comment
    lines (PLY ``comment``/``obj_info``; ``heoslice color``'s design among them).
    """

    vertices: np.ndarray
    faces: np.ndarray
    vertex_colors: np.ndarray | None = None
    face_colors: np.ndarray | None = None
    color_source: str | None = None
    vertex_properties: Mapping[str, np.ndarray] = field(default_factory=dict)
    comments: tuple[str, ...] = ()


def fan_triangles(lengths: np.ndarray, flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate polygons (given as lengths (m,) and concatenated indices) by fans from their first vertex.

    Returns (triangles (k, 3) int64, polygon of each triangle (k,)). Exact for convex
    polygons (quads from scanners and CAD); triangles pass through unchanged.
    """
    per = lengths - 2
    first = np.cumsum(lengths) - lengths
    polygon = np.repeat(np.arange(len(lengths)), per)
    step = np.arange(int(per.sum())) - np.repeat(np.cumsum(per) - per, per)
    base = first[polygon]
    triangles = np.stack([flat[base], flat[base + step + 1], flat[base + step + 2]], axis=1)
    return triangles.astype(np.int64), polygon


def checked_triangles(path: Path, vertex_count: int, lengths: np.ndarray, flat: np.ndarray):
    """Fan triangles of polygons after refusing faces with fewer than 3 vertices or indices outside the vertices.

    Returns (triangles (k, 3) int64, polygon of each triangle (k,)).
    """
    short = lengths < 3
    if short.any():
        bad = int(np.argmax(short))
        raise InputError(f"{path}: face {bad} has {int(lengths[bad])} vertices (a face needs at least 3)")
    triangles = int(lengths.sum()) - 2 * len(lengths)
    if triangles > MAX_TRIANGLES:
        raise InputError(f"{path}: its polygons make {triangles} triangles, more than the {MAX_TRIANGLES} "
                         "heoslice reads")
    flat = flat.astype(np.int64)
    outside = (flat < 0) | (flat >= vertex_count)
    if outside.any():
        bad = int(np.repeat(np.arange(len(lengths)), lengths)[np.argmax(outside)])
        raise InputError(f"{path}: face {bad} refers to vertex {int(flat[np.argmax(outside)])}, "
                         f"outside 0..{vertex_count - 1}")
    return fan_triangles(lengths, flat)


def strip_triangles(path: Path, vertex_count: int, lengths: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """(k, 3) int64 triangles of triangle strips (the PLY ``tristrips`` element): rows of ``lengths`` (m,) indices
    (concatenated: ``flat``), each row one or more strips with -1 between them (for an unsigned list type, its
    largest value, -1's bits, where that cannot be a vertex). A strip v0 v1 v2 v3 ... makes (v0, v1, v2), (v2, v1, v3), (v2, v3, v4), ..., every
    other triangle's first two swapped so all keep the strip's winding; triangles with a repeated vertex (the
    degenerate ones that join strips) are left out. InputError naming ``path`` for another negative index, one
    outside the vertices, or more than MAX_TRIANGLES (refused before they are made)."""
    flat = np.asarray(flat)
    largest = np.iinfo(flat.dtype).max if flat.dtype.kind in "iu" else 0
    restart = flat == (largest if flat.dtype.kind == "u" and largest >= vertex_count else -1)
    indices = np.where(restart, -1, flat.astype(np.int64))
    outside = ~restart & ((indices < 0) | (indices >= vertex_count))
    if outside.any():
        raise InputError(f"{path}: tristrips index {int(indices[np.argmax(outside)])} is outside 0..{vertex_count - 1} "
                         "(-1 alone separates strips)")
    if len(indices) > MAX_TRIANGLES + 2 * len(lengths):
        raise InputError(f"{path}: its strips hold {len(indices)} indices, more than the {MAX_TRIANGLES} triangles "
                         "heoslice reads")
    row_ends = np.cumsum(lengths)[:-1]
    indices = np.insert(indices, row_ends, -1)  # a row ends its strip: the next row starts a new one
    if len(indices) < 3:
        return np.empty((0, 3), dtype=np.int64)
    positions = np.arange(len(indices))
    start = np.maximum.accumulate(np.where(indices < 0, positions + 1, 0))  # each index's strip's first position
    first, second, third = indices[:-2], indices[1:-1], indices[2:]
    odd = (positions[:-2] - start[:-2]) % 2 == 1
    triangles = np.stack([np.where(odd, second, first), np.where(odd, first, second), third], axis=1)
    keep = (np.minimum(np.minimum(first, second), third) >= 0) & (first != second) & (second != third) & (
        first != third)
    return triangles[keep]
