"""Contours: chain intersection segments into closed loops and organise them into families.

The paper's section II.C and IV.B: segments from :mod:`heoslice.layers.slicing` are linked
end to start through the mesh edge they share (local topology), giving closed
loops oriented by the right-hand rule (outer counter-clockwise seen from +z, holes
clockwise). Open meshes give open chains, which are closed by joining their ends
and reported. Loops are then grouped into profile families, the paper's
O_L = {L_i}, L_i = {C_i,j}: an outer ring with the holes directly inside it.

Everything is vectorised over all layers: every segment has at most one successor,
so the loops are the cycles (and open chains) of the successor map; they are
labelled and ordered by pointer jumping, so there is no Python loop per segment
(and no graph library to import).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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


def successors(start_key: np.ndarray, end_key: np.ndarray) -> np.ndarray:
    """For each segment, the index of the segment starting where it ends, or -1 (open chain).

    Keys are compared exactly; where a non-manifold edge carries several segments,
    the k-th segment ending on it is linked to the k-th segment starting on it.
    Both key lists are sorted together, once: in each run of equal keys the starts
    come first, then the ends, each in index order, and the k-th end of a run takes
    the k-th start of the run.
    """
    count = len(start_key)
    keys = np.concatenate([start_key, end_key])
    order, sorted_keys = _stable_key_sort(keys)
    position = np.arange(len(keys))
    is_end = order >= count
    new_run = np.empty(len(keys), dtype=bool)
    new_run[:1] = True
    np.not_equal(sorted_keys[1:], sorted_keys[:-1], out=new_run[1:])
    run_start = np.maximum.accumulate(np.where(new_run, position, 0))
    first_end = new_run.copy()
    first_end[1:] |= ~is_end[:-1]
    first_end &= is_end
    first_end = np.maximum.accumulate(np.where(first_end, position, 0))  # of the run, at its ends
    partner = run_start + position - first_end  # the k-th start of the run, for its k-th end
    match = is_end & (partner < first_end)
    nxt = np.full(count, -1, dtype=np.int64)
    nxt[np.compress(match, order) - count] = order[np.compress(match, partner)]  # compress: faster than a boolean index
    return nxt


def _stable_key_sort(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(order, keys[order]) of non-negative int64 keys, equal keys in index order.

    When the keys leave room, each index is packed below its key and the packed values
    are sorted with ``np.sort`` (several times faster than a stable ``np.argsort``).
    """
    shift = max(int(len(keys) - 1).bit_length(), 1)
    if len(keys) and int(keys.max()).bit_length() + shift <= 63 and keys.min() >= 0:
        packed = keys << shift
        packed |= np.arange(len(keys))
        packed.sort()
        sorted_keys = packed >> shift
        packed &= (1 << shift) - 1
        return packed, sorted_keys
    order = np.argsort(keys, kind="stable")
    return order, keys[order]


def _rank_paths(nxt: np.ndarray) -> np.ndarray:
    """Steps from each node to the tail of its path (nxt == -1 at tails), by pointer jumping.

    A sentinel node after the last one absorbs the tails, so every round is two
    whole-array gathers and an add, and there are ceil(log2(longest path)) rounds.
    """
    count = len(nxt)
    jump = np.append(np.where(nxt >= 0, nxt, count), count)
    hops = np.append((nxt >= 0).astype(np.int64), 0)
    while not np.all(jump[:count] == count):
        hops += hops[jump]
        jump = jump[jump]
    return hops[:count]


def _label_chains(nxt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The chain (cycle or open path) of each node of a successor map, by pointer jumping.

    nxt: (n,) int, each node's successor or -1 (a tail); no node has two predecessors, so
    the chains are disjoint cycles and paths. Returns (key (n,) int, has_tail (n,) bool):
    nodes of one chain share a key, which is ``-1 - tail`` on a path and the smallest
    index of the cycle on a cycle. Each round takes the minimum of a node's key and
    the key 2**k steps on (a tail's negative key spreads back along its path); the
    rounds stop when a round changes nothing, which on a cycle happens only once the
    minimum has gone all the way round: ceil(log2(longest chain)) + 1 rounds.
    """
    count = len(nxt)
    linked = nxt >= 0
    key = np.arange(count + 1, dtype=np.int64)  # the sentinel ``count`` never lowers a key
    key[:count][~linked] = -1 - key[:count][~linked]
    jump = np.append(np.where(linked, nxt, count), count)
    while True:
        lower = np.minimum(key, key[jump])
        if np.array_equal(lower, key):
            break
        key = lower
        jump = jump[jump]
    return key[:count], key[:count] < 0


def chain_loops(sections: Sections) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Order segments into loops.

    Returns (segment order (s,) int, loop offsets (loops+1,) int, closed_by_join
    (loops,) bool). Loops are sorted by layer, then by their smallest segment
    index; within a loop, segments follow each other end to start, a cycle
    from its smallest segment index. Chains that do not close are kept as loops
    flagged in closed_by_join.
    """
    count = len(sections.layer)
    if count == 0:
        return np.zeros(0, np.int64), np.zeros(1, np.int64), np.zeros(0, bool)
    nxt = successors(sections.start_key, sections.end_key)
    key, on_path = _label_chains(nxt)
    # Number the chains by their key node (the tail of a path, the smallest index of a cycle).
    named = np.where(on_path, -1 - key, key)
    label = np.cumsum(named == np.arange(count)) - 1
    label = label[named]
    components = int(label.max()) + 1
    root = np.full(components, count, dtype=np.int64)
    np.minimum.at(root, label, np.arange(count))
    has_tail = np.zeros(components, dtype=bool)
    has_tail[label[on_path]] = True
    # A cycle is cut before its smallest index; a path already has a tail.
    cut = nxt.copy()
    cut[~on_path & (nxt == root[label])] = -1
    to_tail = _rank_paths(cut)
    # Place each segment directly: loops sorted by layer, then along the loop from its head.
    size = np.bincount(label, minlength=components)
    loop_order = np.lexsort((root, sections.layer[root]))
    offsets = np.zeros(components + 1, dtype=np.int64)
    offsets[1:] = np.cumsum(size[loop_order])
    loop_start = np.empty(components, dtype=np.int64)
    loop_start[loop_order] = offsets[:-1]
    order = np.empty(count, dtype=np.int64)
    order[loop_start[label] + size[label] - 1 - to_tail] = np.arange(count)
    return order, offsets, has_tail[loop_order]


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
