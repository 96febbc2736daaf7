"""The sub-region index of one profile family at every pixel of its box (the paper's II.D-E, III.B, eq. 8-10).

Inside each family the solid region is divided into N_R = int(L_S / D_N) sub-regions
(eq. 8); sub-region k (1..N_R) gets the material at r = k / N_R of the distribution
function, from the contour's material to the target. Where r comes from:

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
padded by one cell; blocks of cells wholly off the family's side are skipped,
:mod:`heoslice.grading.lattice`), one plane per cell (a quadratic where the field bends
and that fits better), checked against the eight neighbouring centres (across the rings
too: s continues smoothly there) and expanded to pixels. Cells where neither places the
sub-region boundaries within TOLERANCE_PX pixels of the exact ones (medial axis, sharp
corners) are evaluated per pixel (:mod:`heoslice.grading.refine`). "Exact" means the
nearest of every edge that can be nearest (a bound argued where it is used), measured in
float32 from a nearby centre (under 2e-5 mm). The solid mask decides which pixels are
solid, so the outline is exact.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import shapely

from heoslice.grading.cache import RingMemo
from heoslice.grading.edges import RingEdges, convex_rings, edges_key, ring_edges
from heoslice.grading.edges_kernels import edge_arrays
from heoslice.grading.families import Family, FamilyLayout, family_layout
from heoslice.grading.field_kernels import (
    CellPixels,
    band_field,
    cell_classes,
    curve_cells,
    curved_cells,
    expand_planes,
    label_target,
)
from heoslice.grading.fit_kernels import OneRingFit, one_ring_labels
from heoslice.grading.lattice import (
    CELL_MM,
    Lattice,
    lattice_for,
    measured_centres,
    padded,
    ring_measures,
)
from heoslice.grading.refine import (
    cell_hessians,
    cells_to_refine,
    fit_ring_models,
    fit_test,
    pixel_offsets,
    refine_cells,
    ring_vertices,
)
from heoslice.grading.search import LazyTree, RingSet, rings_apart, rings_apart_kept
from heoslice.grading.search_kernels import EdgeTree
from heoslice.grading.spec import RegionSpec, coordinate_precision
from heoslice.layers.rasterising import Grid

#: The same for families of one or two convex rings (a disc, a tube's wall): their fields have no
#: creases but the deep medial axis (none where the nearest of several holes changes, none beside a
#: reflex corner), so they fit larger cells, which cost less.
WIDE_CELL_MM = 0.68


#: Families whose box pixels x ring sets are at most this get every pixel's exact distance, no lattice fit.
DIRECT_PIXELS = 25_000


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
    (:func:`heoslice.grading.field_kernels.band_field`).
    """
    if not layout.end:
        scale = layout.count / layout.length_mm
        return d[0] * scale, g[0] * scale
    return band_field(d, g, layout.count)


@dataclass(frozen=True)
class FamilyField:
    """The sub-region index of one family over its pixel box.

    ``index``: (rows, cols) uint8/16/32 (:func:`label_dtype`), k in 1..N_R (valid on the family's solid
    pixels; the caller masks; one read-only value broadcast over the box for a family of one
    sub-region without a mask; in :class:`LayerRegions` the outermost family's index,
    when its box is the layer's, is the label array itself); ``box`` = (row0, row1, col0, col1) of the grid;
    ``layout`` its rings and N_R; ``lattice``; ``nearest()`` gives per cell the nearest point
    on the starting rings (foot (2, cells_r, cells_c) mm) and its edge ((cells_r, cells_c)
    into ``start_edges()``, the starting rings' edges in this layer's points), to take the
    contour's material there (measured on first call for a nested shell, whose own material
    usually makes it unneeded, for a small family labelled per pixel, :func:`_exact_index`, and for a
    family of one sub-region, whose contour's material is often one throughout; ``start_edges()`` made on
    first call for a field another layer measured).
    """

    box: tuple[int, int, int, int]
    index: np.ndarray
    layout: FamilyLayout
    lattice: Lattice
    start_edges: Callable[[], RingEdges]
    nearest: Callable[[], tuple[np.ndarray, np.ndarray]]


