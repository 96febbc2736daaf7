"""Graded interiors: offset sub-regions and multi-ring weighting (the paper's II.D-E, III.B, eq. 8-10).

Inside each profile family (an outer ring with the holes directly inside it) the
solid region is divided into N_R = int(L_S / D_N) sub-regions (eq. 8), L_S being the
shortest distance between the outer ring and its inner rings (or a target depth)
and D_N the nozzle diameter. Sub-region k (1..N_R) gets the material at r = k / N_R
of the distribution function, from the contour's material to the target.

Where r comes from:

* one set of rings (a solid family, or a target depth): r = d / L_S, d the distance
  to the starting rings, so sub-region k is the band between the round-join offsets
  of the contour by (k - 1) w and k w, w = L_S / N_R;
* starting and ending rings (an outer ring with holes): eq. 9-10, the weights
  w_i = prod_{k != i} d_k / sum_j prod_{k != j} d_k, and r is the total weight of
  the ending rings. With one hole this is r = d_o / (d_o + d_i): the position of a
  point is decided by both contours together (Fig. 1), and for rings a constant
  distance apart the sub-regions are again equidistant offsets.

The field is computed without a Python loop per pixel or per cell: exact signed
distances to the rings at the centres of a coarse lattice (cells of about 0.5 mm,
padded by one cell; blocks of cells wholly off the family's side are skipped), one
plane per cell (a quadratic where the field bends and that fits better), checked
against the eight neighbouring centres (across the rings too: s continues smoothly
there) and expanded to pixels. Cells where neither places the sub-region boundaries
within TOLERANCE_PX pixels of the exact ones (medial axis, sharp corners) are
evaluated per pixel: eq. 10 from each ring's distance there, measured exactly or, in
an eq. 10 family, taken from that ring's own quadratic where it fits well enough
(:func:`_ring_models`: each ring's distance is smooth away from its medial axis).
"Exact" means the nearest of every edge that can be nearest (a bound argued where it
is used), measured in float32 from a nearby centre (under 2e-5 mm).
Candidate gathering and the per-pixel loops are compiled
(:mod:`heoslice.regions_compiled`). The solid mask decides which pixels are solid,
so the outline is exact. Rings are measured without their points on the straight line
between their neighbours (where a plane crosses a flat quad's diagonal), so the layers
of an extruded part have the same edges and a family may take the previous layer's
field, or a ring set its lattice passes (:func:`layer_regions`' ``reuse``).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from heoslice.errors import InputError
from heoslice.layers.rasterising import Grid, solid_mask

#: Largest error of a sub-region boundary, in pixels, before a lattice cell is evaluated per pixel.
TOLERANCE_PX = 0.5
#: Target lattice cell size, mm (cells are a whole number of pixels, 4 to 16).
_CELL_MM = 0.5
#: The same for families of one or two convex rings (a disc, a tube's wall): their fields have no
#: creases but the deep medial axis (none where the nearest of several holes changes, none beside a
#: reflex corner), so they fit larger cells, which cost less.
_WIDE_CELL_MM = 0.68
#: Families whose box pixels x ring sets are at most this get every pixel's exact distance, no lattice fit.
DIRECT_PIXELS = 25_000
#: Most per-pixel distances measured and held at once when cells are evaluated per pixel (float32: 16 MB).
_MEASURED_VALUES = 1 << 22
DIRECTIONS = ("in", "out")
#: How far (mm) the disc around an island's pixel centres must stay from the layer's other loops for
#: :func:`_alone_in_boxes`: far beyond the rounding of the rasteriser's inside test.
_DISC_MARGIN_MM = 1e-6
#: Most (family, loop) bounding-box tests made at once by :func:`_alone_in_boxes` (two bools each: 8 MB).
_NEAR_TESTS = 1 << 22


@dataclass(frozen=True)
class RegionSpec:
    """How sub-regions are laid out: nozzle diameter D_N (mm), optional target depth (mm), direction.

    ``direction`` 'in' offsets the outer ring inwards (r = 0 at the outer ring, 1 at the
    inner rings or the depth); 'out' offsets the inner rings outwards (r = 0 at the holes).
    A family without holes is always graded inwards from its outer ring. ``count``
    fixes N_R instead of eq. 8 (the paper's Fig. 3b: 200 offsets).
    """

    nozzle_mm: float = 0.2
    depth_mm: float | None = None
    direction: str = "in"
    count: int | None = None

    def __post_init__(self):
        if self.count is not None and (isinstance(self.count, bool) or int(self.count) != self.count
                                       or self.count < 1):
            raise InputError(f"--offsets: the number of sub-regions must be a whole number >= 1, got {self.count}")
        if not (np.isfinite(self.nozzle_mm) and self.nozzle_mm > 0):
            raise InputError(f"--nozzle: nozzle diameter must be a positive number of mm, got {self.nozzle_mm}")
        if self.depth_mm is not None and not (np.isfinite(self.depth_mm) and self.depth_mm > 0):
            raise InputError(f"--depth: target depth must be a positive number of mm, got {self.depth_mm}")
        if self.direction not in DIRECTIONS:
            raise InputError(f"--direction: expected 'in' or 'out', got {self.direction!r}")


def band_count(length_mm: float, nozzle_mm: float) -> int:
    """Eq. 8: N_R = int(L_S / D_N), at least 1 (a region thinner than the nozzle is one sub-region)."""
    return max(1, int(np.floor(length_mm / nozzle_mm + 1e-9)))


def subregion_index(r: np.ndarray, count: int) -> np.ndarray:
    """Sub-region k in 1..N_R of positions r (r = 0 at the starting ring, 1 at the end): min(floor(r N_R) + 1, N_R)."""
    return np.clip(np.floor(np.asarray(r, dtype=np.float64) * count).astype(np.int64) + 1, 1, count)


def ring_weights(distances: np.ndarray) -> np.ndarray:
    """Eq. 10: weights of beta rings at n points from their distances ((n, beta) float, mm) -> (n, beta).

    w_i = prod_{k != i} d_k / sum_j prod_{k != j} d_k: the weights sum to 1, and a ring's
    weight is 1 on the ring itself (d_i = 0) and falls as the point moves away from it.
    Dividing through by prod_k d_k gives w_i = (1 / d_i) / sum_j (1 / d_j), computed here
    as (d_min / d_i) / sum_j (d_min / d_j), which neither overflows nor underflows; where
    some d_i are 0 those rings share the weight (one ring, unless rings touch).
    """
    d = np.asarray(distances, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] < 1:
        raise ValueError("distances must be (n, beta) with beta >= 1")
    nearest = d.min(axis=1, keepdims=True)
    on_ring = d <= 0
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(on_ring, 0.0, nearest / d)
    ratio = np.where(nearest > 0, ratio, on_ring.astype(np.float64))
    return ratio / ratio.sum(axis=1, keepdims=True)


# ---------------------------------------------------------------------------------------------
# Families of one layer


@dataclass(frozen=True)
class Family:
    """One profile family of a layer: loop indices (within the layer) of its outer ring and holes.

    ``nested`` is True when the outer ring lies inside another family's solid (a shell
    inside a shell, e.g. a lesion in an organ): its region keeps its own material.
    ``depth`` is the number of outer rings around it (families are painted outermost first).
    """

    outer: int
    holes: tuple[int, ...]
    nested: bool
    depth: int


def layer_families(area: np.ndarray, parent: np.ndarray) -> list[Family]:
    """The families of one layer's loops (signed areas (l,), parents (l,) within the layer), outermost first.

    A hole belongs to the family of the outer ring directly around it; a hole with no
    outer ring around it (a broken mesh) is ignored.
    """
    area = np.asarray(area, dtype=np.float64)
    parent = np.asarray(parent, dtype=np.int64)
    outer = np.nonzero(area > 0)[0]
    families = []
    for loop in outer:
        holes = tuple(int(h) for h in np.nonzero((parent == loop) & (area < 0))[0])
        depth, up, nested = 0, parent[loop], bool(parent[loop] >= 0 and area[parent[loop]] > 0)
        for _ in range(len(parent)):  # at most every loop: a cycle of parents (a broken hierarchy) ends too
            if up < 0:
                break
            depth += area[up] > 0
            up = parent[up]
        families.append(Family(int(loop), holes, nested, int(depth)))
    return sorted(families, key=lambda family: (family.depth, family.outer))


# ---------------------------------------------------------------------------------------------
# Exact distances to rings


#: Largest distance (mm) of a ring point from the edge that replaces it for it to be left out of the ring's edges.
_STRAIGHT_MM = 1e-5


@dataclass(frozen=True)
class RingEdges:
    """The edges of some closed rings, flattened: edge i runs from (x[i], y[i]) by (vx[i], vy[i]) (mm).

    ``inv_len2`` is 1 / |v|^2 (0 for a zero-length edge), ``ring`` the ring (position in
    the list given), ``first``/``second`` the indices of its end points in the layer's points.
    Points on the straight line between their neighbours (a plane crossing the diagonal of a
    flat quad, repeated points) are left out: an edge may span several of the layer's
    points. Each ring's edges start at its lowest point in x, then y, wherever its points
    start. ``knots`` ((m,) float) places every point of the rings, and each ring's first
    edge's start again at its end, along the edges: edge i + ring[i] + t at fraction t of
    edge i; ``knot_point`` ((m,) int) is that point's index in the layer's points.
    """

    x: np.ndarray
    y: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    inv_len2: np.ndarray
    ring: np.ndarray
    first: np.ndarray
    second: np.ndarray
    knots: np.ndarray
    knot_point: np.ndarray


def _convex(edges: RingEdges) -> bool:
    """Whether every ring of the edges turns one way only (no reflex vertex; turns under 1e-9 rad ignored)."""
    last = np.r_[np.flatnonzero(np.diff(edges.ring)), len(edges.ring) - 1]
    first = np.r_[0, last[:-1] + 1]
    following = np.arange(1, len(edges.ring) + 1)
    following[last] = first
    cross = edges.vx * edges.vy[following] - edges.vy * edges.vx[following]
    scale = np.sqrt(edges.inv_len2 * edges.inv_len2[following])
    turn = np.sign(np.where(np.abs(cross * scale) > 1e-9, cross, 0.0))
    return bool(np.all(np.minimum.reduceat(turn, first) * np.maximum.reduceat(turn, first) >= 0))


def _loop_points(offsets: np.ndarray, loops: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The indices of the given loops' points in the layer, loop after loop ((n,) int), and their sizes ((l,))."""
    begin = offsets[loops]
    sizes = offsets[loops + 1] - begin
    return np.repeat(begin - (np.cumsum(sizes) - sizes), sizes) + np.arange(int(sizes.sum())), sizes


