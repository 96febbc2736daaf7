"""Rasterising: turn a layer's contour loops into a solid mask and a layer image.

A pixel is solid when its centre lies inside the layer's region by the non-zero
winding rule, so a cavity (clockwise loop) stays empty and a nested shell (a second
counter-clockwise loop) stays solid. The mask is built scanline-style without a
Python loop: every loop edge adds +-1 at the first pixel centre right of where it
crosses each row centre, and a cumulative sum along the row gives the winding
number at every pixel centre. Work is confined to the layer's bounding box.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from heoslice.errors import InputError

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
                f"canvas {size[0]:g} x {size[1]:g} mm is smaller than the part "
                f"({high[0] - low[0]:.3f} x {high[1] - low[1]:.3f} mm)"
            )
    width = int(np.ceil(size[0] / px))
    height = int(np.ceil(size[1] / py))
    return Grid(width=width, height=height, x_left=float(centre[0] - width * px / 2.0),
                y_top=float(centre[1] + height * py / 2.0), px=px, py=py)


def parse_dpi(text: str) -> tuple[float, float]:
    """'600' -> (600, 600); '600x300' -> (600, 300). Raises InputError otherwise."""
    parts = str(text).lower().split("x")
    try:
        values = [float(part) for part in parts]
    except ValueError:
        values = []
    if len(values) == 1:
        values = values * 2
    if len(values) != 2 or not all(0 < value <= 100000 for value in values):
        raise InputError(f"--dpi: expected N or NxM with positive numbers, got {text!r}")
    return (values[0], values[1])


def _loop_edges(points: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end points ((e, 2) each) of every edge of every closed loop."""
    following = np.arange(1, len(points) + 1)
    following[offsets[1:] - 1] = offsets[:-1]
    return points, points[following]


def winding_numbers(points: np.ndarray, offsets: np.ndarray, grid: Grid) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """Winding number of the loops at every pixel centre of the loops' bounding box.

    Returns (winding (rows, cols) int16, (row0, row1, col0, col1)) where the box is
    rows row0:row1, columns col0:col1 of the grid.
    """
    if len(points) == 0:
        return np.zeros((0, 0), np.int16), (0, 0, 0, 0)
    start, end = _loop_edges(points, offsets)
    u0 = (start[:, 0] - grid.x_left) / grid.px - 0.5
    u1 = (end[:, 0] - grid.x_left) / grid.px - 0.5
    v0 = (grid.y_top - start[:, 1]) / grid.py - 0.5
    v1 = (grid.y_top - end[:, 1]) / grid.py - 0.5
    v_low = np.minimum(v0, v1)
    v_high = np.maximum(v0, v1)
    row0 = int(np.clip(np.floor(v_low.min()) + 1, 0, grid.height))
    row1 = int(np.clip(np.floor(v_high.max()) + 1, 0, grid.height))
    col0 = int(np.clip(np.ceil(min(u0.min(), u1.min())), 0, grid.width))
    col1 = int(np.clip(np.ceil(max(u0.max(), u1.max())), 0, grid.width))
    if row1 <= row0 or col1 <= col0:
        return np.zeros((0, 0), np.int16), (row0, row0, col0, col0)
    # rows r with v_low < r <= v_high, clipped to the box
    first = np.clip(np.floor(v_low) + 1, row0, row1).astype(np.int64)
    last = np.clip(np.floor(v_high) + 1, row0, row1).astype(np.int64)
    counts = last - first
    edge = np.repeat(np.arange(len(u0)), counts)
    row = np.repeat(first, counts) + (np.arange(len(edge)) - np.repeat(np.cumsum(counts) - counts, counts))
    fraction = (row - v0[edge]) / (v1[edge] - v0[edge])
    u = u0[edge] + fraction * (u1[edge] - u0[edge])
    col = np.clip(np.ceil(u), col0, col1).astype(np.int64) - col0
    sign = np.where(v1[edge] > v0[edge], 1, -1).astype(np.int16)
    width = col1 - col0
    steps = np.zeros((row1 - row0, width + 1), dtype=np.int16)
    np.add.at(steps, (row - row0, col), sign)
    return np.cumsum(steps[:, :width], axis=1, dtype=np.int16), (row0, row1, col0, col1)


def solid_mask(points: np.ndarray, offsets: np.ndarray, grid: Grid) -> np.ndarray:
    """(height, width) bool: pixel centres inside the loops by the non-zero winding rule."""
    mask = np.zeros((grid.height, grid.width), dtype=bool)
    winding, (row0, row1, col0, col1) = winding_numbers(points, offsets, grid)
    if winding.size:
        mask[row0:row1, col0:col1] = winding > 0
    return mask


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

    Without point colours: the (h, w) bool solid mask (written as a 1-bit TIFF). With point colours
    ((p, 3) float): (h, w, 4) uint8 RGBA, alpha 255 solid, interior ``base_color``,
    contour pixels coloured from the nearest intersection point.
    """
    mask = solid_mask(points, offsets, grid)
    solid = int(np.count_nonzero(mask))
    if point_colors is None:
        return mask, solid
    image = np.zeros((grid.height, grid.width, 4), dtype=np.uint8)
    image[mask] = (*base_color, 255)
    paint_contour(image, mask, points, point_colors, grid)
    return image, solid