def family_box(edges: RingEdges, grid: Grid) -> tuple[int, int, int, int]:
    """Pixel box (row0, row1, col0, col1) of the pixel centres inside the bounding box of a ring's edges."""
    low, high = (float(edges.x.min()), float(edges.y.min())), (float(edges.x.max()), float(edges.y.max()))
    col0 = min(max(math.floor((low[0] - grid.x_left) / grid.px - 0.5), 0), grid.width)
    col1 = min(max(math.ceil((high[0] - grid.x_left) / grid.px + 0.5), 0), grid.width)
    row0 = min(max(math.floor((grid.y_top - high[1]) / grid.py - 0.5), 0), grid.height)
    row1 = min(max(math.ceil((grid.y_top - low[1]) / grid.py + 0.5), 0), grid.height)
    return row0, row1, col0, col1


class _FamilyRings:
    """The ring sets of one layer's loops, each made once, its edge tree (made when first asked for) recalled
    from a :class:`RingMemo`."""

    def __init__(self, points: np.ndarray, offsets: np.ndarray, memo: RingMemo):
        self.points, self.offsets, self.memo, self.made = points, offsets, memo, {}

    def __call__(self, loops, encloses: bool) -> RingSet:
        """The ring set of the given loops (its region inside them when ``encloses``), keyed by its edges."""
        if (tuple(loops), encloses) not in self.made:
            edges = ring_edges(self.points, self.offsets, loops)
            key = (encloses, *edges_key(edges))
            tree = self.memo.recall(key, functools.partial(LazyTree, edges))
            self.made[tuple(loops), encloses] = RingSet(tuple(loops), edges, encloses, tree, key)
        return self.made[tuple(loops), encloses]


def family_field(points: np.ndarray, offsets: np.ndarray, family: Family, grid: Grid,
                 spec: RegionSpec, pixels: bool = True, mask: np.ndarray | None = None,
                 label_base: int = 0, memo: RingMemo | None = None, headroom: int = 0) -> FamilyField:
    """Sub-region index k (1..N_R) at every pixel of a family's box (see the module docstring).

    With ``pixels`` False only the lattice is measured (a nested shell, which keeps its
    own material, needs its cells' nearest contour points but no sub-regions): ``index``
    is then empty and N_R is 1. With the layer's solid ``mask`` ((h, w) bool) ``index``
    holds labels instead: k + label_base on solid pixels, 0 elsewhere.

    ``memo``: what the previous layer measured of ring sets with these very edges (their
    edge trees by RingSet.key, distances between sets, lattice passes by key and lattice);
    this family's measurements are kept in it. ``headroom``: labels past its own that the index must hold
    when it becomes the labels of a layer of several families (the outermost family's: the others'), so
    that theirs fit without a copy of it.
    """
    memo = RingMemo() if memo is None else memo
    rings = _FamilyRings(points, offsets, memo)
    # everything below reads the rings' edges only, not their straight points (so a layer may reuse another's)
    outer = rings((family.outer,), True)
    box = family_box(outer.edges, grid)
    row0, row1, col0, col1 = box
    outward = spec.direction == "out" and bool(family.holes)
    # a small family is labelled per pixel: from its exact distance to each ring set (family_layout's ends
    # and its start), or k = 1 throughout when it has one sub-region
    end_sets = 0 if spec.depth_mm is not None or not family.holes else 1 if outward else len(family.holes)
    direct = pixels and (row1 - row0) * (col1 - col0) * (1 + end_sets) <= DIRECT_PIXELS
    smooth = (not direct and len(family.holes) <= 1 and convex_rings(outer.edges)
              and (not family.holes or convex_rings(rings(family.holes, False).edges)))
    lattice = lattice_for(box, grid, WIDE_CELL_MM if smooth else CELL_MM)

    start_loops = family.holes if outward else (family.outer,)
    start = rings(start_loops, not outward)

    @functools.cache
    def nearest():
        measures = ring_measures(start, lattice)
        at, _ = measured_centres(start, measures, lattice, ~measures.far)
        return at[2], at[3]

    if not pixels:
        return FamilyField(box=box, index=np.zeros((0, 0), LABEL_TYPES[0]),
                           layout=FamilyLayout(start_loops, (), 1, 1.0), lattice=lattice,
                           start_edges=lambda: start.edges, nearest=nearest)
    # the rounding a band count allows for (eq. 8); N_R asked for (--offsets, masks without a gradient) has none
    precision = 0.0 if spec.count is not None else coordinate_precision(outer.edges.x, outer.edges.y)
    # one sub-region asked for (masks without a gradient, or --offsets 1): k = 1 throughout, so no grading
    # length (eq. 8)
    lengths = (None, None) if spec.count == 1 else _grading_length(family, spec, outer, rings, grid, memo)
    layout = family_layout(family, spec, *lengths, precision)
    # a family of one sub-region needs no distances to its ending rings: its starting rings' feet alone
    ends = [] if layout.count == 1 else [rings(loops, outward) for loops in layout.end]
    shape = (row1 - row0, col1 - col0)
    dtype = label_dtype(layout.count + label_base + headroom)
    if direct:
        index = (_single_region_index(shape, mask, (lattice.row0, lattice.col0), label_base, dtype)
                 if layout.count == 1 else _exact_index(lattice, grid, layout, [start] + ends, shape, mask,
                                                        label_base, dtype))
        return FamilyField(box=box, index=index, layout=layout, lattice=lattice, start_edges=lambda: start.edges,
                           nearest=nearest)
    index, nearest = _lattice_index(lattice, grid, layout, [start] + ends, shape, mask, label_base, dtype, memo)
    return FamilyField(box=box, index=index, layout=layout, lattice=lattice,
                       start_edges=lambda: start.edges, nearest=nearest)


