"""Rasterising: turn a layer's contour loops into a solid mask and a layer image.

A pixel is solid when its centre lies inside the layer's region: the loops wind
more than 0 times around it, so a cavity (clockwise loop) stays empty and a nested
shell (a second counter-clockwise loop) stays solid. The mask is built scanline-style without a
Python loop: loop edges are crossed with the pixel-row centres, the winding number
is accumulated over each row's sorted crossings, and the solid spans are filled
straight into a packed 1-bit image (the TIFF layout) by a running XOR over bytes.
Work is confined to the rows and byte columns the layer covers.
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
                f"canvas_mm: {size[0]:g} x {size[1]:g} mm is smaller than the part "
                f"({high[0] - low[0]:.3f} x {high[1] - low[1]:.3f} mm)"
            )
    width = int(np.ceil(size[0] / px - 1e-9))
    height = int(np.ceil(size[1] / py - 1e-9))
    return Grid(width=width, height=height, x_left=float(centre[0] - width * px / 2.0),
                y_top=float(centre[1] + height * py / 2.0), px=px, py=py)


def _loop_edges(points: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end points ((e, 2) each) of every edge of every closed loop."""
    following = np.arange(1, len(points) + 1)
    following[offsets[1:] - 1] = offsets[:-1]
    return points, np.take(points, following, axis=0)


def row_crossings(points: np.ndarray, offsets: np.ndarray, grid: Grid):
    """Where loop edges cross pixel-row centres.

    Returns (row (k,) int, column (k,) int, sign (k,) int8): every pixel of that row
    whose column is >= ``column`` gets ``sign`` added to its winding number (+1 for
    an edge going down the image, i.e. the left side of a counter-clockwise loop).
    A row centre exactly at an edge end counts once (rows r with v_low < r <= v_high,
    v the row coordinate); a pixel centre exactly on an edge counts as right of it.
    """
    start, end = _loop_edges(points, offsets)
    u0 = (start[:, 0] - grid.x_left) / grid.px - 0.5
    u1 = (end[:, 0] - grid.x_left) / grid.px - 0.5
    v0 = (grid.y_top - start[:, 1]) / grid.py - 0.5
    v1 = (grid.y_top - end[:, 1]) / grid.py - 0.5
    first = np.clip(np.floor(np.minimum(v0, v1)) + 1, 0, grid.height).astype(np.int64)
    last = np.clip(np.floor(np.maximum(v0, v1)) + 1, 0, grid.height).astype(np.int64)
    counts = last - first
    edge = np.repeat(np.arange(len(u0)), counts)
    row = np.repeat(first, counts) + (np.arange(len(edge)) - np.repeat(np.cumsum(counts) - counts, counts))
    dv = v1[edge] - v0[edge]
    u = u0[edge] + (row - v0[edge]) / dv * (u1[edge] - u0[edge])
    column = np.clip(np.ceil(u), 0, grid.width).astype(np.int64)
    return row, column, np.where(dv > 0, 1, -1).astype(np.int8)


def span_boundaries(row: np.ndarray, column: np.ndarray, sign: np.ndarray, width: int):
    """Columns where the fill (winding number > 0) switches between empty and solid, per row.

    Crossings are summed per (row, column), accumulated along each row (every row's
    crossings sum to zero for closed loops, so one running sum serves all rows), and
    a boundary is kept where "winding > 0" changes. Returns (row (b,), column (b,)),
    an even number per row: solid spans are [column[2i], column[2i+1]).
    """
    key = row * (width + 1) + column
    order = np.argsort(key, kind="stable")
    key = key[order]
    starts = np.concatenate([[0], np.nonzero(np.diff(key))[0] + 1]) if len(key) else np.zeros(0, np.int64)
    winding = np.cumsum(np.add.reduceat(sign[order].astype(np.int64), starts)) if len(key) else np.zeros(0)
    inside = winding > 0
    changed = inside != np.concatenate([[False], inside[:-1]])
    kept = key[starts][changed]
    return kept // (width + 1), kept % (width + 1)


def prefix_xor_bytes(steps: np.ndarray) -> np.ndarray:
    """Running XOR along each row of a (rows, bytes) uint8 array, 64 bits at a time.

    Bytes are viewed as little-endian 64-bit words: a word's bytes are prefix-XORed
    with three shifts, then each word is XORed with the running XOR of the words
    before it, so the sequential part works on 1/8 of the bytes.
    """
    rows, count = steps.shape
    words = -(-count // 8)
    padded = np.zeros((rows, words * 8), dtype=np.uint8)
    padded[:, :count] = steps
    word = padded.view("<u8")
    word ^= word << np.uint64(8)
    word ^= word << np.uint64(16)
    word ^= word << np.uint64(32)
    carry = (word >> np.uint64(56)) * np.uint64(0x0101010101010101)
    carry = np.bitwise_xor.accumulate(carry, axis=1)
    word[:, 1:] ^= carry[:, :-1]
    return padded[:, :count]


def packed_mask(points: np.ndarray, offsets: np.ndarray, grid: Grid) -> np.ndarray:
    """The solid mask as packed bits: (height, ceil(width / 8)) uint8, most significant bit first.

    This is the layout of a 1-bit TIFF row (and of ``np.packbits(mask, axis=1)``).
    Each span [a, b) is written as two toggles of "all bits from here on"; a running
    XOR along the row then fills the spans, touching bytes instead of pixels and only
    the rows and byte columns the loops cover.
    """
    row_bytes = -(-grid.width // 8)
    packed = np.zeros((grid.height, row_bytes), dtype=np.uint8)
    if len(points) == 0:
        return packed
    row, column = span_boundaries(*row_crossings(points, offsets, grid), grid.width)
    if len(row) == 0:
        return packed
    row0, row1 = int(row.min()), int(row.max()) + 1
    byte = column >> 3
    byte0, byte1 = int(byte.min()), int(byte.max()) + 2
    partial = (0xFF >> (column & 7)).astype(np.uint8)
    steps = np.zeros((row1 - row0, byte1 - byte0), dtype=np.uint8)
    np.bitwise_xor.at(steps, (row - row0, byte - byte0), partial)
    np.bitwise_xor.at(steps, (row - row0, byte - byte0 + 1), partial ^ np.uint8(0xFF))
    filled = prefix_xor_bytes(steps)
    stop = min(byte1, row_bytes)
    packed[row0:row1, byte0:stop] = filled[:, : stop - byte0]
    return packed


def count_solid(packed: np.ndarray) -> int:
    """Number of set bits (solid pixels) of a packed mask (any shape, uint8), counted 64 bits at a
    time (faster than byte by byte: benchmarks/README.md)."""
    flat = np.ascontiguousarray(packed).reshape(-1)
    whole = flat.size // 8 * 8
    return (int(np.bitwise_count(flat[:whole].view(np.uint64)).sum(dtype=np.int64))
            + int(np.bitwise_count(flat[whole:]).sum(dtype=np.int64)))


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
    packed = packed_mask(points, offsets, grid)
    solid = count_solid(packed)
    if point_colors is None:
        return packed, solid
    mask = np.unpackbits(packed, axis=1, count=grid.width).astype(bool)
    image = np.zeros((grid.height, grid.width, 4), dtype=np.uint8)
    image[mask] = (*base_color, 255)
    paint_contour(image, mask, points, point_colors, grid)
    return image, solid
