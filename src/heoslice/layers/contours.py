"""Contours: chain intersection segments into closed loops and organise them into families.

The paper's section II.C and IV.B: segments from :mod:`heoslice.layers.slicing` are linked
end to start through the mesh edge they share (local topology), giving closed
loops oriented by the right-hand rule (outer counter-clockwise seen from +z, holes
clockwise). Open meshes give open chains, which are closed by joining their ends
and reported. Loops are then grouped into profile families, the paper's
O_L = {L_i}, L_i = {C_i,j}: an outer ring with the holes directly inside it.

Every segment has at most one successor, so the loops are the cycles (and open
chains) of the successor map: one compiled pass over all layers' segments links
them through a hash table of their edge keys and walks each loop
(:mod:`heoslice.layers.contours_kernels`); everything after it is vectorised.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from heoslice.layers.contours_kernels import loops_by_keys
from heoslice.layers.slicing import Sections


@dataclass(frozen=True)
class Contours:
    """Closed loops of all layers.

    Loop j's points are ``points[offsets[j]:offsets[j+1]]`` ((p, 2) float, mm; the
    closing point is not repeated); ``point_edge`` ((p, 2) int64) and ``point_t``
    ((p,) float) locate each point on its mesh edge for attribute interpolation.
    Per loop: ``layer`` (int), ``area`` (signed, mm^2; > 0 counter-clockwise =
    outer ring, < 0 = hole), ``closed_by_join`` (bool: the chain was open and was
    closed by joining its ends), ``parent`` (the smallest loop of the same layer
    containing it, or -1), ``family`` (the outer ring whose family it belongs to) and
    ``face`` (a mesh face the loop was cut from: ``mesh.shell[face]`` names its shell).
    ``parent`` and ``family`` are None when the contours were built without the hierarchy.
    ``layer_offsets`` ((L+1,) int): loops of layer k are ``layer_offsets[k]:layer_offsets[k+1]``.
    """

    points: np.ndarray
    point_edge: np.ndarray
    point_t: np.ndarray
    offsets: np.ndarray
    layer: np.ndarray
    area: np.ndarray
    closed_by_join: np.ndarray
    parent: np.ndarray | None
    family: np.ndarray | None
    face: np.ndarray
    layer_offsets: np.ndarray

    @property
    def loop_count(self) -> int:
        return int(len(self.layer))

    def loop_points(self, loop: int) -> np.ndarray:
        """(p, 2) float points of one loop, mm."""
        return self.points[self.offsets[loop] : self.offsets[loop + 1]]

    def layer_area(self) -> np.ndarray:
        """(L,) float, mm^2: each layer's sum of signed loop areas, the integral of the winding number.

        This is the solid area when shells do not overlap; a region inside two shells counts twice.
        """
        count = len(self.layer_offsets) - 1
        return np.bincount(self.layer, weights=self.area, minlength=count)


def chain_loops(sections: Sections) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Order segments into loops (compiled: :func:`heoslice.layers.contours_kernels.loops_by_keys`).

    Returns (segment order (s,) int, loop offsets (loops+1,) int, closed_by_join
    (loops,) bool). Loops are sorted by layer, then by their smallest segment
    index; within a loop, segments follow each other end to start, a cycle
    from its smallest segment index. Chains that do not close are kept as loops
    flagged in closed_by_join.
    """
    return loops_by_keys(sections.start_key, sections.end_key)