def _kept_points(points: np.ndarray, offsets: np.ndarray, loops) -> tuple:
    """The given loops' points left as edge starts (:func:`heoslice.regions_compiled.straight_runs`):
    (their indices in the layer in edge order, kept per loop, the loops' points in order, knots, knot_at)."""
    from heoslice.regions_compiled import straight_runs

    loops = np.asarray(loops, dtype=np.int64)
    every, sizes = _loop_points(offsets, loops)
    keep, order, knots, knot_at = straight_runs(points[every, 0], points[every, 1], sizes, _STRAIGHT_MM)
    counts = np.bincount(np.repeat(np.arange(len(loops)), sizes)[keep], minlength=len(loops))
    return every[order[keep[order]]], counts, every, knots, knot_at


def ring_geometry(points: np.ndarray, offsets: np.ndarray, loop_sets) -> list[tuple[bytes, bytes, bytes]]:
    """Each given set of loops' edges (what :func:`ring_edges` keeps) as bytes, the same as their RingEdges'
    :func:`_edges_key`: equal for two layers exactly when their edges are (an extruded part's layers).
    One pass for all the sets (the straight runs of each loop are its own)."""
    if not loop_sets:
        return []
    index, counts, _, _, _ = _kept_points(points, offsets, [loop for loops in loop_sets for loop in loops])
    start = np.concatenate([[0], np.cumsum(counts)])
    keys, first = [], 0
    for loops in loop_sets:
        kept = index[start[first]:start[first + len(loops)]]
        ring = np.repeat(np.arange(len(loops)), counts[first:first + len(loops)])
        keys.append((points[kept, 0].tobytes(), points[kept, 1].tobytes(), ring.tobytes()))
        first += len(loops)
    return keys


def _edges_key(edges: RingEdges) -> tuple[bytes, bytes, bytes]:
    """Edges as bytes (starts x and y, ring of each edge): the key of what another layer measured of them."""
    return edges.x.tobytes(), edges.y.tobytes(), edges.ring.tobytes()


def ring_edges(points: np.ndarray, offsets: np.ndarray, loops) -> RingEdges:
    """Edges of the given loops (indices into offsets) of a layer's points ((p, 2) float, mm), without
    points within _STRAIGHT_MM of the straight line between their neighbours, each ring's from its
    lowest point in x then y round (:func:`heoslice.regions_compiled.straight_runs`)."""
    index, counts, every, knots, knot_at = _kept_points(points, offsets, loops)
    first_kept = np.repeat(np.cumsum(counts) - counts, counts)
    following = index[first_kept + (np.arange(len(index)) - first_kept + 1) % np.repeat(counts, counts)]
    vec = points[following] - points[index]
    length2 = vec[:, 0] ** 2 + vec[:, 1] ** 2
    inv = np.divide(1.0, length2, out=np.zeros_like(length2), where=length2 > 0)
    return RingEdges(x=points[index, 0].copy(), y=points[index, 1].copy(), vx=vec[:, 0].copy(),
                     vy=vec[:, 1].copy(), inv_len2=inv, ring=np.repeat(np.arange(len(counts)), counts), first=index,
                     second=following, knots=knots, knot_point=every[knot_at])


@dataclass(frozen=True)
class Lattice:
    """A coarse lattice over a pixel box: cells of ``cell`` x ``cell`` pixels.

    Cell (i, j) covers pixel rows row0 + i*cell .. +cell and columns col0 + j*cell ..;
    its centre is at x = x0 + (j + 1/2) dx, y = y0 - (i + 1/2) dy (mm).
    """

    row0: int
    col0: int
    cell: int
    rows: int
    cols: int
    x0: float
    y0: float
    dx: float
    dy: float

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """x ((cols,)) and y ((rows,)) of the cell centres, mm."""
        return (self.x0 + (np.arange(self.cols) + 0.5) * self.dx,
                self.y0 - (np.arange(self.rows) + 0.5) * self.dy)


def _padded(lattice: Lattice) -> Lattice:
    """The lattice grown by one cell on every side (cell (i, j) of ``lattice`` is its cell (i + 1, j + 1))."""
    return Lattice(row0=lattice.row0 - lattice.cell, col0=lattice.col0 - lattice.cell, cell=lattice.cell,
                   rows=lattice.rows + 2, cols=lattice.cols + 2, x0=lattice.x0 - lattice.dx,
                   y0=lattice.y0 + lattice.dy, dx=lattice.dx, dy=lattice.dy)


