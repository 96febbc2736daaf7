"""A design evaluated in 3D: the material fraction f(r) at every solid voxel from that voxel's own distance to the
reference (issue 44), the ``field`` interior of ``heoslice slice``.

r is the design's normalisation of the exact 3-D distance (:func:`heoslice.material.references.normalise`
with the range ``color`` recorded), so a voxel on the surface gets the r its vertex got. Plane, point and axis
distances are closed-form and vectorised. A surface reference is measured exactly at the corners of cells of a
layer (:func:`heoslice.material.surface.layer_r`), and a cell's pixels take r from proven bounds on the distance
between those corners (its 1-Lipschitz bound, and a second-order one: over a cell of sides a, b at least m away
the bilinear interpolant of the corners' distances is at most (a^2 + b^2) / 8m above the distance, and below it
by at most what the corners' own nearest triangles spread; near the surface, above it by at most its largest excess
at a corner over the tangent planes of the distances to the triangles within reach), within :data:`R_TOLERANCE` / 2
of every pixel's true r;
cells the bounds cannot settle are halved, down to pixels measured one by one.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from heoslice.errors import InputError
from heoslice.material.design import INTERIORS, Design, surface_path
from heoslice.material.functions import evaluate
from heoslice.material.references import (
    REFERENCES,
    Reference,
    grid_distance,
    grid_square,
    normalise,
    reference_distance,
)

__all__ = [
    "INTERIORS", "R_ERROR", "R_STEPS", "R_TOLERANCE", "LayerSquare", "MaterialField", "depth_field", "material_field",
    "solid_box",
]
#: Steps of r in a table of codes read per voxel (:meth:`MaterialField.layer_steps`): a voxel's r is rounded to
#: the nearest k / R_STEPS, which adds at most 1 / (2 R_STEPS) = 3.1e-5 to its error; k fits uint16, and the
#: table of dither levels read per voxel is 32 KB (a quarter of what 65,535 steps take: fewer cache misses).
R_STEPS = 16383
#: The largest error of a voxel's r to a surface reference, its bounds' and the rounding to r's steps together.
R_ERROR = 1e-3
#: Twice the largest error of a voxel's r where a surface reference's bounds settle it (the bounds' interval
#: width): R_ERROR less the rounding to r's steps, on either side of the interval's midpoint.
R_TOLERANCE = 2 * (R_ERROR - 0.5 / R_STEPS)


@dataclass(frozen=True)
class LayerSquare:
    """A plane's, point's or axis's squared distance over a layer's solid pixels: their ``box`` (as
    :func:`solid_box`), the ``frame`` of its pixel centres (u of the box's first column, u step per column, v of
    its first row, v step per row: mm from the reference's point along x and y), the squared distance in u and v
    (``square``: (A, B, C, D, E, F) of :func:`heoslice.material.references.grid_square`) and the design's
    ``r_range`` (R0, R1) mm: r = (sqrt(max(Q, 0)) - R0) / (R1 - R0) clipped to [0, 1] at each pixel."""

    box: tuple[int, int, int, int]
    frame: tuple[float, float, float, float]
    square: tuple[float, ...]
    r_range: tuple[float, float]


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

    @cached_property
    def fraction_table(self) -> np.ndarray:
        """f(r) clipped to [0, 1] (R_STEPS + 1,) float32 at r = k / R_STEPS (:meth:`layer_steps`)."""
        return self.fraction(np.arange(R_STEPS + 1, dtype=np.float32) / np.float32(R_STEPS))

    def layer_square(self, packed: np.ndarray, grid, z: float) -> LayerSquare | None:
        """A plane's, point's or axis's squared distance over the solid pixels of a layer (``packed``: (h, ceil(w /
        8)) uint8, MSB first) cut at height z (mm) on ``grid``, as :class:`LayerSquare`; None for a surface."""
        if REFERENCES[self.reference.kind].closed_form is None:
            return None
        box = solid_box(packed, grid.width)
        point = self.reference.point
        frame = (grid.x_left + (box[2] + 0.5) * grid.px - point[0], grid.px,
                 grid.y_top - (box[0] + 0.5) * grid.py - point[1], -grid.py)
        return LayerSquare(box, frame, grid_square(self.reference, z), tuple(map(float, self.design.r_range)))

    def layer_steps(self, packed: np.ndarray, grid, z: float) -> tuple[tuple[int, int, int, int], np.ndarray]:
        """The box of a layer's solid pixels (as :meth:`layer_fraction`) and, at each of them, its r to a surface
        reference as the step k of r = k / R_STEPS nearest it (uint16 (rows, cols); anything up to 65535
        elsewhere in the box, which a halftone may read before it masks the solid): f then read from
        :attr:`fraction_table` per voxel, in one compiled pass, instead of evaluated at every voxel. A plane,
        point or axis gives its r as :meth:`layer_square` (ValueError here)."""
        if REFERENCES[self.reference.kind].closed_form is not None:  # the rule layer_square applies
            raise ValueError(f"a {self.reference.kind} reference's r over a layer is its layer_square")
        r0, r1, c0, c1 = solid_box(packed, grid.width)
        from heoslice.material.surface import packed_layer_steps

        x0, y0 = grid.x_left + (c0 + 0.5) * grid.px, grid.y_top - (r0 + 0.5) * grid.py
        steps = packed_layer_steps(packed[r0:r1], c0, c1 - c0, (x0, grid.px, y0, -grid.py, z), self.reference.surface,
                                   self.design.r_range, R_TOLERANCE, R_STEPS)
        return (r0, r1, c0, c1), steps

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
            r = self._surface_r(solid, (x[0] if len(x) else 0.0, grid.px, y[0] if len(y) else 0.0, -grid.py, z))
        return (r0, r1, c0, c1), r

    def layer_r(self, rows: np.ndarray, cols: np.ndarray, grid, z: float) -> np.ndarray:
        """r (n,) at the centres of pixels (rows (n,), cols (n,) int) of a layer cut at height z (mm) on
        ``grid`` (:class:`heoslice.layers.rasterising.Grid`); within R_TOLERANCE / 2 of each pixel's exact r
        for a surface reference, exact otherwise."""
        x = grid.x_left + (cols + 0.5) * grid.px
        y = grid.y_top - (rows + 0.5) * grid.py
        if self.reference.kind != "surface":
            return self.r_at(np.column_stack([x, y, np.full(len(x), float(z))]))
        if not len(rows):
            return np.zeros(0)
        r0, c0 = int(rows.min()), int(cols.min())
        solid = np.zeros((int(rows.max()) + 1 - r0, int(cols.max()) + 1 - c0), dtype=bool)
        solid[rows - r0, cols - c0] = True
        frame = (grid.x_left + (c0 + 0.5) * grid.px, grid.px, grid.y_top - (r0 + 0.5) * grid.py, -grid.py, z)
        return self._surface_r(solid, frame)[rows - r0, cols - c0]

    def _surface_r(self, solid: np.ndarray, frame: tuple) -> np.ndarray:
        """r (h, w) at the solid pixels (h, w) of a layer whose pixel centres ``frame`` places
        (:func:`heoslice.material.surface.layer_r`), 0 elsewhere."""
        from heoslice.material.surface import layer_r

        return layer_r(solid, frame, self.reference.surface, self.design.r_range, R_TOLERANCE)


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
    against its recorded SHA-256, scaled as the design is, and indexed; the field's design records the path it
    was read from (a stack's manifest then names the file its slice used). InputError when it is missing or
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
    design = replace(design, reference=replace(ref, surface=str(Path(path).resolve())))
    return MaterialField(design, Reference("surface", surface=build_surface_index(
        mesh.vertices * ref.surface_scale, mesh.faces)))