def _grading_length(family: Family, spec: RegionSpec, outer: RingSet, rings: _FamilyRings, grid: Grid,
                    memo: RingMemo) -> tuple[float | None, float | None]:
    """(inradius, apart) for :func:`family_layout`: a solid family's largest inscribed distance, or the
    shortest distance (mm) between its starting and ending rings; None where a target depth sets L_S."""
    if spec.depth_mm is not None:
        return None, None
    if not family.holes:
        outline = shapely.Polygon(np.column_stack([outer.edges.x, outer.edges.y]))
        return float(shapely.maximum_inscribed_circle(outline, 0.5 * min(grid.px, grid.py)).length), None
    if spec.direction == "out":
        return None, rings_apart(outer, rings(family.holes, False))
    # hole by hole (the rings the grading ends at, measured anyway), each pair kept for the next layer: through
    # a cavity, only the outer ring's distance to the cavity is new
    return None, min(rings_apart_kept(outer, rings((hole,), False), memo) for hole in family.holes)


def _lattice_index(lattice: Lattice, grid: Grid, layout: FamilyLayout, ring_sets: list[RingSet],
                   shape: tuple[int, int], mask: np.ndarray | None, label_base: int, dtype: type,
                   memo: RingMemo) -> tuple[np.ndarray, Callable[[], tuple[np.ndarray, np.ndarray]]]:
    """k at every pixel of a family's box ((rows, cols), labelled like :func:`_expand_planes`) from the
    lattice fit: one plane or quadratic per cell, per-pixel eq. 10 where neither fits; with a function
    giving the starting rings' nearest foot ((2, rows, cols) mm) and edge ((rows, cols)) at every cell
    centre. ``ring_sets``: the starting rings, then each ending ring set."""
    # measured on the lattice padded by a cell, so that every cell of the family has its eight neighbours
    padded_lattice = padded(lattice)

    def measure(sets: list[RingSet]) -> list[tuple]:
        """The ring ``sets``' centres (signed, gradient, foot, edge) over the padded lattice, in the blocks on
        the family's side of each of them; each set's measures kept for the next layer."""
        measures = [memo.earlier((rings.key, padded_lattice)) or ring_measures(rings, padded_lattice)
                    for rings in sets]
        wanted = ~np.logical_or.reduce([m.far for m in measures])
        centres = [measured_centres(rings, m, padded_lattice, wanted) for rings, m in zip(sets, measures)]
        for rings, (_, m) in zip(sets, centres):
            memo.keep((rings.key, padded_lattice), m)
        return [at for at, _ in centres]

    if layout.count == 1:
        # one sub-region (one asked for, or a family too thin for two): k = 1 throughout, and the starting
        # rings' feet are measured only if asked for (a contour whose material varies along it)
        @functools.cache
        def nearest() -> tuple[np.ndarray, np.ndarray]:
            start_at = measure(ring_sets[:1])[0]
            return start_at[2][:, 1:-1, 1:-1], start_at[3][1:-1, 1:-1]

        return _single_region_index(shape, mask, (lattice.row0, lattice.col0), label_base, dtype), nearest
    measured = measure(ring_sets)
    if len(ring_sets) == 1:
        # one ring set (no holes, or a target depth): the steps of _fitted_index in one compiled call
        index = _one_ring_index(lattice, grid, layout, ring_sets[0], measured[0], shape, mask, label_base, dtype)
    else:
        index = _fitted_index(lattice, grid, layout, ring_sets, measured, shape, mask, label_base, dtype)
    foot, edge = measured[0][2][:, 1:-1, 1:-1], measured[0][3][1:-1, 1:-1]
    return index, lambda: (foot, edge)


