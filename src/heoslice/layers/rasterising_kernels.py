"""The rasteriser's compiled kernel: a layer's closed loops filled into a packed 1-bit mask, scanline by
scanline, in one pass over the edges (numba source, compiled at install: :mod:`heoslice.jit`).

Exact arithmetic (no fast-math): a pixel is solid exactly where the loops' winding number about its centre
is above 0, with the crossing rule of :func:`heoslice.layers.rasterising.packed_mask`.
"""

from __future__ import annotations

import numpy as np

from heoslice.jit import EXACT, helper, kernel

#: Rows with at most this many crossings are sorted by insertion (fewer steps than a general sort).
INSERTION_SORT_AT_MOST = 16


@helper(EXACT)
def _fill_span(packed, row, first, stop):
    """Set bits [first, stop) of packed row ``row`` (most significant bit first); 0 <= first < stop."""
    head, tail = first >> 3, stop >> 3
    if head == tail:
        packed[row, head] |= (0xFF >> (first & 7)) & ~(0xFF >> (stop & 7))
        return
    packed[row, head] |= 0xFF >> (first & 7)
    line = np.uint64(row)  # unsigned indices: none may wrap round from the end, so the loop is one fill
    for byte in range(np.uint64(head + 1), np.uint64(tail)):
        packed[line, byte] = 0xFF
    if stop & 7:
        packed[row, tail] |= (0xFF00 >> (stop & 7)) & 0xFF


@helper(EXACT)
def _sort_small(keys):
    """Sort a short int64 array in place by insertion."""
    for i in range(1, keys.shape[0]):
        key = keys[i]
        j = i - 1
        while j >= 0 and keys[j] > key:
            keys[j + 1] = keys[j]
            j -= 1
        keys[j + 1] = key


@kernel(EXACT)
def _packed_mask(points, offsets, width, height, x_left, y_top, px, py, packed):
    """Fill the loops' solid pixels into ``packed`` ((height, ceil(width / 8)) uint8, zeroed) and return
    their count.

    points: (n, 2) float, mm, loop after loop; offsets: (loops + 1,) int, each loop's first point and n.
    An edge crosses the centres of rows r with v_low < r <= v_high (v the row coordinate of its ends); the
    crossing's column is ceil of its column coordinate, clipped to [0, width]; it adds +1 to the winding of
    every pixel from that column on when the edge runs down the image, else -1.
    """
    count = points.shape[0]
    u = np.empty(count)
    v = np.empty(count)
    for i in range(count):
        u[i] = (points[i, 0] - x_left) / px - 0.5
        v[i] = (y_top - points[i, 1]) / py - 0.5
    following = np.empty(count, np.int64)
    for i in range(count):
        following[i] = i + 1
    for loop in range(offsets.shape[0] - 1):
        if offsets[loop + 1] > offsets[loop]:
            following[offsets[loop + 1] - 1] = offsets[loop]
    first = np.empty(count, np.int64)
    stop = np.empty(count, np.int64)
    per_row = np.zeros(height + 1, np.int64)
    for i in range(count):
        low, high = min(v[i], v[following[i]]), max(v[i], v[following[i]])
        first[i] = int(min(max(np.floor(low) + 1.0, 0.0), float(height)))
        stop[i] = int(min(max(np.floor(high) + 1.0, 0.0), float(height)))
        for row in range(first[i], stop[i]):
            per_row[row + 1] += 1
    for row in range(height):
        per_row[row + 1] += per_row[row]
    keys = np.empty(per_row[height], np.int64)
    filled = per_row[:height].copy()
    for i in range(count):
        j = following[i]
        du, dv = u[j] - u[i], v[j] - v[i]
        down = 1 if dv > 0 else 0
        for row in range(first[i], stop[i]):
            column = np.ceil(u[i] + (row - v[i]) / dv * du)
            keys[filled[row]] = int(min(max(column, 0.0), float(width))) * 2 + down
            filled[row] += 1
    solid = 0
    for row in range(height):
        crossings = keys[per_row[row]:per_row[row + 1]]
        if crossings.shape[0] <= INSERTION_SORT_AT_MOST:
            _sort_small(crossings)
        else:
            crossings.sort()
        winding, start, k = 0, 0, 0
        while k < crossings.shape[0]:
            column = crossings[k] >> 1
            was_inside = winding > 0
            while k < crossings.shape[0] and crossings[k] >> 1 == column:
                winding += 2 * (crossings[k] & 1) - 1
                k += 1
            inside = winding > 0
            if inside and not was_inside:
                start = column
            elif was_inside and not inside:
                _fill_span(packed, row, start, column)
                solid += column - start
    return solid
