"""A design evaluated in 3D: the material fraction f(r) at every solid voxel from that voxel's own distance to the
reference (issue 44), the ``field`` interior of ``heoslice slice``.

r is the design's normalisation of the exact 3-D distance (:func:`heoslice.material.references.normalise`
with the range ``color`` recorded), so a voxel on the surface gets the r its vertex got. Plane, point and axis
distances are closed-form and vectorised. A surface reference is measured exactly
(:func:`heoslice.material.surface.surface_distance`) on a lattice of :data:`CELL` x :data:`CELL`-pixel cells
first: the distance is 1-Lipschitz, so every pixel centre of a cell lies within d(c) +- h of the cell centre's
distance d(c) (h: the farthest pixel centre from c), and where that interval maps to r values less than
:data:`R_TOLERANCE` apart (clipped at 0 or 1, or a range wide against the cell) their midpoint is within
R_TOLERANCE / 2 of every pixel's true r; the other cells' pixels are measured one by one.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from heoslice.errors import InputError
from heoslice.material.design import INTERIORS, Design, surface_path
from heoslice.material.functions import evaluate
from heoslice.material.references import REFERENCES, Reference, grid_distance, normalise, reference_distance

__all__ = ["CELL", "INTERIORS", "R_TOLERANCE", "MaterialField", "depth_field", "material_field", "solid_box"]
#: Side of a lattice cell, pixels (:func:`MaterialField.layer_r` for a surface reference).
CELL = 16
#: Largest error of a voxel's r where the lattice settles it (twice the bound the midpoint keeps).
R_TOLERANCE = 1e-3


@dataclass(frozen=True, eq=False)
class MaterialField:
    """A :class:`Design` ready to evaluate at points: its reference resolved (a surface indexed). ``bands``
    (N_R) steps r to the sub-region values k / N_R, k = max(ceil(r N_R), 1) (eq. 8's sub-regions measured in
    3D, ``slice --grade --depth-from surface``); None keeps r continuous."""

    design: Design
    reference: Reference
    bands: int | None = None

    def r_at(self, points: np.ndarray) -> np.ndarray:
        """Exact r (n,) in [0, 1] at points (n, 3) mm: the design's normalisation of the 3-D distance."""
        return normalise(reference_distance(self.reference, points), self.design.r_range)

    def fraction(self, r: np.ndarray) -> np.ndarray:
        """The share of the target material f(r) clipped to [0, 1] (eq. 1), of r's shape, in r's precision (an
        expression undefined at some r is refused by :func:`heoslice.material.evaluate`)."""
        r = np.asarray(r)
        if self.bands is not None:
            r = np.maximum(np.ceil(r * self.bands), 1.0) / self.bands
        f = evaluate(self.design.function, r.ravel()).reshape(r.shape)
        return np.clip(f, 0.0, 1.0, out=f)

    def layer_fraction(self, packed: np.ndarray, grid, z: float) -> tuple[tuple[int, int, int, int], np.ndarray]:
        """f(r) clipped to [0, 1] over the box of a layer's solid pixels (``packed``: (h, ceil(w / 8)) uint8, MSB
        first) cut at height z (mm) on ``grid``: (the box (first row, end row, first column, end column), f as an
        array that broadcasts to the box: (1, 1), (rows, 1) or (1, cols) where it does not change along a grid
        axis), exact at every solid pixel centre (to :data:`R_TOLERANCE` / 2 in r for a surface), anything
        elsewhere in the box."""
        box, r = self.layer_distance(packed, grid, z)
        # f to the halftone's 1/256 needs no more than single precision: r (in [0, 1]) rounds by 6e-8
        return box, self.fraction(r.astype(np.float32))

    def layer_distance(self, packed: np.ndarray, grid, z: float) -> tuple[tuple[int, int, int, int], np.ndarray]:
        """r over the box of a layer's solid pixels, as :meth:`layer_fraction` gives f(r) (the box, and r
        broadcasting to it; 0 at a surface reference's pixels outside the solid)."""
        r0, r1, c0, c1 = solid_box(packed, grid.width)
        x = grid.x_left + (np.arange(c0, c1) + 0.5) * grid.px
        y = grid.y_top - (np.arange(r0, r1) + 0.5) * grid.py
        if REFERENCES[self.reference.kind].closed_form is not None:
            r = normalise(grid_distance(self.reference, x, y, z), self.design.r_range)
        else:
            solid = np.unpackbits(packed[r0:r1], axis=1, count=grid.width)[:, c0:c1].view(bool)
            rows, cols = np.nonzero(solid)
            r = np.zeros(solid.shape)
            r[rows, cols] = self.layer_r(rows + r0, cols + c0, grid, z)
        return (r0, r1, c0, c1), r

    def layer_r(self, rows: np.ndarray, cols: np.ndarray, grid, z: float) -> np.ndarray:
        """r (n,) at the centres of pixels (rows (n,), cols (n,) int) of a layer cut at height z (mm) on
        ``grid`` (:class:`heoslice.layers.rasterising.Grid`); within R_TOLERANCE / 2 of each pixel's exact r
        for a surface reference (the module's lattice), exact otherwise."""
        x = grid.x_left + (cols + 0.5) * grid.px
        y = grid.y_top - (rows + 0.5) * grid.py
        if self.reference.kind != "surface":
            return self.r_at(np.column_stack([x, y, np.full(len(x), float(z))]))
        cell_of = (rows // CELL).astype(np.int64) * (int(grid.width) // CELL + 1) + cols // CELL
        cells, inverse = np.unique(cell_of, return_inverse=True)
        per_row = int(grid.width) // CELL + 1
        ci, cj = cells // per_row, cells % per_row
        cx = grid.x_left + (cj * CELL + CELL / 2) * grid.px
        cy = grid.y_top - (ci * CELL + CELL / 2) * grid.py
        reach = np.hypot((CELL - 1) / 2 * grid.px, (CELL - 1) / 2 * grid.py) * (1 + 1e-12)
        centre = reference_distance(self.reference, np.column_stack([cx, cy, np.full(len(cx), float(z))]))
        low = normalise(centre - reach, self.design.r_range)
        high = normalise(centre + reach, self.design.r_range)
        settled = (high - low) <= R_TOLERANCE
        r = ((low + high) / 2)[inverse]
        measure = ~settled[inverse]
        if measure.any():
            r[measure] = self.r_at(np.column_stack([x[measure], y[measure], np.full(int(measure.sum()), float(z))]))
        return r


def depth_field(vertices: np.ndarray, faces: np.ndarray, design: Design, bands: int | None) -> MaterialField:
    """The field of a grading measured from the model's own 3-D surface (vertices (n, 3) mm, faces (m, 3)):
    r = the exact distance to the nearest triangle over ``design.r_range`` (0 .. the depth), in ``bands``."""
    from heoslice.material.surface import build_surface_index

    return MaterialField(design, Reference("surface", surface=build_surface_index(vertices, faces)), bands)


def solid_box(packed: np.ndarray, width: int) -> tuple[int, int, int, int]:
    """(first row, last row + 1, first column, last column + 1) of a packed layer's solid pixels, the columns to
    whole bytes (clipped to ``width``); an empty box (0, 0, 0, 0) for an empty layer."""
    rows = np.flatnonzero(packed.any(axis=1))
    if not len(rows):
        return 0, 0, 0, 0
    columns = np.flatnonzero(packed[rows[0]:rows[-1] + 1].any(axis=0))
    return int(rows[0]), int(rows[-1]) + 1, 8 * int(columns[0]), min(8 * (int(columns[-1]) + 1), int(width))


def material_field(design: Design, model: Path | None = None) -> MaterialField:
    """The design's field: a surface reference's mesh read (its recorded path, else beside ``model``), checked
    against its recorded SHA-256, scaled as the design is, and indexed. InputError when it is missing or
    changed."""
    ref = design.reference
    if ref.kind != "surface":
        return MaterialField(design, Reference(ref.kind, ref.point, ref.direction))
    from heoslice.material.surface import build_surface_index
    from heoslice.mesh import load_mesh

    path = surface_path(design, model)
    mesh = load_mesh(path)
    if ref.surface_sha256 is not None and mesh.sha256 != ref.surface_sha256:
        raise InputError(f"{model or 'model'}: the design's reference surface {path} has changed since the model "
                         "was coloured (its SHA-256 differs); colour the model again")
    return MaterialField(design, Reference("surface", surface=build_surface_index(
        mesh.vertices * ref.surface_scale, mesh.faces)))