def _one_ring_index(lattice: Lattice, grid: Grid, layout: FamilyLayout, rings: RingSet, measured: tuple,
                    shape: tuple[int, int], mask: np.ndarray | None, label_base: int, dtype: type) -> np.ndarray:
    """:func:`_fitted_index` of a family graded from one ring set, in one compiled call
    (:func:`heoslice.grading.fit_kernels.one_ring_labels`): the same labels, without Python between its steps."""
    index = np.empty(shape, dtype=dtype)
    outer = padded(lattice)
    diagonal = float(np.hypot(lattice.dx, lattice.dy))
    fit = OneRingFit(lattice.dx, lattice.dy, 0.5 * diagonal, diagonal, *fit_test(lattice, grid), layout.count,
                     layout.length_mm, outer.x0, outer.y0)
    ox, oy = pixel_offsets(lattice.cell, grid.px, grid.py)
    return one_ring_labels(label_target(index, mask, (lattice.row0, lattice.col0), label_base), measured[0],
                           measured[1], fit, CellPixels(lattice.cell, float(grid.px), float(grid.py)),
                           (lattice.x0, lattice.y0, lattice.dx, lattice.dy), ox, oy, EdgeTree(*rings.tree),
                           edge_arrays(rings.edges))


def _fitted_index(lattice: Lattice, grid: Grid, layout: FamilyLayout, ring_sets: list[RingSet], measured: list[tuple],
                  shape: tuple[int, int], mask: np.ndarray | None, label_base: int, dtype: type) -> np.ndarray:
    """The lattice fit of :func:`_lattice_index`, step by step (families of several ring sets), from each ring
    set's (signed distance, gradient, ...) at the centres of the lattice padded by a cell (``measured``)."""
    padded_lattice = padded(lattice)
    start, ends = ring_sets[0], ring_sets[1:]
    d = np.stack([at[0] for at in measured])
    g = np.stack([at[1] for at in measured])
    s, grad = _band_coordinate(layout, d, g)

    # a cell may hold solid pixels when its centre is within half a diagonal of the family's side; beyond, it is
    # deep enough that every pixel of the cell is in the last sub-region (s >= N_R - 1 throughout)
    touched, beyond, candidate, known, side = cell_classes(s, grad, d, 0.5 * np.hypot(lattice.dx, lattice.dy),
                                                           layout.count)
    # a cell gets a quadratic where it fits better than a plane: eq. 10's field bends everywhere, one ring's
    # distance field around its medial axis (the centre of a disc)
    hessian = cell_hessians(grad, padded_lattice)
    vertices = ring_vertices([(start, 0.0)] + [(rings, float(layout.count)) for rings in ends], padded_lattice)
    refine = cells_to_refine(s, grad, known, side, candidate, padded_lattice, grid, layout.count, hessian, vertices)
    refined = np.nonzero(refine)  # never on the padded lattice's border: its cells are no candidates
    models = [None] * len(ring_sets)
    if layout.end and len(refined[0]):
        models = fit_ring_models(layout, d, g, grad, padded_lattice, grid, refined)
    curved = curved_cells(hessian, candidate, refine)
    inner = (slice(1, -1), slice(1, -1))
    if not known[inner].all():
        # cells without s are refined or hold no solid pixel: expanded from 0
        s, grad = np.where(known, s, 0.0), np.where(known[..., None], grad, 0.0)
    # the padded lattice's inner part read in place
    index = _expand_planes(lattice, s, grad, grid, beyond, layout.count, shape, mask, label_base, ~touched, dtype)
    if len(curved[0]):
        curve_cells(label_target(index, mask, (lattice.row0, lattice.col0), label_base), curved[0], curved[1],
                    CellPixels(lattice.cell, grid.px, grid.py), s[inner], grad[inner], hessian[:, 1:-1, 1:-1],
                    layout.count)
    if len(refined[0]):
        cells = (refined[0] - 1, refined[1] - 1)
        refine_cells(index, lattice, cells, grid, layout,
                     [(rings, np.abs(at[0][inner][cells]), model)
                      for rings, at, model in zip(ring_sets, measured, models)], mask, label_base)
    return index


