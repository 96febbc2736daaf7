"""Rasterising: turn a layer's contour loops into a solid mask and a layer image.

A pixel is solid when its centre lies inside the layer's region: the loops wind
more than 0 times around it, so a cavity (clockwise loop) stays empty and a nested
shell (a second counter-clockwise loop) stays solid. The mask is built scanline-style by a
compiled kernel: loop edges are crossed with the pixel-row centres, the winding number
is accumulated over each row's sorted crossings, and the solid spans are filled
straight into a packed 1-bit image (the TIFF layout).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from heoslice.errors import InputError
from heoslice.jit import f64, i64
from heoslice.layers.rasterising_kernels import _packed_mask

MM_PER_INCH = 25.4


@dataclass(frozen=True)
class Grid:
    """The pixel grid of every layer image.

    Pixel (row r, column c) has its centre at x = x_left + (c + 1/2) px,
    y = y_top - (r + 1/2) py (mm): images seen from above, +x right, +y up.
    """

    width: int
    height: int
    x_left: float
    y_top: float
    px: float
    py: float

    @property
    def dpi(self) -> tuple[float, float]:
        return (MM_PER_INCH / self.px, MM_PER_INCH / self.py)

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Pixel-centre coordinates: x (width,) and y (height,) float, mm."""
        x = self.x_left + (np.arange(self.width) + 0.5) * self.px
        y = self.y_top - (np.arange(self.height) + 0.5) * self.py
        return x, y


def grid_for(bounds_xy: np.ndarray, dpi: tuple[float, float], margin_mm: float = 1.0,
             canvas_mm: tuple[float, float] | None = None) -> Grid:
    """A grid covering bounds_xy ((2, 2) float [[x_min, y_min], [x_max, y_max]], mm) at dpi.

    Without a canvas, the grid is the bounding box plus ``margin_mm`` on each side;
    with ``canvas_mm`` (width, height), a fixed build area centred on the part.
    """
    px, py = MM_PER_INCH / float(dpi[0]), MM_PER_INCH / float(dpi[1])
    low = np.asarray(bounds_xy[0], dtype=np.float64)
    high = np.asarray(bounds_xy[1], dtype=np.float64)
    centre = (low + high) / 2.0
    if canvas_mm is None:
        size = high - low + 2.0 * margin_mm
    else:
        size = np.asarray(canvas_mm, dtype=np.float64)
        if np.any(size < high - low):
            raise InputError(
                f"canvas_mm: {size[0]:g} x {size[1]:g} mm is smaller than the part "
                f"({high[0] - low[0]:.3f} x {high[1] - low[1]:.3f} mm)"
            )
    width = int(np.ceil(size[0] / px - 1e-9))
    height = int(np.ceil(size[1] / py - 1e-9))
    return Grid(width=width, height=height, x_left=float(centre[0] - width * px / 2.0),
                y_top=float(centre[1] + height * py / 2.0), px=px, py=py)


def packed_mask_and_count(points: np.ndarray, offsets: np.ndarray, grid: Grid) -> tuple[np.ndarray, int]:
    """The solid mask as packed bits, (height, ceil(width / 8)) uint8 most significant bit first (the
    layout of a 1-bit TIFF row and of ``np.packbits(mask, axis=1)``), and its number of solid pixels.

    points: (p, 2) float, mm, loop after loop; offsets: (loops + 1,) int. A row centre exactly at an edge
    end counts once (rows r with v_low < r <= v_high, v the row coordinate); a pixel centre exactly on an
    edge counts as right of it. One compiled pass (:mod:`heoslice.layers.rasterising_kernels`) crosses the
    edges with the row centres, sorts each row's crossings and fills the solid spans byte by byte; the
    zeroed image is allocated lazily, so rows the loops do not reach cost nothing.
    """
    packed = np.zeros((grid.height, -(-grid.width // 8)), dtype=np.uint8)
    if len(points) == 0:
        return packed, 0
    solid = _packed_mask(f64(points), i64(offsets), int(grid.width), int(grid.height), float(grid.x_left),
                         float(grid.y_top), float(grid.px), float(grid.py), packed)
    return packed, int(solid)


def part_rows(points: np.ndarray, grid: Grid) -> tuple[int, int]:
    """(first, stop): the rows of ``grid`` whose centres the loops' points ((p, 2) float, mm) span, a row
    more either side; no other row holds a solid pixel (:func:`packed_mask_and_count`)."""
    if len(points) == 0:
        return 0, 0
    v = (grid.y_top - f64(points)[:, 1]) / grid.py - 0.5
    first, stop = math.floor(float(v.min())), math.floor(float(v.max())) + 2
    return min(max(first, 0), grid.height), min(max(stop, 0), grid.height)


def packed_mask(points: np.ndarray, offsets: np.ndarray, grid: Grid) -> np.ndarray:
    """The solid mask as packed bits (:func:`packed_mask_and_count` without the count)."""
    return packed_mask_and_count(points, offsets, grid)[0]


def solid_mask(points: np.ndarray, offsets: np.ndarray, grid: Grid) -> np.ndarray:
    """(height, width) bool: pixel centres the loops wind more than 0 times around."""
    return np.unpackbits(packed_mask(points, offsets, grid), axis=1, count=grid.width).astype(bool)


def contour_pixels(mask: np.ndarray) -> np.ndarray:
    """(k, 2) int (row, col) of solid pixels with an empty 4-neighbour (or on the image edge)."""
    padded = np.pad(mask, 1, constant_values=False)
    interior = (padded[:-2, 1:-1] & padded[2:, 1:-1] & padded[1:-1, :-2] & padded[1:-1, 2:])
    return np.argwhere(mask & ~interior)


def paint_contour(image: np.ndarray, mask: np.ndarray, points: np.ndarray, point_colors: np.ndarray,
                  grid: Grid) -> None:
    """Colour each contour pixel of ``image`` ((h, w, 3+) uint8) with its nearest contour point's colour.

    points: (p, 2) float, mm; point_colors: (p, 3) float 0..255 (the colours the
    intersection points carry, interpolated along their mesh edges).
    """
    from scipy.spatial import cKDTree

    pixels = contour_pixels(mask)
    if len(pixels) == 0 or len(points) == 0:
        return
    xy = np.column_stack([grid.x_left + (pixels[:, 1] + 0.5) * grid.px,
                          grid.y_top - (pixels[:, 0] + 0.5) * grid.py])
    _, nearest = cKDTree(points).query(xy, k=1)
    image[pixels[:, 0], pixels[:, 1], :3] = np.clip(np.rint(point_colors[nearest]), 0, 255).astype(np.uint8)


def render_layer(points: np.ndarray, offsets: np.ndarray, grid: Grid, *,
                 point_colors: np.ndarray | None = None,
                 base_color: tuple[int, int, int] = (255, 255, 255)) -> tuple[np.ndarray, int]:
    """One layer image and its solid pixel count.

    Without point colours: the packed 1-bit mask ((h, ceil(w / 8)) uint8, see
    :func:`packed_mask`). With point colours ((p, 3) float): (h, w, 4) uint8 RGBA,
    alpha 255 solid, interior ``base_color``, contour pixels coloured from the
    nearest intersection point.
    """
    packed, solid = packed_mask_and_count(points, offsets, grid)
    if point_colors is None:
        return packed, solid
    mask = np.unpackbits(packed, axis=1, count=grid.width).astype(bool)
    image = np.zeros((grid.height, grid.width, 4), dtype=np.uint8)
    image[mask] = (*base_color, 255)
    paint_contour(image, mask, points, point_colors, grid)
    return image, solid