def signed_areas(points: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Shoelace area of each loop ((loops,) float, mm^2): > 0 counter-clockwise seen from +z."""
    if len(points) == 0:
        return np.zeros(len(offsets) - 1)
    following = np.arange(1, len(points) + 1)
    following[offsets[1:] - 1] = offsets[:-1]
    cross = points[:, 0] * points[following, 1] - points[following, 0] * points[:, 1]
    loop = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
    return 0.5 * np.bincount(loop, weights=cross, minlength=len(offsets) - 1)


def loop_parents(points: np.ndarray, offsets: np.ndarray, layer: np.ndarray, area: np.ndarray) -> np.ndarray:
    """For each loop, the smallest loop of the same layer that contains it, or -1.

    Loops of one layer do not cross, so one vertex decides containment; shapely's
    STRtree answers all loops at once (layers are shifted apart in x so that only
    loops of the same layer meet). Where loops do cross (a self-intersecting mesh), a
    parent is still larger in area than its child, so following parents always ends.
    """
    import shapely

    loops = len(offsets) - 1
    parent = np.full(loops, -1, dtype=np.int64)
    sizes = np.diff(offsets)
    loops_in_layer = np.bincount(layer)[layer]
    usable = np.nonzero((sizes >= 3) & (loops_in_layer >= 2))[0]
    if len(usable) < 2:
        return parent
    shift = layer[usable] * 2.0 * (np.ptp(points[:, 0]) + np.ptp(points[:, 1]) + 1.0)
    # the usable loops' points, each ring closed by its first point again: shapely's ragged layout, which
    # builds the polygons several times faster than from indices
    ring_sizes = sizes[usable] + 1
    ring_offsets = np.concatenate([[0], np.cumsum(ring_sizes)])
    source = np.arange(ring_offsets[-1]) - np.repeat(ring_offsets[:-1] - offsets[usable], ring_sizes)
    source[ring_offsets[1:] - 1] = offsets[usable]
    coords = np.take(points, source, axis=0)
    coords[:, 0] += np.repeat(shift, ring_sizes)
    polygons = shapely.from_ragged_array(shapely.GeometryType.POLYGON, coords,
                                         (ring_offsets, np.arange(len(usable) + 1)))
    probes = shapely.points(coords[ring_offsets[:-1]])
    inner, outer = shapely.STRtree(polygons).query(probes, predicate="within")
    inner, outer = usable[inner], usable[outer]
    # a container is larger: loops that overlap without nesting (a self-intersecting mesh) may each hold the
    # other's first vertex, and a cycle of parents would never end
    keep = np.abs(area[outer]) > np.abs(area[inner])
    inner, outer = inner[keep], outer[keep]
    if len(inner) == 0:
        return parent
    order = np.lexsort((np.abs(area[outer]), inner))
    inner, outer = inner[order], outer[order]
    first = np.concatenate([[True], inner[1:] != inner[:-1]])
    parent[inner[first]] = outer[first]
    return parent


def assign_families(area: np.ndarray, parent: np.ndarray) -> np.ndarray:
    """Profile family of each loop: an outer ring is its own family; a hole joins its parent outer ring.

    A hole without an outer parent (an open or broken mesh) stands as a family of its own.
    """
    own = np.arange(len(area))
    parent_is_outer = (parent >= 0) & (area[np.maximum(parent, 0)] > 0)
    return np.where((area <= 0) & parent_is_outer, parent, own)


def _drop_repeated_points(points, point_edge, point_t, offsets):
    """Remove a loop point equal to its predecessor, and a loop whose points are all one point.

    Repeats only arise where a mesh vertex lies exactly on the plane (t is 0 or 1),
    so only those points are examined. A loop of one point is what an apex exactly on a plane
    leaves (the section just below it shrunk to the apex): zero area, and no loop of the layer.
    Returns the points, edges, positions, offsets and which of the loops are kept ((loops,) bool).
    """
    loops = len(offsets) - 1
    on_vertex = np.nonzero((point_t == 0.0) | (point_t == 1.0))[0]
    if len(on_vertex) == 0:
        return points, point_edge, point_t, offsets, np.ones(loops, dtype=bool)
    loop_of_point = np.repeat(np.arange(loops), np.diff(offsets))
    previous = on_vertex - 1
    loop_first = offsets[loop_of_point[on_vertex]]
    previous[on_vertex == loop_first] = offsets[loop_of_point[on_vertex] + 1][on_vertex == loop_first] - 1
    keep = np.ones(len(points), dtype=bool)
    keep[on_vertex] = ~np.all(points[on_vertex] == points[previous], axis=1)
    kept_any = np.zeros(loops, dtype=bool)
    kept_any[loop_of_point[keep]] = True
    sizes = np.bincount(loop_of_point[keep], minlength=loops)[kept_any]
    new_offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    return points[keep], point_edge[keep], point_t[keep], new_offsets, kept_any


def build_contours(sections: Sections, hierarchy: bool = True) -> Contours:
    """Chain all layers' segments into loops and classify them (outer/hole, families).

    ``hierarchy=False`` skips which loop lies in which (``parent``, ``family`` are None):
    filling a layer by its winding number does not need it, only grading does.
    """
    order, offsets, closed_by_join = chain_loops(sections)
    first_segment = offsets[:-1]
    loop_layer = sections.layer[order[first_segment]] if len(order) else np.zeros(0, np.int64)
    points = np.take(sections.start, order, axis=0)  # row gathers: np.take is several times faster
    point_edge = np.take(sections.start_edge, order, axis=0)
    point_t = sections.start_t[order]
    if closed_by_join.any():  # an open chain also keeps the end point of its last segment
        tails = order[offsets[1:][closed_by_join] - 1]
        at = offsets[1:][closed_by_join]
        points = np.insert(points, at, sections.end_points(tails), axis=0)
        point_edge = np.insert(point_edge, at, sections.end_edge[tails], axis=0)
        point_t = np.insert(point_t, at, sections.end_t[tails])
        offsets = offsets + np.concatenate([[0], np.cumsum(closed_by_join)])
    points, point_edge, point_t, offsets, kept = _drop_repeated_points(points, point_edge, point_t, offsets)
    first_segment, loop_layer, closed_by_join = first_segment[kept], loop_layer[kept], closed_by_join[kept]

    area = signed_areas(points, offsets)
    parent = loop_parents(points, offsets, loop_layer, area) if hierarchy else None
    return Contours(
        points=points,
        point_edge=point_edge,
        point_t=point_t,
        offsets=offsets,
        layer=loop_layer,
        area=area,
        closed_by_join=closed_by_join,
        parent=parent,
        family=assign_families(area, parent) if hierarchy else None,
        face=sections.face[order[first_segment]] if len(order) else np.zeros(0, np.int64),
        layer_offsets=np.searchsorted(loop_layer, np.arange(sections.layer_count + 1), side="left"),
    )