def _single_region_index(shape: tuple[int, int], mask: np.ndarray | None, origin: tuple[int, int],
                         label_base: int, dtype: type) -> np.ndarray:
    """k = 1 at every pixel of a one-sub-region family's box ((rows, cols), labelled like
    :func:`_expand_planes`: 1 + label_base, with the layer's ``mask`` on its solid pixels only). Pixels of
    the box off the family hold the label too; they are solid only where another family paints its own.
    Without a mask the index is one read-only value seen at every pixel (no memory: the labels take it
    as a value, :func:`heoslice.grading.labels.layer_regions`)."""
    if mask is None:
        return np.broadcast_to(np.array(1 + label_base, dtype=dtype), shape)
    index = np.full(shape, 1 + label_base, dtype=dtype)
    row, col = origin
    index[~mask[row:row + shape[0], col:col + shape[1]]] = 0
    return index


def _exact_index(lattice: Lattice, grid: Grid, layout: FamilyLayout, ring_sets: list[RingSet],
                 shape: tuple[int, int], mask: np.ndarray | None, label_base: int, dtype: type) -> np.ndarray:
    """k at every pixel of a small family's box ((rows, cols), labelled like :func:`_expand_planes`),
    each from its exact distance to every ring set (:func:`refine_cells` over every cell).

    Below DIRECT_PIXELS (box pixels x ring sets) this beats fitting the lattice, whose fixed
    cost per family dominates a small island's (benchmarks/README.md); each cell's bound is its
    distance to a ring set's first point."""
    index = np.empty(shape, dtype=dtype)
    ci, cj = (a.ravel() for a in np.indices((lattice.rows, lattice.cols)))
    x, y = lattice.centres()
    bounds = [np.hypot(x[cj] - rings.edges.x[0], y[ci] - rings.edges.y[0]) for rings in ring_sets]
    refine_cells(index, lattice, (ci, cj), grid, layout,
                  [(rings, bound, None) for rings, bound in zip(ring_sets, bounds)], mask, label_base)
    return index


#: The label types, narrowest first: labels are never negative (0 is no label).
LABEL_TYPES = (np.uint8, np.uint16, np.uint32)


def label_dtype(largest: int) -> type:
    """The narrowest of LABEL_TYPES holding labels up to ``largest`` (the per-pixel passes over a layer's
    labels are bound by their memory traffic)."""
    return next(kind for kind in LABEL_TYPES if largest <= np.iinfo(kind).max)


def _expand_planes(lattice: Lattice, s: np.ndarray, grad: np.ndarray, grid: Grid, flat: np.ndarray, count: int,
                   shape: tuple[int, int], mask: np.ndarray | None, label_base: int, empty: np.ndarray | None,
                   dtype: type) -> np.ndarray:
    """k = clip(floor(s) + 1, 1, N_R) at every pixel of the family's box ((rows, cols) ``dtype``, as
    :func:`family_field` chose it) from one plane per cell (compiled); a ``flat`` cell takes its centre's
    value throughout, an ``empty`` one (none of the family's pixels) 0. With the layer's
    ``mask``: k + label_base on solid pixels, else 0. s, grad, flat and empty are over the lattice padded
    by a cell (:func:`heoslice.grading.lattice.padded`)."""
    out = np.empty(shape, dtype=dtype)
    return expand_planes(s, grad, CellPixels(lattice.cell, grid.px, grid.py), count,
                         label_target(out, mask, (lattice.row0, lattice.col0), label_base), empty, flat, pad=1)
