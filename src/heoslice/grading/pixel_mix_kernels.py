"""Compiled kernels of :mod:`heoslice.grading.pixel_mix`: the droplet masks of a layer whose every solid pixel's
share of the target is a table's value at the pixel's r, in one pass over the packed solid rows: r from a
closed-form reference's squared distance (no per-pixel array of r, codes or labels written and read back), or
r's step per pixel as a surface reference's bounds gave it."""

from __future__ import annotations

import numpy as np

from heoslice.jit import EXACT, helper, kernel


@helper(EXACT)
def _dither_masks(level):  # pragma: no cover - compiled
    """masks (n, n / 8, 257) uint8: for each tile row, byte of the tile and count of levels c (0 .. 256), the byte
    whose bit 7 - t is set where level[row, 8 byte + t] < c (``level`` (n, n) int32, the dither's level per tile
    position, 0 .. 255): each position's bit set at its level + 1, then carried to every larger count, so a
    64-pixel tile costs a pass over its masks, not one per count and position."""
    size = level.shape[0]
    masks = np.zeros((size, size // 8, 257), dtype=np.uint8)
    for tile_row in range(size):
        for col in range(size):
            masks[tile_row, col >> 3, level[tile_row, col] + 1] |= np.uint8(128 >> (col & 7))
        for part in range(size // 8):
            for count in range(1, 257):
                masks[tile_row, part, count] |= masks[tile_row, part, count - 1]
    return masks


@helper(EXACT)
def _run_bits(row, begin, end, index, below, row_masks, planes, start, target, out):  # pragma: no cover - compiled
    """Bytes begin:end of a packed solid ``row``, whose pixels' table indices are index[0:8 (end - begin)], into row
    ``out`` of the start and target planes: each pixel jets the target where its tile position's level is below
    below[index] (``row_masks`` the tile row's :func:`_dither_masks`), else the start; bytes off the solid are not
    written."""
    parts = row_masks.shape[0] - 1
    for byte in range(begin, end):
        byte_masks = row_masks[byte & parts]
        at = (byte - begin) * 8
        bits = 0
        for t in range(8):
            bits |= byte_masks[below[index[at + t]]] & (128 >> t)
        solid = row[byte]
        planes[start, out, byte] = solid & ~bits
        planes[target, out, byte] |= solid & bits


@helper(EXACT)
def _next_run(row, k):  # pragma: no cover - compiled
    """(begin, end) of the first run of nonzero bytes of ``row`` at or after byte k ((len, len) when none)."""
    width = row.shape[0]
    while k < width:
        while k + 8 <= width and (row[k] | row[k + 1] | row[k + 2] | row[k + 3] | row[k + 4] | row[k + 5]
                                  | row[k + 6] | row[k + 7]) == 0:
            k += 8  # an empty stretch, eight bytes at a time
        if k >= width:
            break
        if row[k] == 0:
            k += 1
            continue
        begin = k
        while k < width and row[k] != 0:
            k += 1
        return begin, k
    return width, width


@kernel(EXACT)
def quadratic_planes(packed: np.ndarray, row0: int, c0: int, frame: tuple, square: tuple, r0: float, r1: float,
                     below: np.ndarray, level: np.ndarray, start: int, target: int,
                     planes: np.ndarray) -> None:  # pragma: no cover - compiled
    """The ordered dither of rows row0 .. row0 + len(packed) of a layer into ``planes`` ((K, h, bytes) uint8, MSB
    first, zero there on entry): each solid pixel (row0 + i, c) of ``packed`` ((rows, bytes) uint8; c0 a multiple of
    8 at or left of the first solid column) jets ``target`` where level[(row0 + i) % n, c % n] < below[k], else
    ``start``. ``level`` (n, n) int32, n a power of two from 8: the dither's level at each tile position;
    ``below`` (m,) uint16 (half the cache lines of int32): the levels under f at r = k / (m - 1); k = round(r (m -
    1)), r = (d - r0) / (r1 - r0) clipped to [0, 1], d = sqrt(max(Q, 0)), Q = A u^2 + B u v + C v^2 + D u + E v + F
    (``square``: (A, B, C, D, E, F)), u and v the pixel centre's offsets (mm) from the reference's point along x and
    y; frame: (u of column c0, u step per column, v of row i = 0, v step per row). Each run of nonzero bytes of a
    row takes its table indices in one branch-free loop (it vectorises), then each of its pixels the bit of a
    byte made once per tile row, byte of the tile and count of levels (0 .. 256, ``below`` <= 256): the byte's
    pixels whose level is below that count; bytes off the solid pixels are not written."""
    a, b, c, d, e, f = square
    steps = below.shape[0] - 1
    scale = 1.0 / (r1 - r0)
    width = packed.shape[1]
    size = level.shape[0]
    wrap = size - 1
    masks = _dither_masks(level)
    index = np.empty(8 * width, dtype=np.uint32)  # a run's table indices (unsigned: read without a sign test)
    for i in range(packed.shape[0]):
        v = frame[2] + i * frame[3]
        linear = b * v + d
        constant = (c * v + e) * v + f
        row = packed[i]
        row_masks = masks[(row0 + i) & wrap]
        begin, end = _next_run(row, c0 >> 3)
        while begin < width:
            offset = 8 * begin - c0
            for t in range(8 * (end - begin)):
                u = frame[0] + (offset + t) * frame[1]
                q = (a * u + linear) * u + constant
                index[t] = int(min(max((np.sqrt(max(q, 0.0)) - r0) * scale, 0.0), 1.0) * steps + 0.5)
            _run_bits(row, begin, end, index, below, row_masks, planes, start, target, row0 + i)
            begin, end = _next_run(row, end)


@kernel(EXACT)
def step_planes(packed: np.ndarray, row0: int, c0: int, steps: np.ndarray, below: np.ndarray, level: np.ndarray,
                start: int, target: int, planes: np.ndarray) -> None:  # pragma: no cover - compiled
    """:func:`quadratic_planes`' dither with each solid pixel's table index given: the pixel (row0 + i, c0 + j) of
    ``packed`` (rows, bytes; c0 a multiple of 8 at or left of the first solid column, as there) takes
    below[steps[i, j]] (``steps`` (rows, cols) uint16, r's step as a surface
    reference's bounds gave it, cols reaching the last solid column; anything off the solid). ``below`` has an
    entry for every uint16 (65536; ValueError else), so a step off the solid indexes it too, and every index is
    unsigned (read without a test for negative indices, nor a clip)."""
    if below.shape[0] != 65536:
        raise ValueError("step_planes: below has an entry for every uint16 step (65536)")
    width = packed.shape[1]
    wrap = level.shape[0] - 1
    cols = steps.shape[1]
    last = np.uint64(cols - 1)
    masks = _dither_masks(level)
    parts, counts = masks.shape[1] - 1, np.uint64(masks.shape[2])
    for i in range(packed.shape[0]):
        row = packed[i]
        row_masks = masks[(row0 + i) & wrap].ravel()  # one view a row: a view a byte costs two reference counts
        given = steps[i]
        begin, end = _next_run(row, c0 >> 3)
        while begin < width:
            for byte in range(begin, end):  # each pixel's step read where its bit is made (no array between)
                part = np.uint64(byte & parts) * counts
                first = 8 * byte - c0  # >= 0: c0 is a multiple of 8 at or left of the first solid column
                at = np.uint64(first)
                bits = 0
                if first + 8 <= cols:
                    for t in range(8):
                        bits |= row_masks[part + below[given[at + np.uint64(t)]]] & (128 >> t)
                else:  # the last byte may reach past the last solid column
                    for t in range(8):
                        bits |= row_masks[part + below[given[min(at + np.uint64(t), last)]]] & (128 >> t)
                solid = row[byte]
                planes[start, row0 + i, byte] = solid & ~bits
                planes[target, row0 + i, byte] |= solid & bits
            begin, end = _next_run(row, end)
