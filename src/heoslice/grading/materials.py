"""The materials of a graded layer's families: what each interior starts from (its contour's material, its
shell's, or --from) and the fraction of the target per sub-region (eq. 1)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from heoslice.grading.families import Family
from heoslice.grading.field import FamilyField
from heoslice.grading.labels import LayerRegions, family_of, label_fractions
from heoslice.grading.materials_kernels import values_at_points
from heoslice.grading.search import nearest_edges, ring_tree
from heoslice.grading.spec import GradeSpec
from heoslice.layers.rasterising import Grid
from heoslice.material import evaluate

#: Most pixels whose nearest starting-ring point is measured at once by :func:`pixel_contour_values`.
_PIXELS_AT_ONCE = 1 << 20


def _family_sources(spec: GradeSpec, shell, point_mix):
    """How one family's contour material is read: (its shell's own Material or None, use the points' mixes?)."""
    shells = dict(spec.shells)
    if shell is not None and int(shell) in shells:
        return shells[int(shell)], False
    return None, point_mix is not None


def point_mixes(spec: GradeSpec, point_material: np.ndarray | None) -> np.ndarray | None:
    """The contour points' material mixes over ``spec.channel_materials()`` ((p, K) float, rows summing to 1):
    ``point_material`` as it is when it is already (p, K), or a material fraction m ((p,) in [0, 1]) as
    1 - m of the base and m of the second material; None without one (or without a second material)."""
    if point_material is None:
        return None
    values = np.asarray(point_material, dtype=np.float64)
    if values.ndim == 2:
        return values
    if spec.second is None:
        return None
    m = np.clip(values, 0.0, 1.0)
    mix = np.zeros((len(m), len(spec.channel_materials())))
    mix[:, spec.channel_index(spec.base)] = 1.0 - m
    mix[:, spec.channel_index(spec.second)] += m
    return mix


def _start_material(spec: GradeSpec, family: Family, own):
    """The Material a family's interior starts from when it is one material (its shell's, or --from), else None."""
    if own is not None:
        return own
    return spec.start if spec.start is not None and not family.nested else None


#: Whether every start mix between low and high ((K,) float each, per channel) gives family ``number``'s
#: pixels the same choices (its cells may then start from one of them: :func:`contour_values`).
JetsAsOne = Callable[[int, np.ndarray, np.ndarray], bool]


def family_starts(regions: LayerRegions, spec: GradeSpec, loop_shell, point_material,
                  as_one: JetsAsOne | None = None) -> list[np.ndarray]:
    """Per family, the mix of the K channel materials its interior starts from at each lattice cell (its
    contour's material, or its shell's, or --from): (cells_r, cells_c, K) float, summing to 1.
    ``point_material``: the contour points' mixes or fractions (:func:`point_mixes`); ``as_one``: where the
    contour's mixes (clipped to [0, 1]) are that close, one of them serves every cell."""
    materials = spec.channel_materials()
    point_mix = point_mixes(spec, point_material)
    mixes = []
    for number, (family, field) in enumerate(zip(regions.families, regions.fields)):
        shell = None if loop_shell is None else loop_shell[family.outer]
        own, use_mix = _family_sources(spec, shell, point_mix)
        start = _start_material(spec, family, own)
        mix = np.zeros((field.lattice.rows, field.lattice.cols, len(materials)))
        if start is not None:
            mix[..., spec.channel_index(start)] = 1.0
        elif use_mix:
            close = None if as_one is None else (
                lambda low, high, number=number: as_one(number, np.clip(low, 0.0, 1.0), np.clip(high, 0.0, 1.0)))
            mix[...] = np.clip(contour_values(field, point_mix, close), 0.0, 1.0)
        else:
            mix[..., spec.channel_index(spec.base)] = 1.0
        mixes.append(mix)
    return mixes


def target_fractions(regions: LayerRegions, spec: GradeSpec) -> np.ndarray:
    """Fraction of the target material per label ((label_count,) float; zeros without a gradient)."""
    if spec.function is None or spec.target is None:
        return np.zeros(regions.label_count)
    return label_fractions(regions, lambda r: evaluate(spec.function, r))


def contour_values(field: FamilyField, values: np.ndarray,
                   as_one: Callable[[np.ndarray, np.ndarray], bool] | None = None) -> np.ndarray:
    """Per-point values ((p,) or (p, c)) of the layer's loops taken at each cell's nearest
    starting-ring point, interpolated between the layer's points on either side of it
    (an edge may span several, :class:`RingEdges`): (cells_r, cells_c[, c]) float.

    Where every point of the starting rings has the same value (a gradient along z, through a layer), or
    ``as_one(low, high)`` says that any value between the points' least and greatest ((c,) each) will do
    (the same gradient, whose points differ in rounding), the first point's value is every cell's, and the
    cells' nearest points are not measured: an interpolated value lies between its two points' (to within
    a rounding of float64, far inside the margin ``as_one`` leaves for float32)."""
    edges = field.start_edges()
    values = np.asarray(values, dtype=np.float64)[edges.knot_point]
    if len(values) and ((values == values[:1]).all() or (
            as_one is not None and as_one(values.min(axis=0).reshape(-1),
                                          values.max(axis=0).reshape(-1)))):
        return np.broadcast_to(values[0], (field.lattice.rows, field.lattice.cols) + values.shape[1:])
    foot, edge = field.nearest()
    at_feet = values_at_points(foot, edge, edges, values.reshape(len(values), -1))
    return at_feet[..., 0] if values.ndim == 1 else at_feet


