"""Intensities become materials: a scalar volume (a CT in Hounsfield units) mapped per pixel to a blend of
materials by a piecewise-linear curve, then halftoned into droplet masks like any graded layer.

The curve is the paper's eq. 1 with the image value in place of r: between two points the fractions blend
linearly, beyond the ends they hold the end's blend. It is a function of values only
(:meth:`IntensityCurve.mix`), so a mesh's designed material field can share it. The materials file gives it::

    [intensity]                      # HU -> blend of materials, points in increasing HU
    points = [
      { value = 150, mix = { tissue = 1.0 } },
      { value = 700, mix = { bone = 1.0 } },
    ]

Voxels below the first point's value are not printed (air, fat): the solid is where the interpolated value
reaches it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from heoslice.errors import InputError
from heoslice.layers.rasterising import Grid
from heoslice.material import Material, table_material

#: Most points one curve may have.
MAX_POINTS = 256


@dataclass(frozen=True)
class IntensityCurve:
    """values: (n,) float, strictly increasing image values; mixes: (n, K) float, each point's fractions over
    ``materials`` (rows sum to 1)."""

    values: np.ndarray
    mixes: np.ndarray
    materials: tuple[Material, ...]

    def mix(self, values: np.ndarray) -> np.ndarray:
        """(..., K) float32 fractions of the materials at image values ``values`` (any shape): linear between
        the curve's points, the end blends beyond them."""
        flat = np.asarray(values, dtype=np.float64).ravel()
        out = np.stack([np.interp(flat, self.values, self.mixes[:, k]) for k in range(self.mixes.shape[1])], axis=-1)
        return out.reshape(*np.shape(values), self.mixes.shape[1]).astype(np.float32)


def read_curve(data: dict, table: dict[str, Material], where: str = "[intensity]") -> IntensityCurve:
    """The curve of a materials file's parsed [intensity] table (``data``); InputError naming ``where``."""
    points = data.get("points") if isinstance(data, dict) else None
    if not isinstance(points, list) or not 1 <= len(points) <= MAX_POINTS:
        raise InputError(f"{where}: give points = [{{ value = HU, mix = {{ MATERIAL = FRACTION, ... }} }}, ...] "
                         f"(1 to {MAX_POINTS})")
    used: dict[str, Material] = {}
    rows = []
    for number, point in enumerate(points):
        if not (isinstance(point, dict) and isinstance(point.get("mix"), dict) and point["mix"]
                and isinstance(point.get("value"), (int, float)) and not isinstance(point.get("value"), bool)):
            raise InputError(f"{where}: point {number + 1}: give {{ value = NUMBER, mix = {{ MATERIAL = FRACTION }} }}")
        for name, fraction in point["mix"].items():
            material = table_material(name, table)
            if material is None:
                raise InputError(f"{where}: point {number + 1}: unknown material {name!r} "
                                 f"(materials: {', '.join(table)})")
            if isinstance(fraction, bool) or not isinstance(fraction, (int, float)) or not 0 <= fraction:
                raise InputError(f"{where}: point {number + 1}: fraction of {name} must be a number >= 0")
            used.setdefault(material.name, material)
        rows.append((float(point["value"]), {table_material(n, table).name: float(f) for n, f in point["mix"].items()}))
    values = np.array([value for value, _ in rows])
    if not np.all(np.isfinite(values)) or np.any(np.diff(values) <= 0):
        raise InputError(f"{where}: point values must be finite and strictly increasing")
    materials = tuple(sorted(used.values(), key=lambda m: (m.channel is None, m.channel or 0, m.name)))
    mixes = np.array([[mix.get(m.name, 0.0) for m in materials] for _, mix in rows])
    totals = mixes.sum(axis=1)
    if np.any(totals <= 0):
        raise InputError(f"{where}: every point's fractions must add up to more than 0")
    return IntensityCurve(values, mixes / totals[:, None], materials)


def intensity_plane(oriented: np.ndarray, origin: np.ndarray, spacing: np.ndarray, z_mm: float,
                    grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """((H, W) float32 values, (H, W) bool inside) of an intensity volume at the layer's pixel centres:
    ``oriented`` its (z, y, x) array along the printer's axes, ``origin`` printer (z, y, x) mm of its first
    voxel, ``spacing`` (3,) mm; trilinear between voxel centres, and inside the volume's voxels as cells: up to
    half a voxel beyond the outermost centres, where the outermost value holds (as a label map's voxels are cells,
    so that a scan's first and last slices print their whole thickness)."""
    x, y = grid.centres()
    k = (z_mm - origin[0]) / spacing[0]
    values = np.zeros((grid.height, grid.width), dtype=np.float32)
    inside = np.zeros((grid.height, grid.width), dtype=bool)
    if not -0.5 <= k <= oriented.shape[0] - 0.5:
        return values, inside
    k = min(max(k, 0.0), oriented.shape[0] - 1.0)
    below = min(int(np.floor(k)), max(oriented.shape[0] - 2, 0))
    weight = np.float32(k - below)
    plane = oriented[below].astype(np.float32)
    if oriented.shape[0] > 1:
        plane = plane + weight * (oriented[below + 1].astype(np.float32) - plane)
    gy = (y - origin[1]) / spacing[1]
    gx = (x - origin[2]) / spacing[2]
    rows = (gy >= -0.5) & (gy <= plane.shape[0] - 0.5)  # np.interp holds the end values beyond the centres
    columns = (gx >= -0.5) & (gx <= plane.shape[1] - 0.5)
    if not rows.any() or not columns.any():
        return values, inside
    ry, cx = np.flatnonzero(rows), np.flatnonzero(columns)
    along_x = np.stack([np.interp(gx[cx], np.arange(plane.shape[1]), row) for row in plane])  # (ny, w')
    block = np.stack([np.interp(gy[ry], np.arange(plane.shape[0]), column) for column in along_x.T], axis=1)
    values[np.ix_(ry, cx)] = block
    inside[np.ix_(ry, cx)] = True
    return values, inside
