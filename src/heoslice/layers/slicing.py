"""Slicing: intersect every triangle with the layer planes it crosses, for all layers at once.

The paper's section IV.A-B:

* global intersection filter (Table 2): each triangle's z-range is located among
  the sorted plane heights with ``searchsorted``, so a triangle is touched only for
  the planes it crosses, and the (triangle, plane) pairs are grouped by layer (a
  counting sort, in the one compiled pass of :mod:`heoslice.layers.slicing_kernels`
  that also makes the segments);
* local topology: each intersection point is named by the mesh edge it lies on,
  and each segment is directed by the right-hand rule, from the edge that goes down
  through the plane to the edge that goes up, so that outer contours run
  counter-clockwise seen from +z and holes clockwise. :mod:`heoslice.layers.contours`
  chains the segments into loops through those shared edge names.

Singular points (a vertex, an edge or a face exactly on a plane) follow one symbolic rule: a vertex
on a plane counts as above it (the comparison is ``z < plane`` for below). This is the section of
the plane moved an infinitesimal distance down, which is in general position: every crossed
triangle has exactly one vertex alone on its side and two crossing edges, so each segment has two
well-named ends and, on a closed mesh, the segments chain into closed loops through the edges they
share (the chaining follows the perturbed topology, so loops that touch at a vertex stay apart). The
section's area is the limit from below, so layer areas (and the stack's volume) are those of a
generic plane: a face on a plane belongs to the layer when the solid is below it (a box's top at the
plane: the full outline) and not when it is above (an overhang's underside: the part below only).
An apex pointing up exactly on a plane leaves a loop shrunk to one point, of zero area, which
:mod:`heoslice.layers.contours` drops; one pointing down touches nothing; a ridge (an edge at a local
top) on a plane leaves a loop of zero area along it, which fills no pixel. The paper (section IV)
instead perturbs with a micro-triangle vertex and picks the direction by the number of such
vertices and the support volume; the rule here needs no choice and gives the same closed loops.
The intersection of an edge is computed from its lower-numbered vertex, making the point
bit-identical in both triangles that share the edge.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from heoslice.errors import InputError
from heoslice.layers.slicing_kernels import layer_segments


@dataclass(frozen=True)
class Sections:
    """The directed intersection segments of all layers, grouped by layer.

    Segment i lies in layer ``layer[i]`` (sorted; segments of layer k are
    ``offsets[k]:offsets[k+1]``) and runs from a point on mesh edge
    ``start_edge[i]`` to a point on mesh edge ``end_edge[i]`` ((s, 2) int64 vertex
    indices, lower first). ``start_key``/``end_key`` ((s,) int64) name those edges
    uniquely within the layer, for chaining. ``start`` ((s, 2) float, mm) is the
    start point and ``start_t``/``end_t`` ((s,) float) the positions along the
    edges (lower vertex 0, higher 1), for interpolating vertex attributes and for
    :meth:`end_points`. The end of a segment is the start of the next one in its loop.
    ``face`` ((s,) int64) is the triangle each segment came from.
    """

    z: np.ndarray
    offsets: np.ndarray
    layer: np.ndarray
    face: np.ndarray
    start: np.ndarray
    start_key: np.ndarray
    end_key: np.ndarray
    start_edge: np.ndarray
    end_edge: np.ndarray
    start_t: np.ndarray
    end_t: np.ndarray
    vertices: np.ndarray

    @property
    def layer_count(self) -> int:
        return int(len(self.z))

    def layer_slice(self, index: int) -> slice:
        """Index range of layer ``index``'s segments."""
        return slice(int(self.offsets[index]), int(self.offsets[index + 1]))

    def end_points(self, segments: np.ndarray | slice = slice(None)) -> np.ndarray:
        """(k, 2) float end points of the given segments, mm."""
        edge = self.end_edge[segments]
        return interpolate_at(self.vertices[:, :2], edge, self.end_t[segments])