def pixel_start_colors(regions: LayerRegions, spec: GradeSpec, loop_shell, point_colors, point_material,
                       grid: Grid) -> np.ndarray:
    """The colour each family's interior starts from at each of its pixels ((rows, cols, 3) float 0..255 over
    the layer's box, 0 off every family): its shell's or --from's colour, or else its contour's colour, or
    the display colour of its contour's material mix (:func:`point_mixes`: the materials' colours mixed),
    at the pixel centre's nearest starting-ring point."""
    b = regions.box
    out = np.zeros((b[1] - b[0], b[3] - b[2], 3))
    point_mix = point_mixes(spec, point_material)
    palette = np.array([m.color for m in spec.channel_materials()], dtype=np.float64)
    for family, field, own_pixels in zip(regions.families, regions.fields, family_of(regions)):
        shell = None if loop_shell is None else loop_shell[family.outer]
        own, use_mix = _family_sources(spec, shell, point_mix)
        start = _start_material(spec, family, own)
        if start is not None:
            color = np.asarray(start.color, dtype=np.float64)
        elif point_colors is not None:
            color = pixel_contour_values(field, point_colors, own_pixels, grid)
        elif use_mix:
            color = np.clip(pixel_contour_values(field, point_mix, own_pixels, grid), 0.0, 1.0) @ palette
        else:
            color = np.asarray(spec.base.color, dtype=np.float64)
        r0, r1, c0, c1 = field.box
        target = out[r0 - b[0]:r1 - b[0], c0 - b[2]:c1 - b[2]]
        np.copyto(target, np.broadcast_to(color, target.shape), where=own_pixels[..., None])
    return out


def pixel_contour_values(field: FamilyField, values: np.ndarray, own: np.ndarray, grid: Grid) -> np.ndarray:
    """Per-point values ((p,) or (p, c)) of the layer's loops at the nearest starting-ring point of each
    pixel centre of the family's box where ``own`` ((rows, cols) bool) holds, interpolated between the
    layer's points either side of it: (rows, cols[, c]) float, 0 elsewhere.

    A pixel p within h (half a cell's diagonal) of its cell's centre c, whose nearest starting-ring
    point (:meth:`FamilyField.nearest`) is d(c) away, has its own nearest point within d(c) + 2 h of
    c: the edges there are every candidate, and their nearest (:func:`nearest_edges`) is exact.
    """
    edges = field.start_edges()
    foot, _ = field.nearest()
    lattice, f = field.lattice, field.lattice.cell
    rows, cols = own.shape
    padded = np.zeros((lattice.rows * f, lattice.cols * f), dtype=bool)
    padded[:rows, :cols] = own
    ci, cj = np.nonzero(padded.reshape(lattice.rows, f, lattice.cols, f).any(axis=(1, 3)))
    v, u = (a.ravel() for a in np.meshgrid(np.arange(f), np.arange(f), indexing="ij"))
    ox, oy = (u + 0.5 - 0.5 * f) * grid.px, -(v + 0.5 - 0.5 * f) * grid.py
    reach = np.hypot(lattice.dx, lattice.dy) * (1 + 1e-9) + 1e-6
    values = np.asarray(values, dtype=np.float64)[edges.knot_point]
    columns = values.reshape(len(values), -1)
    out = np.zeros((lattice.rows * f, lattice.cols * f, columns.shape[1]))
    tree = ring_tree(edges)
    step = max(1, _PIXELS_AT_ONCE // (f * f))
    for first in range(0, len(ci), step):
        i, j = ci[first:first + step], cj[first:first + step]
        cx, cy = lattice.x0 + (j + 0.5) * lattice.dx, lattice.y0 - (i + 0.5) * lattice.dy
        radius = np.hypot(cx - foot[0][i, j], cy - foot[1][i, j]) + reach
        edge = np.maximum(nearest_edges(cx, cy, radius, ox, oy, edges, tree), 0).astype(np.int64)
        centres = np.stack([cx[:, None] + ox[None, :], cy[:, None] + oy[None, :]])
        rows_at = (i[:, None] * f + v[None, :]).ravel()
        cols_at = (j[:, None] * f + u[None, :]).ravel()
        out[rows_at, cols_at] = values_at_points(centres, edge, edges, columns).reshape(len(rows_at), -1)
    out = np.where(own[..., None], out[:rows, :cols], 0.0)
    return out[..., 0] if values.ndim == 1 else out
