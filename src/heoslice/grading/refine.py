"""Where one plane per lattice cell does not place the sub-region boundaries within TOLERANCE_PX pixels, and
those cells evaluated per pixel: eq. 10 from each ring's exact distance, or its own quadratic where it fits."""

from __future__ import annotations

import functools

import numpy as np

from heoslice.grading.families import FamilyLayout
from heoslice.grading.field_kernels import CellPixels, label_target
from heoslice.grading.lattice import Lattice
from heoslice.grading.refine_kernels import (
    MEASURED_VALUES,
    CellField,
    FitTest,
    RingVertices,
    band_cells,
    hessian_of,
    measured_cells,
    refine_flags,
    ring_models,
    vertices_by_cell,
)
from heoslice.grading.search import RingSet, nearest_edges
from heoslice.layers.rasterising import Grid

#: Largest error of a sub-region boundary, in pixels, before a lattice cell is evaluated per pixel.
TOLERANCE_PX = 0.5


def cell_hessians(grad: np.ndarray, lattice: Lattice) -> np.ndarray:
    """(3, rows, cols) s_xx, s_xy, s_yy per mm^2 at the cell centres: central differences of the exact
    gradients ((rows, cols, 2) per mm, y up) of neighbouring centres (one-sided at the border;
    zero along an axis the lattice is one cell wide in, and all zero where a neighbour's
    gradient is unknown (past a pole of eq. 10's continuation): no quadratic there)."""
    return hessian_of(grad, lattice.dx, lattice.dy)


def cells_to_refine(s: np.ndarray, grad: np.ndarray, known: np.ndarray, side: np.ndarray, candidate: np.ndarray,
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
    one) within TOLERANCE_PX at the ring ``vertices`` around the cell (:func:`ring_vertices`):
    a round outline's steady turn, not a hidden notch, whose tip is a vertex.
    """
    return refine_flags(CellField(s, grad, known, side, candidate), FitTest(lattice.dx, lattice.dy,
                                                                             *fit_test(lattice, grid), count),
                        hessian, vertices)


def fit_test(lattice: Lattice, grid: Grid) -> tuple[float, float]:
    """The fit test's misfit allowed at a neighbour's centre (mm of s's slope: twice TOLERANCE_PX pixels) and
    the cosine of the largest turn allowed next to the outline (:func:`cells_to_refine`)."""
    tolerance = 2.0 * TOLERANCE_PX * min(grid.px, grid.py)
    return tolerance, float(np.sqrt(max(0.0, 1.0 - (2.0 * TOLERANCE_PX / lattice.cell) ** 2)))


def ring_vertices(ring_sets: list[tuple[RingSet, float]], lattice: Lattice) -> RingVertices:
    """The vertices of the given ring sets, each with the exact s on its rings, grouped by the lattice
    cell holding them: (start (rows * cols + 1,) int, x, y, s, x0, y0) for :func:`cells_to_refine`."""
    x = np.concatenate([rings.edges.x for rings, _ in ring_sets])
    y = np.concatenate([rings.edges.y for rings, _ in ring_sets])
    s = np.concatenate([np.full(len(rings.edges.x), value) for rings, value in ring_sets])
    return vertices_by_cell(x, y, s, lattice.x0, lattice.y0, lattice.dx, lattice.dy, lattice.rows, lattice.cols)


def fit_ring_models(layout: FamilyLayout, d: np.ndarray, g: np.ndarray, grad: np.ndarray, lattice: Lattice, grid: Grid,
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
    (:func:`heoslice.grading.refine_kernels.ring_models`).
    """
    models = ring_models(d, g, grad, cells[0], cells[1], lattice.dx, lattice.dy, layout.count,
                         0.5 * np.hypot(lattice.dx, lattice.dy), TOLERANCE_PX * min(grid.px, grid.py))
    return list(models)


def refine_cells(index: np.ndarray, lattice: Lattice, cells: tuple[np.ndarray, np.ndarray], grid: Grid,
                  layout: FamilyLayout, ring_sets: list, mask: np.ndarray | None = None, label_base: int = 0) -> None:
    """k at every pixel of the given cells (where one plane or quadratic of s does not fit), in place
    (with the layer's ``mask``, labels as :func:`_expand_planes` writes them), from every ring
    set's distance at the pixel: exact, or from the ring's own quadratic where it fits.

    ``ring_sets`` holds per ring set (rings, U, model): U ((n,) mm) an upper bound of the exact
    distance from each cell's centre c to it (any edge's distance will do), ``model`` None or
    (n, 6) per cell (:func:`fit_ring_models`; NaN rows: measure). A pixel p within h (half
    the cell's diagonal) of c has its nearest edge within |p - c| + d(p) <= h + (U + h) of
    c, so a cell's candidates, every edge within U + 2 h of its centre, hold the nearest
    edge of each of its pixels wherever the medial axis runs, and their minimum
    (:func:`nearest_edges`) is the exact distance. Measured distances are unsigned, modelled
    ones signed: only the family's own pixels are kept, and there every distance is positive.
    """
    f = lattice.cell
    ox, oy = pixel_offsets(f, grid.px, grid.py)
    reach = np.hypot(lattice.dx, lattice.dy)
    target = label_target(index, mask, (lattice.row0, lattice.col0), label_base)
    pixels = CellPixels(f, grid.px, grid.py)
    if len(ring_sets) == 1 and ring_sets[0][2] is None:
        # one ring set, measured at every pixel (a family without holes): measured and labelled in one call
        rings, bound, _ = ring_sets[0]
        measured_cells(target, cells[0], cells[1], pixels, (lattice.x0, lattice.y0, lattice.dx, lattice.dy),
                       bound + reach, ox, oy, rings.edges, rings.tree, layout.count, layout.length_mm)
        return
    # cells in batches, so that the measured distances held at once stay within MEASURED_VALUES
    step = max(1, MEASURED_VALUES // (len(ring_sets) * f * f))
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
                measured.append(np.sqrt(squared, out=squared))
        measured = (measured[0] if len(measured) == 1 else np.concatenate(measured) if measured
                    else np.zeros((0, f * f), dtype=np.float32))
        band_cells(target, ci, cj, pixels, models, measured, slot, layout.count, layout.length_mm)


@functools.lru_cache(maxsize=16)
def pixel_offsets(cell: int, px: float, py: float) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) offsets (mm, y up; (cell * cell,) float32, row-major, read-only) of a cell's pixel centres from
    the cell's centre."""
    v, u = (a.ravel() for a in np.meshgrid(np.arange(cell), np.arange(cell), indexing="ij"))
    ox = ((u + 0.5 - 0.5 * cell) * px).astype(np.float32)
    oy = (-(v + 0.5 - 0.5 * cell) * py).astype(np.float32)
    ox.flags.writeable = oy.flags.writeable = False
    return ox, oy