def slice_mesh(vertices: np.ndarray, faces: np.ndarray, z: np.ndarray,
               face_range: tuple[np.ndarray, np.ndarray] | None = None) -> Sections:
    """Intersect a triangle mesh with horizontal planes at heights z, for all planes at once.

    vertices: (n, 3) float, mm; faces: (m, 3) int, outward-oriented; z: (L,) float,
    sorted ascending, mm. ``face_range`` ((m,) lowest and highest z per face, as
    :func:`face_z_range`) may be given when known. Returns the directed segments grouped by layer.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    z = np.asarray(z, dtype=np.float64)
    n_vertices = len(vertices)
    span = np.int64(n_vertices) * np.int64(n_vertices)
    if len(z) * float(span) >= 2.0**62:
        raise InputError(f"mesh too large to slice: {n_vertices} vertices x {len(z)} layers")
    low, high = face_range if face_range is not None else face_z_range(vertices, faces)
    # Global intersection filter: planes p with z_min < p <= z_max cross the triangle.
    first = np.searchsorted(z, low, side="right")
    stop = np.searchsorted(z, high, side="right")
    # local topology, per (triangle, plane) pair, grouped by layer in one compiled pass
    (offsets, layer, face, start, start_key, end_key, start_edge, end_edge, start_t,
     end_t) = layer_segments(vertices, faces, z, first, stop)
    return Sections(z=z, offsets=offsets, layer=layer, face=face, start=start, start_key=start_key,
                    end_key=end_key, start_edge=start_edge, end_edge=end_edge, start_t=start_t, end_t=end_t,
                    vertices=vertices)


def interpolate_at(values: np.ndarray, edge: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Per-vertex values ((n,) or (n, k)) interpolated at points t along edges (k, 2): (1 - t) v_lo + t v_hi."""
    values = np.asarray(values, dtype=np.float64)
    lo = values[edge[:, 0]]
    hi = values[edge[:, 1]]
    weight = t if values.ndim == 1 else t[:, None]
    return lo + weight * (hi - lo)


def segments_per_plane(vertices: np.ndarray, faces: np.ndarray, z: np.ndarray,
                       face_range: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(L,) int: how many segments each plane will get (triangles with z_min < plane <= z_max)."""
    low, high = face_range if face_range is not None else face_z_range(vertices, faces)
    first = np.searchsorted(z, low, side="right")
    stop = np.searchsorted(z, high, side="right")
    change = np.bincount(first, minlength=len(z) + 1) - np.bincount(stop, minlength=len(z) + 1)
    return np.cumsum(change)[: len(z)]


def plane_chunks(vertices: np.ndarray, faces: np.ndarray, z: np.ndarray, max_segments: int = 50_000,
                 face_range: tuple[np.ndarray, np.ndarray] | None = None) -> list[tuple[int, int]]:
    """Split the planes into consecutive runs [start, stop) of at most ~max_segments segments each.

    Slicing run by run keeps peak memory bounded however many layers a part has
    (a single plane with more segments than the budget is a run of its own).
    """
    per_plane = segments_per_plane(vertices, faces, z, face_range)
    total = np.cumsum(per_plane)
    bounds = [0]
    while bounds[-1] < len(z):
        start = bounds[-1]
        base = total[start - 1] if start else 0
        stop = int(np.searchsorted(total, base + max_segments, side="right"))
        bounds.append(max(stop, start + 1))
    return list(zip(bounds[:-1], bounds[1:]))


def slice_planes(vertices: np.ndarray, faces: np.ndarray, z: np.ndarray, start: int, stop: int,
                 face_range: tuple[np.ndarray, np.ndarray] | None = None) -> Sections:
    """Sections of planes z[start:stop] only, from the triangles that can reach them.

    Layer numbers in the result are local to the run; ``face`` indices refer to the
    full ``faces`` array. ``face_range`` ((m,) lowest and highest z per face) may be
    passed in to avoid recomputing it for every run.
    """
    low, high = face_range if face_range is not None else face_z_range(vertices, faces)
    reach = np.nonzero((high >= z[start]) & (low < z[stop - 1]))[0]
    sections = slice_mesh(vertices, np.take(faces, reach, axis=0), z[start:stop], (low[reach], high[reach]))
    return replace(sections, face=reach[sections.face])


def face_z_range(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lowest and highest vertex z of every face ((m,) float each, mm)."""
    return _face_min_max(np.ascontiguousarray(np.asarray(vertices, dtype=np.float64)[:, 2])[np.asarray(faces)])


def _face_min_max(face_z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row minimum and maximum of (m, 3) corner heights, column by column (a reduction
    along a length-3 axis is several times slower in numpy)."""
    a, b, c = face_z[:, 0], face_z[:, 1], face_z[:, 2]
    return np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)