def lattice_for(box: tuple[int, int, int, int], grid: Grid, cell_mm: float = _CELL_MM) -> Lattice:
    """A lattice covering pixel rows box[0]:box[1] and columns box[2]:box[3] of ``grid``."""
    cell = int(np.clip(round(cell_mm / max(grid.px, grid.py)), 4, 16))
    row0, row1, col0, col1 = box
    rows = max(1, -(-(row1 - row0) // cell))
    cols = max(1, -(-(col1 - col0) // cell))
    return Lattice(row0=row0, col0=col0, cell=cell, rows=rows, cols=cols,
                   x0=grid.x_left + col0 * grid.px, y0=grid.y_top - row0 * grid.py,
                   dx=cell * grid.px, dy=cell * grid.py)


def ring_tree(edges: RingEdges) -> tuple:
    """A bounding-box hierarchy over the edges (ring order), for :func:`nearest_edges`."""
    from heoslice.regions_compiled import edge_tree

    return edge_tree(edges.x, edges.y, edges.x + edges.vx, edges.y + edges.vy)


def nearest_edges(cx: np.ndarray, cy: np.ndarray, radius: np.ndarray, ox: np.ndarray, oy: np.ndarray,
                  edges: RingEdges, tree: tuple, track: bool = True) -> np.ndarray:
    """The nearest edge ((g, k) int, -1: none), or without ``track`` the squared distance to it ((g, k)
    mm^2), of the points (cx + ox[k], cy + oy[k]) ((g,), (k,) mm) among the edges within radius[g]
    of (cx[g], cy[g]) (compiled, :func:`heoslice.regions_compiled.nearest_in_groups`)."""
    from heoslice.regions_compiled import nearest_in_groups

    return nearest_in_groups(cx, cy, radius, ox, oy, edges.x, edges.y, edges.vx, edges.vy, edges.inv_len2, tree,
                             track)


#: Lattice cells per side of the blocks whose centres share candidate edges in :func:`lattice_edges`.
_BLOCK = 8


@dataclass(frozen=True)
class BlockBounds:
    """An upper bound of the distance to a ring set at the centres of blocks of _BLOCK x _BLOCK cells.

    ``blocks`` is the block lattice; per block ((rows, cols)): ``edge`` the edge found nearest
    its centre and ``upper`` the exact distance to it (mm).
    """

    blocks: Lattice
    edge: np.ndarray
    upper: np.ndarray


def block_bounds(edges: RingEdges, lattice: Lattice, tree: tuple) -> BlockBounds:
    """Upper bounds of the distance at block centres: the exact distance to the edge found nearest each
    centre (:func:`nearest_edges`, in float32, among the edges within the centre's distance to the rings'
    first point, which holds the nearest)."""
    from heoslice.regions_compiled import feet

    b = _BLOCK
    blocks = Lattice(row0=lattice.row0, col0=lattice.col0, cell=lattice.cell * b, rows=-(-lattice.rows // b),
                     cols=-(-lattice.cols // b), x0=lattice.x0, y0=lattice.y0, dx=lattice.dx * b, dy=lattice.dy * b)
    x, y = blocks.centres()
    cx = np.broadcast_to(x, (blocks.rows, blocks.cols)).ravel()
    cy = np.broadcast_to(y[:, None], (blocks.rows, blocks.cols)).ravel()
    reach = np.hypot(cx - edges.x[0], cy - edges.y[0]) * (1 + 1e-6) + 1e-6
    edge = nearest_edges(cx, cy, reach, np.zeros(1), np.zeros(1), edges, tree)[:, 0].astype(np.int64)
    upper = feet(cx, cy, edge, edges.x, edges.y, edges.vx, edges.vy, edges.inv_len2)[0]
    shape = (blocks.rows, blocks.cols)
    return BlockBounds(blocks, edge.reshape(shape), upper.reshape(shape))


def lattice_edges(edges: RingEdges, lattice: Lattice, tree: tuple | None = None,
                  bounds: BlockBounds | None = None, wanted: np.ndarray | None = None) -> np.ndarray:
    """The nearest edge of the rings to every cell centre ((rows, cols) int).

    Centres are taken in blocks of _BLOCK x _BLOCK cells. A block's centre C has an
    upper bound U of its distance (:func:`block_bounds`). A centre p at a = |p - C| from
    C has d(p) <= U + a (the distance is 1-Lipschitz), so its nearest edge is within
    U + 2 a of C: every edge within U + 2 max a of C is a candidate, and the nearest is
    exact. Blocks not ``wanted`` ((rows, cols) bool over the blocks; default all) are not
    measured: their centres get the edge found nearest their block's centre (its distance an upper bound).
    """
    if tree is None:
        tree = ring_tree(edges)
    if bounds is None:
        bounds = block_bounds(edges, lattice, tree)
    blocks, b = bounds.blocks, _BLOCK
    edge = np.repeat(bounds.edge[:, :, None], b * b, axis=2)
    chosen = np.nonzero(np.ones(bounds.edge.shape, bool) if wanted is None else wanted)
    if len(chosen[0]):
        x, y = blocks.centres()
        v, u = (a.ravel() for a in np.meshgrid(np.arange(b), np.arange(b), indexing="ij"))
        ox, oy = (u + 0.5 - 0.5 * b) * lattice.dx, -(v + 0.5 - 0.5 * b) * lattice.dy
        edge[chosen] = nearest_edges(x[chosen[1]], y[chosen[0]], bounds.upper[chosen] + 2.0 * np.hypot(ox, oy).max(),
                                     ox, oy, edges, tree)
    edge = edge.reshape(blocks.rows, blocks.cols, b, b).transpose(0, 2, 1, 3).reshape(blocks.rows * b, blocks.cols * b)
    return edge[:lattice.rows, :lattice.cols]


def _inside_loops(rings: RingSet, lattice: Lattice) -> np.ndarray:
    """(rows, cols) bool: cell centres inside any of the ring set's loops (a family's holes, or its outer
    ring: they neither cross nor nest, so the parity of crossings decides)."""
    from heoslice.regions_compiled import inside_centres

    e = rings.edges
    return inside_centres(e.x, e.y, e.vx, e.vy, lattice.x0, lattice.y0, lattice.dx, lattice.dy, lattice.rows,
                          lattice.cols)


# ---------------------------------------------------------------------------------------------
# The band coordinate s = r * N_R of one family


@dataclass(frozen=True)
class FamilyLayout:
    """How one family is graded: ring sets (start first), N_R, band width, L_S (mm)."""

    start: tuple[int, ...]
    end: tuple[tuple[int, ...], ...]
    count: int
    length_mm: float


def family_layout(family: Family, spec: RegionSpec, inradius: float | None = None,
                  apart: float | None = None) -> FamilyLayout:
    """Which rings start and end the grading of a family, and N_R by eq. 8.

    L_S is the target depth when given; otherwise the shortest distance between the
    starting and ending rings (``apart``, mm: :func:`rings_apart` of the outer ring and
    the holes); for a family without holes, its largest inscribed distance
    (``inradius``, mm), so that the target is reached at its deepest point.
    """
    holes = family.holes

    def count(length: float) -> int:
        return int(spec.count) if spec.count is not None else band_count(length, spec.nozzle_mm)

    if spec.direction == "out" and holes:
        start, end = holes, ((family.outer,),)
    else:
        start, end = (family.outer,), tuple((hole,) for hole in holes)
    if spec.depth_mm is not None:
        return FamilyLayout(start, (), count(spec.depth_mm), float(spec.depth_mm))
    length = float((apart if holes else inradius) or 0.0)
    return FamilyLayout(start, end if holes else (), count(length), max(length, 1e-9))


def rings_apart(first: RingSet, second: RingSet) -> float:
    """Shortest distance (mm) between two sets of rings that do not cross.

    It is reached at a vertex of one set (the nearest point of the other can be anywhere
    on an edge), so it is the least vertex-to-edge distance both ways; the nearest pair
    among a sample of vertices bounds it, so only chunks of edges that close are measured
    (:func:`heoslice.regions_compiled.edge_sets_apart`).
    """
    from heoslice.regions_compiled import edge_sets_apart

    a = np.column_stack([first.edges.x, first.edges.y, first.edges.vx, first.edges.vy, first.edges.inv_len2])
    b = np.column_stack([second.edges.x, second.edges.y, second.edges.vx, second.edges.vy, second.edges.inv_len2])
    sample_a, sample_b = a[::max(1, len(a) // 64)], b[::max(1, len(b) // 1024)]
    across = sample_a[:, 0, None] - sample_b[None, :, 0]
    along = sample_a[:, 1, None] - sample_b[None, :, 1]
    bound = float(np.sqrt((across * across + along * along).min())) * (1 + 1e-12) + 1e-12
    return edge_sets_apart(a, first.tree, b, second.tree, bound)


def _rings_apart_kept(first: RingSet, second: RingSet, before: dict, now: dict) -> float:
    """:func:`rings_apart`, taken from ``before`` (what the last layer measured, by the two sets' keys) when
    there, and kept in ``now``."""
    key = ("apart", first.key, second.key)
    apart = before.get(key)
    if apart is None:
        apart = now.get(key)
    if apart is None:
        apart = rings_apart(first, second)
    now[key] = apart
    return apart


def _band_coordinate(layout: FamilyLayout, d: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """s = r * N_R and its gradient from the signed distances d and gradients g to the starting rings (d[0])
    and each ending ring.

    One ring set: s = d N_R / L_S. Several: r = 1 - w_start of eq. 10, which divided
    through by the product of all d is r = u / (1 + u), u = d_start * sum_end 1 / d_k.
    Taken with the ending ring m nearest in |d| as r = d_start A / (d_m + d_start A),
    A = 1 + d_m * sum_{k != m} 1 / d_k, it has no pole on any ring: with signed distances
    (< 0 off the family's side) s continues smoothly across the rings, so the lattice
    cells a contour crosses are fitted and checked like any other. Where the continuation
    passes a pole (d_m + d_start A <= 0, deep off the family's side) s is NaN. Distances
    (sets, rows, cols) mm, gradients (sets, rows, cols, 2); several ring sets compiled
    (:func:`heoslice.regions_compiled.band_field`).
    """
    from heoslice.regions_compiled import band_field

    if not layout.end:
        scale = layout.count / layout.length_mm
        return d[0] * scale, g[0] * scale
    return band_field(d, g, layout.count)


# ---------------------------------------------------------------------------------------------
# Per-family field


@dataclass(frozen=True)
class RingSet:
    """Rings whose nearest one gives a distance: loops (within the layer), their edges, and whether
    the family's region is inside them (an outer ring) or outside (holes); ``key`` (encloses and the
    edges as bytes, made by :func:`family_field`) finds what another layer measured of the same rings."""

    loops: tuple[int, ...]
    edges: RingEdges
    encloses: bool
    tree: tuple
    key: tuple = ()


def ring_set(points: np.ndarray, offsets: np.ndarray, loops, encloses: bool) -> RingSet:
    """The ring set of some loops of a layer, with its edges and their bounding-box hierarchy."""
    edges = ring_edges(points, offsets, loops)
    return RingSet(tuple(loops), edges, encloses, ring_tree(edges))


@dataclass(frozen=True)
class RingMeasures:
    """One ring set's passes over a family's padded lattice: its block bounds, the cell centres inside
    it, the blocks off the family's side of it (``far``), and the exact nearest edge ((rows, cols) int)
    of the cells of the blocks measured so far (``done``, (block rows, block cols) bool; elsewhere
    ``edge`` means nothing); ``centres`` the blocks last wanted of :func:`_measured_centres` and what it
    gave for them (read-only arrays). A pure function
    of the ring set's edges and the lattice, so a layer with the same edges (an extruded hole) reuses it."""

    bounds: BlockBounds
    inside: np.ndarray
    far: np.ndarray
    edge: np.ndarray
    done: np.ndarray
    centres: tuple = ()


def _ring_measures(rings: RingSet, lattice: Lattice) -> RingMeasures:
    """A ring set's RingMeasures on a lattice, no block's edges measured yet."""
    bounds = block_bounds(rings.edges, lattice, rings.tree)
    inside = _inside_loops(rings, lattice)
    far = _far_side(rings, inside, bounds, lattice)
    return RingMeasures(bounds, inside, far, np.zeros((lattice.rows, lattice.cols), dtype=np.int64),
                        np.zeros(far.shape, dtype=bool))


def _measured_centres(rings: RingSet, measures: RingMeasures, lattice: Lattice, wanted: np.ndarray
                      ) -> tuple[tuple, RingMeasures]:
    """At every cell centre: signed distance to the rings (> 0 on the family's side), its unit gradient, foot
    and edge, exact in the ``wanted`` blocks ((block rows, block cols) bool; elsewhere from the edge nearest
    the block's centre, :func:`lattice_edges`), measuring only the blocks ``measures`` does not hold yet:
    ((signed, gradient, foot, edge), the measures with them). The same blocks wanted as the last time give
    the last answer (a hole that stays while another ring of its family changes, as through a cavity)."""
    from heoslice.regions_compiled import signed_feet

    if measures.centres and np.array_equal(measures.centres[0], wanted):
        return measures.centres[1], measures
    if not measures.done.any():
        edge = lattice_edges(rings.edges, lattice, rings.tree, measures.bounds, wanted)
        measures = replace(measures, edge=edge, done=wanted)
    else:
        todo = wanted & ~measures.done
        if todo.any():
            fresh = lattice_edges(rings.edges, lattice, rings.tree, measures.bounds, todo)
            measures = replace(measures, edge=np.where(_block_cells(todo, lattice), fresh, measures.edge),
                               done=measures.done | todo)
        seeds = lattice_edges(rings.edges, lattice, rings.tree, measures.bounds, np.zeros_like(wanted))
        edge = np.where(_block_cells(wanted, lattice), measures.edge, seeds)
    e = rings.edges
    at = signed_feet(edge, lattice.x0, lattice.y0, lattice.dx, lattice.dy, e.x, e.y, e.vx, e.vy, e.inv_len2,
                     measures.inside, rings.encloses) + (edge,)
    for array in at:
        array.flags.writeable = False
    return at, replace(measures, centres=(wanted, at))


def _block_cells(blocks: np.ndarray, lattice: Lattice) -> np.ndarray:
    """(rows, cols) bool over the lattice's cells from (block rows, block cols) bool over its blocks."""
    return np.repeat(np.repeat(blocks, _BLOCK, axis=0), _BLOCK, axis=1)[:lattice.rows, :lattice.cols]


@dataclass(frozen=True)
class FamilyField:
    """The sub-region index of one family over its pixel box.

    ``index``: (rows, cols) int16/int32, k in 1..N_R (valid on the family's solid
    pixels; the caller masks; in :class:`LayerRegions` the outermost family's index,
    when its box is the layer's, is the label array itself); ``box`` = (row0, row1, col0, col1) of the grid;
    ``layout`` its rings and N_R; ``lattice``; ``nearest()`` gives per cell the nearest point
    on the starting rings (foot (2, cells_r, cells_c) mm) and its edge ((cells_r, cells_c)
    into ``start_edges()``, the starting rings' edges in this layer's points), to take the
    contour's material there (measured on first call for a nested shell, whose own material
    usually makes it unneeded, and for a small family labelled from exact distances,
    :func:`_exact_index`; ``start_edges()`` made on first call for a field another layer measured).
    """

    box: tuple[int, int, int, int]
    index: np.ndarray
    layout: FamilyLayout
    lattice: Lattice
    start_edges: Callable[[], RingEdges]
    nearest: Callable[[], tuple[np.ndarray, np.ndarray]]


def family_box(edges: RingEdges, grid: Grid) -> tuple[int, int, int, int]:
    """Pixel box (row0, row1, col0, col1) of the pixel centres inside the bounding box of a ring's edges."""
    low, high = (edges.x.min(), edges.y.min()), (edges.x.max(), edges.y.max())
    col0 = int(np.clip(np.floor((low[0] - grid.x_left) / grid.px - 0.5), 0, grid.width))
    col1 = int(np.clip(np.ceil((high[0] - grid.x_left) / grid.px + 0.5), 0, grid.width))
    row0 = int(np.clip(np.floor((grid.y_top - high[1]) / grid.py - 0.5), 0, grid.height))
    row1 = int(np.clip(np.ceil((grid.y_top - low[1]) / grid.py + 0.5), 0, grid.height))
    return row0, row1, col0, col1


def _far_side(rings: RingSet, inside: np.ndarray, bounds: BlockBounds, lattice: Lattice) -> np.ndarray:
    """(rows, cols) bool over the blocks: the block's cells and their neighbours are all off the family's
    side of the rings, so nothing there is needed for the family's pixels.

    Each block is judged at one of its cells (``inside``: (rows, cols) bool over the
    lattice, cell centres inside the rings): off the family's side by more than the way
    to the block's farthest cell centre plus a cell's diagonal and a half, measured
    exactly where the block's upper bound allows it.
    """
    b = _BLOCK
    first_r, first_c = np.arange(bounds.blocks.rows) * b, np.arange(bounds.blocks.cols) * b
    rep_r = np.minimum(first_r + b // 2, lattice.rows - 1)
    rep_c = np.minimum(first_c + b // 2, lattice.cols - 1)
    span_r = np.maximum(rep_r - first_r, np.minimum(first_r + b - 1, lattice.rows - 1) - rep_r) * lattice.dy
    span_c = np.maximum(rep_c - first_c, np.minimum(first_c + b - 1, lattice.cols - 1) - rep_c) * lattice.dx
    margin = np.hypot(span_r[:, None], span_c[None, :]) + 1.5 * np.hypot(lattice.dx, lattice.dy)
    x, y = lattice.centres()
    bx, by = bounds.blocks.centres()
    reach = bounds.upper + np.hypot((x[rep_c] - bx)[None, :], (y[rep_r] - by)[:, None])
    far = (inside[np.ix_(rep_r, rep_c)] != rings.encloses) & (reach > margin)
    if far.any():
        rows, cols = np.nonzero(far)
        squared = nearest_edges(x[rep_c[cols]], y[rep_r[rows]], reach[far] * (1 + 1e-9) + 1e-9, np.zeros(1),
                                np.zeros(1), rings.edges, rings.tree, track=False)
        far[rows, cols] = squared.ravel() > margin[far] ** 2
    return far


def family_field(points: np.ndarray, offsets: np.ndarray, family: Family, grid: Grid,
                 spec: RegionSpec, pixels: bool = True, mask: np.ndarray | None = None,
                 label_base: int = 0, measured: tuple[dict, dict] | None = None) -> FamilyField:
    """Sub-region index k (1..N_R) at every pixel of a family's box (see the module docstring).

    With ``pixels`` False only the lattice is measured (a nested shell, which keeps its
    own material, needs its cells' nearest contour points but no sub-regions): ``index``
    is then empty and N_R is 1. With the layer's solid ``mask`` ((h, w) bool) ``index``
    holds labels instead: k + label_base on solid pixels, 0 elsewhere.

    ``measured`` (before, now): what the previous layer measured of ring sets with these
    very edges, read from ``before``: their edge trees (by RingSet.key) and lattice passes
    (:class:`RingMeasures`, by key and lattice); this family's go into ``now``
    (:func:`layer_regions` keeps them a layer).
    """
    made: dict[tuple, RingSet] = {}
    measured_before, measured_now = measured if measured is not None else ({}, {})

    def rings(loops, encloses: bool) -> RingSet:
        if (tuple(loops), encloses) not in made:
            edges = ring_edges(points, offsets, loops)
            key = (encloses, *_edges_key(edges))
            tree = measured_before.get(key) or measured_now.get(key) or ring_tree(edges)
            measured_now[key] = tree
            made[tuple(loops), encloses] = RingSet(tuple(loops), edges, encloses, tree, key)
        return made[tuple(loops), encloses]

    # everything below reads the rings' edges only, not their straight points (so a layer may reuse another's)
    outer = rings((family.outer,), True)
    box = family_box(outer.edges, grid)
    row0, row1, col0, col1 = box
    outward = spec.direction == "out" and bool(family.holes)
    # a small family takes every pixel's exact distance to each ring set (family_layout's ends and its start)
    end_sets = 0 if spec.depth_mm is not None or not family.holes else 1 if outward else len(family.holes)
    direct = pixels and (row1 - row0) * (col1 - col0) * (1 + end_sets) <= DIRECT_PIXELS
    smooth = (not direct and len(family.holes) <= 1 and _convex(outer.edges)
              and (not family.holes or _convex(rings(family.holes, False).edges)))
    lattice = lattice_for(box, grid, _WIDE_CELL_MM if smooth else _CELL_MM)

    start_loops = family.holes if outward else (family.outer,)
    start = rings(start_loops, not outward)

    @functools.cache
    def nearest():
        measures = _ring_measures(start, lattice)
        at, _ = _measured_centres(start, measures, lattice, ~measures.far)
        return at[2], at[3]

    if not pixels:
        return FamilyField(box=box, index=np.zeros((0, 0), np.int16), layout=FamilyLayout(start_loops, (), 1, 1.0),
                           lattice=lattice, start_edges=lambda: start.edges, nearest=nearest)
    inradius = None
    if not family.holes and spec.depth_mm is None:
        import shapely

        outline = shapely.Polygon(np.column_stack([outer.edges.x, outer.edges.y]))
        inradius = float(shapely.maximum_inscribed_circle(outline, 0.5 * min(grid.px, grid.py)).length)
    apart = None
    if family.holes and spec.depth_mm is None and outward:
        apart = rings_apart(outer, rings(family.holes, False))
    elif family.holes and spec.depth_mm is None:
        # hole by hole (the rings the grading ends at, measured anyway), each pair kept for the next layer: through
        # a cavity, only the outer ring's distance to the cavity is new
        apart = min(_rings_apart_kept(outer, rings((hole,), False), measured_before, measured_now)
                    for hole in family.holes)
    layout = family_layout(family, spec, inradius, apart)
    ends = [rings(loops, outward) for loops in layout.end]
    if direct:
        index = _exact_index(lattice, grid, layout, [start] + ends, (row1 - row0, col1 - col0), mask, label_base)
        return FamilyField(box=box, index=index, layout=layout, lattice=lattice, start_edges=lambda: start.edges,
                           nearest=nearest)
    # measured on the lattice padded by a cell, so that every cell of the family has its eight neighbours
    padded = _padded(lattice)
    measures = [measured_before.get((rings.key, padded)) or _ring_measures(rings, padded) for rings in [start] + ends]
    wanted = ~np.logical_or.reduce([m.far for m in measures])
    centres = [_measured_centres(rings, m, padded, wanted) for rings, m in zip([start] + ends, measures)]
    measured_now.update(((rings.key, padded), m) for rings, (_, m) in zip([start] + ends, centres))
    start_at, ends_at = centres[0][0], [at for at, _ in centres[1:]]
    d = np.stack([start_at[0]] + [at[0] for at in ends_at])
    g = np.stack([start_at[1]] + [at[1] for at in ends_at])
    s, grad = _band_coordinate(layout, d, g)

    # a cell may hold solid pixels when its centre is within half a diagonal of the family's side
    reach = -0.5 * np.hypot(lattice.dx, lattice.dy)
    touched = np.logical_and.reduce([start_at[0] >= reach] + [at[0] >= reach for at in ends_at])
    touched[[0, -1], :] = touched[:, [0, -1]] = False
    # deep enough that every pixel of the cell is in the last sub-region (s >= N_R - 1 throughout)
    half_diagonal = 0.5 * np.hypot(lattice.dx, lattice.dy)
    beyond = (s - np.hypot(grad[..., 0], grad[..., 1]) * half_diagonal >= layout.count) | ~touched
    # a cell gets a quadratic where it fits better than a plane: eq. 10's field bends everywhere, one ring's
    # distance field around its medial axis (the centre of a disc)
    hessian = _hessian(grad, padded)
    candidate = touched & ~beyond
    known = np.isfinite(s) & np.isfinite(grad[..., 0]) & np.isfinite(grad[..., 1])
    side = np.logical_and.reduce([start_at[0] >= 0] + [at[0] >= 0 for at in ends_at])
    vertices = _ring_vertices([(start, 0.0)] + [(rings, float(layout.count)) for rings in ends], padded)
    refine = _refine(s, grad, known, side, candidate, padded, grid, layout.count, hessian, vertices)
    refined = np.nonzero(refine)  # never on the padded lattice's border: its cells are no candidates
    models = [None] * (1 + len(ends))
    if layout.end and len(refined[0]):
        models = _ring_models(layout, d, g, grad, padded, grid, refined)
    inner = (slice(1, -1), slice(1, -1))
    s, grad, beyond, candidate, refine, known, touched = (a[inner] for a in (s, grad, beyond, candidate, refine, known,
                                                                             touched))
    hessian = hessian[:, 1:-1, 1:-1]
    if not known.all():
        # cells without s are refined or hold no solid pixel: expanded from 0
        s, grad = np.where(known, s, 0.0), np.where(known[..., None], grad, 0.0)
    index = _expand_planes(lattice, s, grad, grid, beyond, layout.count, (row1 - row0, col1 - col0), mask, label_base,
                           ~touched)
    curved = np.nonzero((hessian != 0).any(axis=0) & candidate & ~refine)
    if len(curved[0]):
        from heoslice.regions_compiled import curve_cells

        curve_cells(index, curved[0], curved[1], lattice.cell, s, grad, hessian, grid.px, grid.py, layout.count,
                    mask, (lattice.row0, lattice.col0), label_base)
    if len(refined[0]):
        cells = (refined[0] - 1, refined[1] - 1)
        _refine_cells(index, lattice, cells, grid, layout,
                      [(rings, np.abs(at[0][inner][cells]), model)
                       for rings, at, model in zip([start] + ends, [start_at] + ends_at, models)], mask, label_base)
    foot, edge = start_at[2][:, 1:-1, 1:-1], start_at[3][inner]
    return FamilyField(box=box, index=index, layout=layout, lattice=lattice,
                       start_edges=lambda: start.edges, nearest=lambda: (foot, edge))


def _exact_index(lattice: Lattice, grid: Grid, layout: FamilyLayout, ring_sets: list[RingSet],
                 shape: tuple[int, int], mask: np.ndarray | None = None, label_base: int = 0) -> np.ndarray:
    """k at every pixel of a small family's box ((rows, cols), labelled like :func:`_expand_planes`),
    each from its exact distance to every ring set (:func:`_refine_cells` over every cell).

    Below DIRECT_PIXELS (box pixels x ring sets) this beats fitting the lattice, whose fixed
    cost (~2.5 ms a family) dominates a small island's; each cell's bound is its distance
    to a ring set's first point."""
    index = np.empty(shape, dtype=_index_dtype(layout.count + label_base))
    ci, cj = (a.ravel() for a in np.indices((lattice.rows, lattice.cols)))
    x, y = lattice.centres()
    bounds = [np.hypot(x[cj] - rings.edges.x[0], y[ci] - rings.edges.y[0]) for rings in ring_sets]
    _refine_cells(index, lattice, (ci, cj), grid, layout,
                  [(rings, bound, None) for rings, bound in zip(ring_sets, bounds)], mask, label_base)
    return index


def _index_dtype(largest: int) -> type:
    """int16 for labels up to 32000, else int32."""
    return np.int16 if largest < 32000 else np.int32


def _hessian(grad: np.ndarray, lattice: Lattice) -> np.ndarray:
    """(3, rows, cols) s_xx, s_xy, s_yy per mm^2 at the cell centres: central differences of the exact
    gradients ((rows, cols, 2) per mm, y up) of neighbouring centres (one-sided at the border;
    zero along an axis the lattice is one cell wide in, and all zero where a neighbour's
    gradient is unknown (past a pole of eq. 10's continuation): no quadratic there)."""
    from heoslice.regions_compiled import hessian_of

    return hessian_of(grad, lattice.dx, lattice.dy)


def _refine(s: np.ndarray, grad: np.ndarray, known: np.ndarray, side: np.ndarray, candidate: np.ndarray,
            lattice: Lattice, grid: Grid, count: int, hessian: np.ndarray | None = None,
            vertices: tuple | None = None) -> np.ndarray:
    """(rows, cols) bool: candidate cells where one plane (or, with a ``hessian``, one quadratic:
    whichever fits better; the Hessian is zeroed where the plane is kept) does not place the
    sub-region boundaries within TOLERANCE_PX pixels, so they are evaluated per pixel.

    A plane that misses s at a neighbour's centre by more than twice TOLERANCE_PX pixels
    at the local slope misses it at the shared border by more than TOLERANCE_PX, which
    matters only if a boundary (an integer of s) can lie in the cell: not where the
    plane's range over the cell, widened by that miss, holds one sub-region (where eq.
    10's field flattens out, a tiny slope makes every miss "large"). Neighbours off the
    family's side count too: s continues smoothly across the rings (signed distances,
    :func:`_band_coordinate`), and where that continuation bends (outside a corner, past
    another part of the ring) it only makes the test stricter. Next to the outline (some
    neighbour off the family's ``side``, or its s not ``known``: past a pole of eq. 10's
    continuation) features smaller than a cell (a notch, a sharp corner) hide between the
    centres; there, where the field's direction turns towards a neighbour by an angle a,
    a plane misplaces a boundary by about cell * sin(a) / 2 pixels, which the misfit test
    may not see: such cells are refined, unless the quadratic's own gradient follows the
    turn to every neighbour and it gives the exact s (0 on a starting ring, N_R on an ending
    one) within TOLERANCE_PX at the ring ``vertices`` around the cell (:func:`_ring_vertices`):
    a round outline's steady turn, not a hidden notch, whose tip is a vertex.
    """
    from heoslice.regions_compiled import refine_flags

    tolerance = 2.0 * TOLERANCE_PX * min(grid.px, grid.py)
    limit = np.sqrt(max(0.0, 1.0 - (2.0 * TOLERANCE_PX / lattice.cell) ** 2))
    return refine_flags(s, grad, known, side, candidate, lattice.dx, lattice.dy, tolerance, limit, count, hessian,
                        vertices)


def _ring_vertices(ring_sets: list[tuple[RingSet, float]], lattice: Lattice) -> tuple:
    """The vertices of the given ring sets, each with the exact s on its rings, grouped by the lattice
    cell holding them: (start (rows * cols + 1,) int, x, y, s, x0, y0) for :func:`_refine`."""
    x = np.concatenate([rings.edges.x for rings, _ in ring_sets])
    y = np.concatenate([rings.edges.y for rings, _ in ring_sets])
    s = np.concatenate([np.full(len(rings.edges.x), value) for rings, value in ring_sets])
    col = np.floor((x - lattice.x0) / lattice.dx).astype(np.int64)
    row = np.floor((lattice.y0 - y) / lattice.dy).astype(np.int64)
    keep = (col >= 0) & (col < lattice.cols) & (row >= 0) & (row < lattice.rows)
    key = (row * lattice.cols + col)[keep]
    order = np.argsort(key, kind="stable")
    start = np.concatenate([[0], np.cumsum(np.bincount(key, minlength=lattice.rows * lattice.cols))])
    return start, x[keep][order], y[keep][order], s[keep][order], lattice.x0, lattice.y0


def _expand_planes(lattice: Lattice, s: np.ndarray, grad: np.ndarray, grid: Grid, flat: np.ndarray, count: int,
                   shape: tuple[int, int], mask: np.ndarray | None = None, label_base: int = 0,
                   empty: np.ndarray | None = None) -> np.ndarray:
    """k = clip(floor(s) + 1, 1, N_R) at every pixel of the family's box ((rows, cols) int16, int32
    past 32000 labels) from one plane per cell (compiled); a ``flat`` cell takes its centre's
    value throughout, an ``empty`` one (none of the family's pixels) 0. With the layer's
    ``mask``: k + label_base on solid pixels, else 0."""
    from heoslice.regions_compiled import expand_planes

    s = np.where(flat, np.clip(s, -1.0, count - 0.5), s)
    gx = np.where(flat, 0.0, grad[..., 0])
    gy = np.where(flat, 0.0, grad[..., 1])
    out = np.empty(shape, dtype=_index_dtype(count + label_base))
    return expand_planes(s, gx, gy, lattice.cell, grid.px, grid.py, count, out, mask,
                         (lattice.row0, lattice.col0), label_base, empty)


def _ring_models(layout: FamilyLayout, d: np.ndarray, g: np.ndarray, grad: np.ndarray, lattice: Lattice, grid: Grid,
                 cells: tuple[np.ndarray, np.ndarray]) -> list[np.ndarray]:
    """Per ring set of an eq. 10 family, a quadratic of its signed distance over each given cell
    ((n, 6): d, d_x, d_y, d_xx, d_xy, d_yy at the centre, mm), NaN where the exact distance
    must be measured per pixel instead.

    eq. 10's s bends where no plane or quadratic of s fits, yet each ring's own distance
    is smooth there unless the cell holds that ring's medial axis. A ring's quadratic
    (exact value and gradient, the Hessian from its neighbours' gradients) that misses
    the exact distance at the eight neighbouring centres by m_j moves s by at most about
    |ds/dd_j| m_j / 2 inside the cell (linear growth, the worst case: a kink), and s off
    by e moves a boundary by e / |grad s| mm; so rings are modelled, cheapest
    first, while the sum of |ds/dd_j| m_j (|ds/dd_j| the largest, |grad s| the smallest
    over the cell and its neighbours, or a bound of it over the cell's pixels on the family's
    side where smaller: it holds beside a pole of eq. 10's continuation too) stays within
    TOLERANCE_PX pixels of s; the others are measured. The bounds: on the family's side every d >= 0, so
    A >= 1 and D >= d_m + d_0 A (:func:`_band_coordinate`), whence |ds/dd_0| <= N_R / (4 d_0) and, for
    every ending ring k, |ds/dd_k| <= N_R d_m / (4 d_k^2), taken over the cell's pixels (within half a
    diagonal h of its centre: d - h, d_m + h). ``d`` (sets, rows, cols) mm and ``g`` (sets, rows, cols, 2) are
    the signed distance and gradient over the (padded) ``lattice`` of the starting rings then each ending
    ring, ``grad`` s's gradient there; ``cells`` index that lattice and are not on its border. Compiled
    (:func:`heoslice.regions_compiled.ring_models`).
    """
    from heoslice.regions_compiled import ring_models

    models = ring_models(d, g, grad, cells[0], cells[1], lattice.dx, lattice.dy, layout.count,
                         0.5 * np.hypot(lattice.dx, lattice.dy), TOLERANCE_PX * min(grid.px, grid.py))
    return list(models)


def _refine_cells(index: np.ndarray, lattice: Lattice, cells: tuple[np.ndarray, np.ndarray], grid: Grid,
                  layout: FamilyLayout, ring_sets: list, mask: np.ndarray | None = None, label_base: int = 0) -> None:
    """k at every pixel of the given cells (where one plane or quadratic of s does not fit), in place
    (with the layer's ``mask``, labels as :func:`_expand_planes` writes them), from every ring
    set's distance at the pixel: exact, or from the ring's own quadratic where it fits.

    ``ring_sets`` holds per ring set (rings, U, model): U ((n,) mm) an upper bound of the exact
    distance from each cell's centre c to it (any edge's distance will do), ``model`` None or
    (n, 6) per cell (:func:`_ring_models`; NaN rows: measure). A pixel p within h (half
    the cell's diagonal) of c has its nearest edge within |p - c| + d(p) <= h + (U + h) of
    c, so a cell's candidates, every edge within U + 2 h of its centre, hold the nearest
    edge of each of its pixels wherever the medial axis runs, and their minimum
    (:func:`nearest_edges`) is the exact distance. Measured distances are unsigned, modelled
    ones signed: only the family's own pixels are kept, and there every distance is positive.
    """
    from heoslice.regions_compiled import band_cells

    f = lattice.cell
    v, u = (a.ravel() for a in np.meshgrid(np.arange(f), np.arange(f), indexing="ij"))
    ox = (u + 0.5 - 0.5 * f) * grid.px
    oy = -(v + 0.5 - 0.5 * f) * grid.py
    reach = np.hypot(lattice.dx, lattice.dy)
    # cells in batches, so that the measured distances held at once stay within _MEASURED_VALUES
    step = max(1, _MEASURED_VALUES // (len(ring_sets) * f * f))
    for first in range(0, len(cells[0]), step):
        ci, cj = (a[first:first + step] for a in cells)
        cx, cy = lattice.x0 + (cj + 0.5) * lattice.dx, lattice.y0 - (ci + 0.5) * lattice.dy
        models = np.full((len(ring_sets), len(ci), 6), np.nan)
        slot = np.full((len(ring_sets), len(ci)), -1, dtype=np.int64)
        measured = []
        for j, (rings, bound, model) in enumerate(ring_sets):
            if model is not None:
                models[j] = model[first:first + step]
            measure = np.isnan(models[j, :, 0])
            if measure.any():
                squared = nearest_edges(cx[measure], cy[measure], bound[first:first + step][measure] + reach, ox, oy,
                                        rings.edges, rings.tree, track=False)
                slot[j, measure] = sum(len(part) for part in measured) + np.arange(len(squared))
                measured.append(np.sqrt(squared))
        measured = np.concatenate(measured) if measured else np.zeros((0, f * f), dtype=np.float32)
        band_cells(index, ci, cj, f, grid.px, grid.py, models, measured, slot, layout.count, layout.length_mm, mask,
                   (lattice.row0, lattice.col0), label_base)


# ---------------------------------------------------------------------------------------------
# Per-layer regions


@dataclass(frozen=True)
class LayerRegions:
    """The sub-regions of one layer.

    ``label`` ((rows, cols) int16/int32 over pixel ``box`` = (row0, row1, col0, col1))
    numbers every solid pixel's sub-region across the layer: family f's sub-region k
    is ``base[f] + k`` (k = 1..N_R; a nested shell keeps its own material: k = 0),
    0 is empty. ``families``/``fields`` are aligned, outermost first (the first field's
    ``index`` may share the label's memory: it is labelled in place, not copied).
    """

    box: tuple[int, int, int, int]
    label: np.ndarray
    families: tuple[Family, ...]
    fields: tuple[FamilyField, ...]
    base: np.ndarray

    @property
    def label_count(self) -> int:
        """Labels in use are 1 .. label_count - 1."""
        return int(self.base[-1]) if len(self.base) else 1


def layer_regions(points: np.ndarray, offsets: np.ndarray, area: np.ndarray, parent: np.ndarray,
                  mask: np.ndarray | None, grid: Grid, spec: RegionSpec, packed: np.ndarray | None = None,
                  reuse: dict | None = None) -> LayerRegions:
    """Sub-regions of one layer: loops (points (p, 2) mm, offsets (l+1,), signed areas and parents
    (l,) within the layer) and the layer's solid mask ((height, width) bool).

    Families are painted outermost first, each over its own solid pixels; a family
    inside another family's solid (a nested shell) is painted after it, so the inner
    shell wins where shells overlap. Without the bool ``mask``, from the ``packed`` one
    only (:func:`heoslice.layers.rasterising.packed_mask`; the droplet masks' path, which reads
    labels only where the layer is solid), the outermost family labels its whole box:
    pixels off the solid there hold labels too.

    ``reuse`` (a dict the caller keeps from layer to layer, same grid and spec) holds the
    previous layer's fields by their rings' edges (:func:`ring_geometry`): a family whose
    edges are the same, value for value (an extruded part), takes its field from there; a
    family measured afresh takes the edge trees and lattice passes of its ring sets that
    are the same (holes that stay while another changes, :class:`RingMeasures`). When every
    family's field is the previous layer's, and was the layer's before that, every island is
    alone in its box (:func:`_alone_in_boxes`) and the ``packed`` solid bits are the previous
    layer's, so are the labels: that array is returned again (callers only read labels).
    """
    families = tuple(layer_families(area, parent))
    if not families:
        return LayerRegions((0, 0, 0, 0), np.zeros((0, 0), np.int16), (), (), np.ones(1, np.int64))
    # the outermost family (label base 1) is labelled by its own expansion, saving a pass over ~15 MP
    masks = [None if number or family.nested else mask for number, family in enumerate(families)]
    keyed = [number for number, family_mask in enumerate(masks) if reuse is not None and family_mask is None]
    geometry = dict(zip(keyed, ring_geometry(points, offsets, [(families[n].outer, *families[n].holes)
                                                               for n in keyed])))
    keys = [(family.nested, int(number == 0), geometry[number]) if number in geometry else None
            for number, family in enumerate(families)]
    before: dict = {} if reuse is None else reuse.setdefault("fields", {})
    for stale in set(before) - set(keys):
        del before[stale]  # freed before this layer's fields are made
    painted = None if reuse is None else reuse.pop("painted", None)
    if painted is not None and painted[0] != keys:
        painted = None  # so are labels painted from other fields
    measured = ({} if reuse is None else reuse.get("rings", {}), {})
    fields = tuple(_layer_field(points, offsets, family, grid, spec, family_mask, 0 if number else 1,
                                None if key is None else before.get(key), measured)
                   for number, (family, family_mask, key) in enumerate(zip(families, masks, keys)))
    if reuse is not None:
        reuse["fields"] = {key: field for key, field in zip(keys, fields) if key is not None}
        reuse["rings"] = measured[1]
    boxes = np.array([field.box for field in fields])
    box = (int(boxes[:, 0].min()), int(boxes[:, 1].max()), int(boxes[:, 2].min()), int(boxes[:, 3].max()))
    sizes = np.array([1 if family.nested else field.layout.count + 1 for family, field in zip(families, fields)])
    base = np.concatenate([[1], 1 + np.cumsum(sizes)]).astype(np.int64)
    dtype = _index_dtype(int(base[-1]))
    first = fields[0]
    # the outermost family labels its box by its own expansion: only the others may take the solid pixels of theirs
    alone = np.r_[False, _alone_in_boxes(points, offsets, families[1:], [field.box for field in fields[1:]], grid)]
    # painted from fields alone and the solid bits: the same fields, islands and bits paint the same labels
    # (kept for the next layer only when this one's fields are all the last one's: an extruded part)
    paintable = (reuse is not None and packed is not None and None not in keys and all(key in before for key in keys)
                 and bool(alone[1:].all()))
    if paintable and painted is not None and np.array_equal(painted[1], packed):
        reuse["painted"] = painted
        return LayerRegions(box, painted[2], families, fields, base)
    painted = None  # freed before this layer's labels are painted
    if first.box == box and first.index.dtype == dtype and (keys[0] is None or len(fields) == 1):
        # the outermost family spans the layer's box: its labels are the layer's, no copy of ~15 MP (unless
        # other families paint over them and the field may serve the next layer)
        label = first.index
    elif first.box == box:
        label = np.empty((box[1] - box[0], box[3] - box[2]), dtype=dtype)  # the copy of its labels fills it
    else:
        label = np.zeros((box[1] - box[0], box[3] - box[2]), dtype=dtype)
    for number, (family, field) in enumerate(zip(families, fields)):
        r0, r1, c0, c1 = field.box
        if r1 <= r0 or c1 <= c0:
            continue
        target = label[r0 - box[0]:r1 - box[0], c0 - box[2]:c1 - box[2]]
        if number == 0:
            # the outermost family's labels cover its box's solid pixels; everything after paints its own region
            if label is not first.index:
                np.copyto(target, first.index, casting="unsafe")
            continue
        solid = _solid_in(mask, packed, field.box)
        if not alone[number]:
            solid = solid & _family_mask(points, offsets, family, grid, field.box)
        value = base[number] if family.nested else field.index + base[number]
        np.copyto(target, value, where=solid, casting="unsafe")
    if paintable:
        reuse["painted"] = (keys, packed.copy(), label)
    return LayerRegions(box, label, families, fields, base)


def _layer_field(points: np.ndarray, offsets: np.ndarray, family: Family, grid: Grid, spec: RegionSpec,
                 mask: np.ndarray | None, label_base: int, same: FamilyField | None,
                 measured: tuple[dict, dict]) -> FamilyField:
    """One family's field for :func:`layer_regions`: measured (``measured`` as :func:`family_field`), or
    ``same``, the previous layer's field of a family with the same rings' edges, with this layer's start
    edges and loop numbers."""
    if same is None:
        return family_field(points, offsets, family, grid, spec, pixels=not family.nested, mask=mask,
                            label_base=label_base, measured=measured)
    loops = family_layout(family, spec)
    # only contours with colours or material fractions read them (contour_values)
    start_edges = functools.cache(lambda: ring_edges(points, offsets, loops.start))
    return replace(same, start_edges=start_edges,
                   layout=replace(same.layout, start=loops.start, end=loops.end if same.layout.end else ()))


def _solid_in(mask: np.ndarray | None, packed: np.ndarray | None, box: tuple[int, int, int, int]) -> np.ndarray:
    """(rows, cols) bool: the layer's solid pixels in a pixel box, from the bool mask or else the packed one."""
    r0, r1, c0, c1 = box
    if mask is not None:
        return mask[r0:r1, c0:c1]
    bits = np.unpackbits(packed[r0:r1, c0 // 8:-(-c1 // 8)], axis=1).view(bool)
    return bits[:, c0 % 8:c0 % 8 + c1 - c0]


def _alone_in_boxes(points: np.ndarray, offsets: np.ndarray, families: tuple[Family, ...],
                    boxes: list[tuple[int, int, int, int]], grid: Grid) -> np.ndarray:
    """(f,) bool per family: whether the layer's solid pixels in its pixel box are all pixels of the family
    (:func:`_family_mask`), so its rings need no rasterising again: an island standing in a hole, a pin
    in a plate. The layer is solid where all its loops wind more than 0 times around a pixel centre, the
    family's pixels where its own loops do; so it holds when the other loops wind at most 0 times around a
    disc holding the box's pixel centres and none of them meets it (compiled
    :func:`heoslice.regions_compiled.disc_winding`). Only loops whose bounding box, grown by the disc's
    radius, holds its centre can meet the disc or wind around it."""
    from heoslice.regions_compiled import disc_winding

    if not families:
        return np.zeros(0, dtype=bool)
    box = np.array(boxes, dtype=np.float64).reshape(-1, 4)
    low = np.column_stack([grid.x_left + (box[:, 2] + 0.5) * grid.px, grid.y_top - (box[:, 1] - 0.5) * grid.py])
    high = np.column_stack([grid.x_left + (box[:, 3] - 0.5) * grid.px, grid.y_top - (box[:, 0] + 0.5) * grid.py])
    centre, reach = 0.5 * (low + high), 0.5 * np.hypot(*(high - low).T) + _DISC_MARGIN_MM
    loop_low, loop_high = np.minimum.reduceat(points, offsets[:-1]), np.maximum.reduceat(points, offsets[:-1])
    near = []
    step = max(1, _NEAR_TESTS // len(loop_low))  # families at once: (step, loops) tests
    for first in range(0, len(families), step):
        c, r = centre[first:first + step, None, :], reach[first:first + step, None, None]
        near += list(map(np.flatnonzero, np.all((c >= loop_low - r) & (c <= loop_high + r), axis=2)))
    alone = np.zeros(len(families), dtype=bool)
    for number, (family, loops) in enumerate(zip(families, near)):
        own = {family.outer, *family.holes}
        others = [loop for loop in loops.tolist() if loop not in own]
        winding = disc_winding(points, offsets, np.array(others), centre[number], reach[number]) if others else 0
        alone[number] = winding is not None and winding <= 0
    return alone


def _family_mask(points: np.ndarray, offsets: np.ndarray, family: Family, grid: Grid,
                 box: tuple[int, int, int, int]) -> np.ndarray:
    """(rows, cols) bool over a pixel box: pixel centres inside the family's outer ring and outside its holes."""
    loops = (family.outer,) + family.holes
    sizes = np.array([offsets[loop + 1] - offsets[loop] for loop in loops])
    ring_points = np.concatenate([points[offsets[loop]:offsets[loop + 1]] for loop in loops])
    r0, r1, c0, c1 = box
    sub = Grid(width=c1 - c0, height=r1 - r0, x_left=grid.x_left + c0 * grid.px, y_top=grid.y_top - r0 * grid.py,
               px=grid.px, py=grid.py)
    return solid_mask(ring_points, np.concatenate([[0], np.cumsum(sizes)]), sub)


def family_of(regions: LayerRegions) -> list[np.ndarray]:
    """For each family, the (rows, cols) bool mask of its labelled pixels within its own box."""
    out = []
    for number, field in enumerate(regions.fields):
        r0, r1, c0, c1 = field.box
        b = regions.box
        sub = regions.label[r0 - b[0]:r1 - b[0], c0 - b[2]:c1 - b[2]]
        out.append((sub >= regions.base[number]) & (sub < regions.base[number + 1]))
    return out


def contour_values(field: FamilyField, values: np.ndarray) -> np.ndarray:
    """Per-point values ((p,) or (p, c)) of the layer's loops taken at each cell's nearest
    starting-ring point, interpolated between the layer's points on either side of it
    (an edge may span several, :class:`RingEdges`): (cells_r, cells_c[, c]) float."""
    edges = field.start_edges()
    foot, edge = field.nearest()
    t = ((foot[0] - edges.x[edge]) * edges.vx[edge] + (foot[1] - edges.y[edge]) * edges.vy[edge]) * edges.inv_len2[edge]
    at = edge + edges.ring[edge] + np.clip(t, 0.0, 1.0)
    values = np.asarray(values, dtype=np.float64)[edges.knot_point]
    if values.ndim == 1:
        return np.interp(at, edges.knots, values)
    return np.stack([np.interp(at, edges.knots, column) for column in values.T], axis=-1)


def paint_cells(regions: LayerRegions, per_family: list[np.ndarray], dtype=np.float32) -> np.ndarray:
    """Per-pixel values over the layer box from per-cell values of each family ((cells_r, cells_c, c)).

    Each family's cells are expanded to its pixels (blocks of cell x cell) and written
    where the family's labels are: (rows, cols, c) of ``dtype``, 0 elsewhere.
    """
    channels = per_family[0].shape[-1] if per_family else 1
    b = regions.box
    out = np.zeros((b[1] - b[0], b[3] - b[2], channels), dtype=dtype)
    for field, cells, own in zip(regions.fields, per_family, family_of(regions)):
        r0, r1, c0, c1 = field.box
        f = field.lattice.cell
        pixels = np.repeat(np.repeat(cells.astype(dtype), f, axis=0), f, axis=1)[: r1 - r0, : c1 - c0]
        np.copyto(out[r0 - b[0]:r1 - b[0], c0 - b[2]:c1 - b[2]], pixels, where=own[..., None])
    return out


def label_fractions(regions: LayerRegions, fraction_at) -> np.ndarray:
    """Fraction of the target material per label ((label_count,) float in [0, 1]).

    ``fraction_at(r)`` is the distribution function ((n,) -> (n,)); sub-region k of a
    family with N_R sub-regions gets f(k / N_R) clipped to [0, 1] (eq. 1: M1 at f <= 0,
    M2 at f >= 1); a nested shell's label gets 0 (its own material); label 0 (empty) 0.
    """
    out = np.zeros(regions.label_count)
    for number, (family, field) in enumerate(zip(regions.families, regions.fields)):
        if family.nested:
            continue
        count = field.layout.count
        k = np.arange(1, count + 1)
        out[regions.base[number] + k] = np.clip(np.asarray(fraction_at(k / count), dtype=np.float64), 0.0, 1.0)
    return out


# ---------------------------------------------------------------------------------------------
# Materials of a graded layer


@dataclass(frozen=True)
class GradeSpec:
    """What a graded slice asks for (``heoslice slice --grade``).

    ``function``: the distribution function (:class:`heoslice.material.functions.DistributionFunction`,
    or None: no gradient, every family keeps its contour's material); ``target``: the
    material M2 reached at r = 1 (eq. 1); ``start``: M1 overriding the contour's
    material (``--from``); ``base``/``second``: the materials a mesh's per-vertex
    material fraction m mixes as (1 - m) base + m second (without it a contour is
    ``base``); ``shells``: (shell number, Material) pairs, a shell's own material
    (its region keeps it, nested shells win).
    """

    regions: RegionSpec
    function: object | None
    target: object | None
    start: object | None
    base: object
    second: object | None = None
    shells: tuple = ()

    def channel_materials(self) -> tuple:
        """The K materials of the droplet masks, without repeats (same name and colour), in a fixed order."""
        found = []
        for material in (self.base, self.second, self.start, self.target, *(m for _, m in self.shells)):
            if material is not None and all((material.name, material.color) != (m.name, m.color) for m in found):
                found.append(material)
        return tuple(found)


@dataclass(frozen=True)
class GradedLayer:
    """A rendered graded layer: RGBA image ((h, w, 4) uint8), solid pixel count, and the
    droplet masks ((K, h, w) bool, one per :meth:`GradeSpec.channel_materials`) or None."""

    image: np.ndarray
    solid: int
    masks: np.ndarray | None
    grading_seconds: float


def _family_sources(spec: GradeSpec, shell, point_material):
    """How one family's contour material is read: (its shell's own Material or None, use the mesh's fraction?)."""
    shells = dict(spec.shells)
    if shell is not None and int(shell) in shells:
        return shells[int(shell)], False
    return None, point_material is not None and spec.second is not None


def _family_starts(regions: LayerRegions, spec: GradeSpec, loop_shell, point_colors, point_material,
                   colors: bool = True):
    """Per family, what its interior starts from at each lattice cell (its contour's material, or
    its shell's, or --from): colour ((cells_r, cells_c, 3) int16 0..255; None without ``colors``)
    and the mix of the K channel materials ((cells_r, cells_c, K) float, summing to 1)."""
    materials = spec.channel_materials()
    position = {(m.name, m.color): i for i, m in enumerate(materials)}
    starts, mixes = [], []
    for family, field in zip(regions.families, regions.fields):
        shell = None if loop_shell is None else loop_shell[family.outer]
        own, use_fraction = _family_sources(spec, shell, point_material)
        if own is not None:
            start = own
        elif spec.start is not None and not family.nested:
            start = spec.start
        else:
            start = None
        cells = (field.lattice.rows, field.lattice.cols)
        mix = np.zeros((*cells, len(materials)))
        if start is not None:
            mix[..., position[(start.name, start.color)]] = 1.0
            color = np.asarray(start.color, dtype=np.float64)
        elif use_fraction:
            m = np.clip(contour_values(field, point_material), 0.0, 1.0)
            mix[..., position[(spec.base.name, spec.base.color)]] = 1.0 - m
            mix[..., position[(spec.second.name, spec.second.color)]] += m
            color = (np.asarray(spec.base.color, dtype=np.float64) * (1.0 - m)[..., None]
                     + np.asarray(spec.second.color, dtype=np.float64) * m[..., None])
        else:
            mix[..., position[(spec.base.name, spec.base.color)]] = 1.0
            color = np.asarray(spec.base.color, dtype=np.float64)
        mixes.append(mix)
        if not colors:
            starts.append(None)
            continue
        if point_colors is not None and start is None:
            color = contour_values(field, point_colors)
        starts.append(np.broadcast_to(np.clip(np.rint(color), 0, 255).astype(np.int16), (*cells, 3)))
    return starts, mixes


def _target_fractions(regions: LayerRegions, spec: GradeSpec) -> np.ndarray:
    """Fraction of the target material per label ((label_count,) float; zeros without a gradient)."""
    from heoslice.material.functions import evaluate

    if spec.function is None or spec.target is None:
        return np.zeros(regions.label_count)
    return label_fractions(regions, lambda r: evaluate(spec.function, r))


def render_graded(points: np.ndarray, offsets: np.ndarray, area: np.ndarray, parent: np.ndarray,
                  loop_shell: np.ndarray | None, mask: np.ndarray, grid: Grid, spec: GradeSpec, layer: int, *,
                  point_colors: np.ndarray | None = None, point_material: np.ndarray | None = None,
                  channels: bool = False, reuse: dict | None = None) -> GradedLayer:
    """Render one graded layer (Fig. 9b): sub-regions by :func:`layer_regions`, each family's
    interior blended from its contour's material to the target by eq. 1, contour pixels
    in the contour's colours, and optionally the droplet masks (:mod:`heoslice.halftone`).

    points (p, 2) mm, offsets (l+1,), area/parent/loop_shell (l,) of the layer's loops;
    mask (h, w) bool its solid pixels; point_colors (p, 3) float 0..255 and
    point_material (p,) in [0, 1] the attributes interpolated at the contour points; ``reuse``
    as :func:`layer_regions`.
    """
    import time

    from heoslice.layers.rasterising import paint_contour

    started = time.process_time()
    regions = layer_regions(points, offsets, area, parent, mask, grid, spec.regions, reuse=reuse)
    grading_seconds = time.process_time() - started
    solid = int(np.count_nonzero(mask))
    image = np.zeros((grid.height, grid.width, 4), dtype=np.uint8)
    masks = None
    if channels:
        planes = _droplet_planes_of(regions, spec, loop_shell, point_material, np.packbits(mask, axis=1), grid, layer)
        masks = np.unpackbits(planes, axis=2, count=grid.width).view(bool)
    if not regions.fields:
        return GradedLayer(image, solid, masks, grading_seconds)

    fractions = _target_fractions(regions, spec)
    colors, _ = _family_starts(regions, spec, loop_shell, point_colors, point_material)
    b = regions.box
    label = regions.label
    inside = label > 0
    solid_box = mask[b[0]:b[1], b[2]:b[3]]
    stray = solid_box & ~inside
    weight = np.rint(fractions * 255).astype(np.int16)
    g = np.take(weight, label)
    start_color = paint_cells(regions, colors, dtype=np.int16)
    view = image[b[0]:b[1], b[2]:b[3]]
    target = spec.target.color if spec.target is not None else (0, 0, 0)
    for channel in range(3):
        value = start_color[..., channel]
        if spec.target is not None:
            value = value + ((target[channel] - value) * g + 127) // 255
        view[..., channel] = value
    view[..., 3] = inside.view(np.uint8) * np.uint8(255)
    view[stray] = (*spec.base.color, 255)
    if point_colors is not None:
        paint_contour(image, mask, points, point_colors, grid)
    return GradedLayer(image, solid, masks, grading_seconds)


def droplet_planes(points: np.ndarray, offsets: np.ndarray, area: np.ndarray, parent: np.ndarray,
                   loop_shell: np.ndarray | None, mask: np.ndarray | None, grid: Grid, spec: GradeSpec, layer: int, *,
                   point_material: np.ndarray | None = None, packed: np.ndarray | None = None,
                   reuse: dict | None = None) -> np.ndarray:
    """The droplet masks of one graded layer, bit-packed: (K, height, ceil(width / 8)) uint8, rows MSB first.

    Each solid pixel's mix is its family's start mix at its lattice cell moved by its
    sub-region's fraction towards the target (eq. 1), halftoned by the ordered dither of
    :mod:`heoslice.halftone` (in its float32 arithmetic), in one compiled pass over the
    layer's pixels, without the RGBA image: the path of ``slice --channels`` (and of
    ``render_graded(..., channels=True)``). Solid pixels outside every family jet the base
    material. Arguments as :func:`render_graded`; mask (h, w) bool, ``packed`` the same mask
    bit-packed (:func:`heoslice.layers.rasterising.packed_mask`) when the caller has it; with it, the
    mask may be None (no per-pixel mask built or read: :func:`layer_regions`); ``reuse`` as there.
    """
    packed = np.packbits(mask, axis=1) if packed is None else packed
    regions = layer_regions(points, offsets, area, parent, mask, grid, spec.regions, packed, reuse)
    return _droplet_planes_of(regions, spec, loop_shell, point_material, packed, grid, layer, reuse)


def _droplet_planes_of(regions: LayerRegions, spec: GradeSpec, loop_shell, point_material, packed: np.ndarray,
                       grid: Grid, layer: int, reuse: dict | None = None) -> np.ndarray:
    """:func:`droplet_planes` of a layer whose sub-regions are already known; ``reuse`` keeps the
    choice table for the next layer (:func:`_layer_choice_table`)."""
    from heoslice.halftone import layer_tile
    from heoslice.regions_compiled import droplet_bits

    materials = spec.channel_materials()
    planes = np.zeros((len(materials), grid.height, -(-grid.width // 8)), dtype=np.uint8)
    position = {(m.name, m.color): i for i, m in enumerate(materials)}
    base_channel = position[(spec.base.name, spec.base.color)]
    if not regions.fields:
        return droplet_bits(np.zeros((0, 0), np.int16), (0, 0), packed, np.zeros(1, np.int64), np.zeros(1),
                            np.zeros((0, 5), np.int64), np.zeros(0), np.zeros(len(materials)),
                            layer_tile(layer), base_channel, planes, np.full((1, 256), base_channel, np.int8))
    _, mixes = _family_starts(regions, spec, loop_shell, None, point_material, colors=False)
    target_mix = np.zeros(len(materials))
    if spec.target is not None and spec.function is not None:
        target_mix[position[(spec.target.name, spec.target.color)]] = 1.0
    fractions = _target_fractions(regions, spec)
    family_of_label = np.zeros(regions.label_count, dtype=np.int64)
    for number in range(len(regions.fields)):
        family_of_label[regions.base[number]:regions.base[number + 1]] = number
    sizes = np.array([mix.size for mix in mixes])
    layout = np.array([(field.box[0], field.box[2], field.lattice.cell, field.lattice.cols, start)
                       for field, start in zip(regions.fields, np.cumsum(sizes) - sizes)], dtype=np.int64)
    table = _layer_choice_table(regions, mixes, fractions, target_mix, base_channel, reuse)
    return droplet_bits(regions.label, regions.box[::2], packed, family_of_label, fractions,
                        layout, np.concatenate([mix.ravel() for mix in mixes]), target_mix, layer_tile(layer),
                        base_channel, planes, table)


def _layer_choice_table(regions: LayerRegions, mixes: list[np.ndarray], fractions: np.ndarray,
                        target_mix: np.ndarray, base_channel: int, reuse: dict | None) -> np.ndarray:
    """:func:`_choice_table` with label 0 (solid pixels outside every family) on the base channel; the
    last layer's (kept in ``reuse``) when its label bases, fractions, mixes and base channel are the same
    (an extruded part)."""
    key = (np.array([base_channel]), regions.base, fractions, target_mix, *mixes)
    last = None if reuse is None else reuse.get("choices")
    if last is not None and len(last[0]) == len(key) and all(map(np.array_equal, last[0], key)):
        return last[1]
    table = _choice_table(regions, mixes, fractions, target_mix)
    table[0] = base_channel
    if reuse is not None:
        reuse["choices"] = (key, table)
    return table


def _choice_table(regions: LayerRegions, mixes: list[np.ndarray], fractions: np.ndarray,
                  target_mix: np.ndarray) -> np.ndarray:
    """The channel each label jets at each of the 256 dither thresholds ((labels, 256) int8), for the
    labels of families whose start mix is the same at every cell (-1 for the others, which
    are halftoned per pixel). Computed in choose_materials' float32 arithmetic, so a pixel's
    channel is the same either way; it turns the per-pixel mix into one table look-up."""
    from heoslice.halftone import TILE

    count = TILE * TILE
    table = np.full((regions.label_count, count), -1, dtype=np.int8)
    levels = ((np.arange(count) + 0.5) / count).astype(np.float32)
    target = target_mix.astype(np.float32)
    for number, mix in enumerate(mixes):
        flat = mix.reshape(-1, mix.shape[-1]).astype(np.float32)
        if not len(flat) or (flat != flat[0]).any():
            continue
        labels = np.arange(regions.base[number], regions.base[number + 1])
        share = flat[0] + fractions.astype(np.float32)[labels, None] * (target - flat[0])
        total = np.zeros(len(labels), dtype=np.float32)
        for column in share.T:
            total += column
        threshold = levels[None, :] * np.where(total > 0, total, np.float32(1.0))[:, None]
        chosen = np.full(threshold.shape, share.shape[1] - 1, dtype=np.int8)
        running = np.zeros(len(labels), dtype=np.float32)
        undecided = np.ones(threshold.shape, dtype=bool)
        for channel in range(share.shape[1] - 1):
            running += share[:, channel]
            here = undecided & (threshold < running[:, None])
            chosen[here] = channel
            undecided &= ~here
        table[labels] = chosen
    return table
