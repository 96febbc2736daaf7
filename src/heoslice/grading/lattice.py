"""The coarse lattice over a family's pixel box and the exact distances to a ring set at its cell centres.

Centres are measured in blocks of BLOCK x BLOCK cells that share candidate edges; a
ring set's passes over a lattice (:class:`RingMeasures`) are a pure function of its edges
and the lattice, so a layer with the same edges (an extruded hole) takes them again.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from heoslice.grading.edges import RingEdges
from heoslice.grading.lattice_kernels import BLOCK, block_bounds_of, block_edges, block_passes, signed_feet
from heoslice.grading.search import RingSet, ring_tree
from heoslice.layers.rasterising import Grid

#: Target lattice cell size, mm (cells are a whole number of pixels, 4 to 16).
CELL_MM = 0.5


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


def padded(lattice: Lattice) -> Lattice:
    """The lattice grown by one cell on every side (cell (i, j) of ``lattice`` is its cell (i + 1, j + 1))."""
    return Lattice(row0=lattice.row0 - lattice.cell, col0=lattice.col0 - lattice.cell, cell=lattice.cell,
                   rows=lattice.rows + 2, cols=lattice.cols + 2, x0=lattice.x0 - lattice.dx,
                   y0=lattice.y0 + lattice.dy, dx=lattice.dx, dy=lattice.dy)


def lattice_for(box: tuple[int, int, int, int], grid: Grid, cell_mm: float = CELL_MM) -> Lattice:
    """A lattice covering pixel rows box[0]:box[1] and columns box[2]:box[3] of ``grid``."""
    cell = min(max(round(cell_mm / max(grid.px, grid.py)), 4), 16)
    row0, row1, col0, col1 = box
    rows = max(1, -(-(row1 - row0) // cell))
    cols = max(1, -(-(col1 - col0) // cell))
    return Lattice(row0=row0, col0=col0, cell=cell, rows=rows, cols=cols,
                   x0=grid.x_left + col0 * grid.px, y0=grid.y_top - row0 * grid.py,
                   dx=cell * grid.px, dy=cell * grid.py)


@dataclass(frozen=True)
class BlockBounds:
    """An upper bound of the distance to a ring set at the centres of blocks of BLOCK x BLOCK cells.

    ``blocks`` is the block lattice; per block ((rows, cols)): ``edge`` the edge found nearest
    its centre and ``upper`` the exact distance to it (mm).
    """

    blocks: Lattice
    edge: np.ndarray
    upper: np.ndarray


def block_lattice(lattice: Lattice) -> Lattice:
    """The lattice of a lattice's blocks of BLOCK x BLOCK cells (the last row and column may be cut short)."""
    b = BLOCK
    return Lattice(row0=lattice.row0, col0=lattice.col0, cell=lattice.cell * b, rows=-(-lattice.rows // b),
                   cols=-(-lattice.cols // b), x0=lattice.x0, y0=lattice.y0, dx=lattice.dx * b, dy=lattice.dy * b)


def block_bounds(edges: RingEdges, lattice: Lattice, tree: tuple) -> BlockBounds:
    """Upper bounds of the distance at block centres: the exact distance to the edge found nearest each
    centre (:func:`heoslice.grading.search.nearest_edges`' search, in float32, among the edges within the
    centre's distance to the nearest chunk's first point, which holds the nearest; compiled,
    :func:`heoslice.grading.lattice_kernels.block_bounds_of`)."""
    edge, upper = block_bounds_of(edges, tree, lattice, lattice.rows, lattice.cols)
    return BlockBounds(block_lattice(lattice), edge, upper)


def lattice_edges(edges: RingEdges, lattice: Lattice, tree: tuple | None = None,
                  bounds: BlockBounds | None = None, wanted: np.ndarray | None = None) -> np.ndarray:
    """The nearest edge of the rings to every cell centre ((rows, cols) int).

    Centres are taken in blocks of BLOCK x BLOCK cells. A block's centre C has an
    upper bound U of its distance (:func:`block_bounds`). A centre p at a = |p - C| from
    C has d(p) <= U + a (the distance is 1-Lipschitz), so its nearest edge is within
    U + 2 a of C: every edge within U + 2 max a of C is a candidate, and the nearest is
    exact. Blocks not ``wanted`` ((rows, cols) bool over the blocks; default all) are not
    measured: their centres get the edge found nearest their block's centre (its distance an upper bound).
    Compiled (:func:`heoslice.grading.lattice_kernels.block_edges`).
    """
    if tree is None:
        tree = ring_tree(edges)
    if bounds is None:
        bounds = block_bounds(edges, lattice, tree)
    wanted = np.ones(bounds.edge.shape, bool) if wanted is None else wanted
    return block_edges(bounds.edge, bounds.upper, wanted, lattice, lattice.rows, lattice.cols, edges, tree)


@dataclass(frozen=True)
class RingMeasures:
    """One ring set's passes over a family's padded lattice: its block bounds, the cell centres inside
    it, the blocks off the family's side of it (``far``), and the exact nearest edge ((rows, cols) int)
    of the cells of the blocks measured so far (``done``, (block rows, block cols) bool; elsewhere
    ``edge`` means nothing); ``centres`` the blocks last wanted of :func:`measured_centres` and what it
    gave for them (read-only arrays). A pure function
    of the ring set's edges and the lattice, so a layer with the same edges (an extruded hole) reuses it."""

    bounds: BlockBounds
    inside: np.ndarray
    far: np.ndarray
    edge: np.ndarray
    done: np.ndarray
    centres: tuple = ()


def ring_measures(rings: RingSet, lattice: Lattice) -> RingMeasures:
    """A ring set's RingMeasures on a lattice, no block's edges measured yet.

    A block is off the family's side (``far``) when its cells and their neighbours all are: judged at
    one of its cells, off the family's side of the rings by more than the way to the block's farthest
    cell centre plus a cell's diagonal and a half, measured exactly where the block's upper bound allows
    it. The centres inside the rings are those inside any of its loops (a family's holes, or its outer
    ring: they neither cross nor nest, so the parity of crossings decides). One compiled call
    (:func:`heoslice.grading.lattice_kernels.block_passes`).
    """
    edge, upper, inside, far = block_passes(rings.edges, rings.tree, lattice, lattice.rows, lattice.cols,
                                            rings.encloses)
    return RingMeasures(BlockBounds(block_lattice(lattice), edge, upper), inside, far,
                        np.zeros((lattice.rows, lattice.cols), dtype=np.int64), np.zeros(far.shape, dtype=bool))


def measured_centres(rings: RingSet, measures: RingMeasures, lattice: Lattice, wanted: np.ndarray
                      ) -> tuple[tuple, RingMeasures]:
    """At every cell centre: signed distance to the rings (> 0 on the family's side), its unit gradient, foot
    and edge, exact in the ``wanted`` blocks ((block rows, block cols) bool; elsewhere from the edge nearest
    the block's centre, :func:`lattice_edges`), measuring only the blocks ``measures`` does not hold yet:
    ((signed, gradient, foot, edge), the measures with them). The same blocks wanted as the last time give
    the last answer (a hole that stays while another ring of its family changes, as through a cavity)."""
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
    at = signed_feet(edge, lattice, rings.edges, measures.inside, rings.encloses) + (edge,)
    for array in at:
        array.flags.writeable = False
    return at, replace(measures, centres=(wanted, at))


def _block_cells(blocks: np.ndarray, lattice: Lattice) -> np.ndarray:
    """(rows, cols) bool over the lattice's cells from (block rows, block cols) bool over its blocks."""
    return np.repeat(np.repeat(blocks, BLOCK, axis=0), BLOCK, axis=1)[:lattice.rows, :lattice.cols]
