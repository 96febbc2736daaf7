"""The volume route's compiled kernel (numba source, compiled at install: :mod:`heoslice.jit`): one layer's
label fields resampled at the pixel centres into the layer's packed 1-bit solid mask and one mask per
material code, span by span.

The fields are given on the layer's plane at the voxel nodes (already interpolated along z), so a pixel's
value is their bilinear interpolation: exactly the trilinear interpolation of the voxel fields. A pixel
belongs to the label of highest score (its field, plus the label's boost where the field is positive);
the layer is solid where a label's field is positive, or where two labels' fields both come within a
``crack`` of it (the seam between two touching labels, whose fields need not meet exactly: a gap of
background between labels is a voxel or more wide and stays). Along a pixel row every field is linear
within a voxel cell, so the rule's answer changes only where a field crosses 0 or -crack or two fields
cross each other: the kernel finds those points in each cell, decides the rule once per piece between
them and sets the piece's pixels as one span.
"""

from __future__ import annotations

import numpy as np

from heoslice.jit import JIT, helper, kernel
from heoslice.layers.rasterising_kernels import _fill_span


@helper(JIT)
def _cell_candidates(fields, boxes, crack):
    """(starts, candidates): the labels that may reach -crack in each voxel cell of the layer's node grid,
    cell c's in candidates[starts[c]:starts[c + 1]] (int64). A label at or below -crack at a cell's four
    corners is so everywhere in it (bilinear): it can neither make a pixel solid nor win one."""
    count, rows_n, columns_n = fields.shape
    cells = (rows_n - 1) * (columns_n - 1)
    starts = np.zeros(cells + 1, dtype=np.int64)
    for label in range(count):
        for cy in range(max(boxes[label, 0], 0), min(boxes[label, 1], rows_n) - 1):
            for cx in range(max(boxes[label, 2], 0), min(boxes[label, 3], columns_n) - 1):
                if fields[label, cy, cx] > -crack or fields[label, cy, cx + 1] > -crack \
                        or fields[label, cy + 1, cx] > -crack or fields[label, cy + 1, cx + 1] > -crack:
                    starts[cy * (columns_n - 1) + cx + 1] += 1
    for cell in range(cells):
        starts[cell + 1] += starts[cell]
    candidates = np.zeros(starts[cells], dtype=np.int64)
    filled = starts[:-1].copy()
    for label in range(count):
        for cy in range(max(boxes[label, 0], 0), min(boxes[label, 1], rows_n) - 1):
            for cx in range(max(boxes[label, 2], 0), min(boxes[label, 3], columns_n) - 1):
                if fields[label, cy, cx] > -crack or fields[label, cy, cx + 1] > -crack \
                        or fields[label, cy + 1, cx] > -crack or fields[label, cy + 1, cx + 1] > -crack:
                    cell = cy * (columns_n - 1) + cx
                    candidates[filled[cell]] = label
                    filled[cell] += 1
    return starts, candidates


@helper(JIT)
def _piece_winner(ends, labels, count, boost, crack, t):
    """The label that takes the point at fraction ``t`` of a cell's pixel row (its index into ``labels``), or
    -1 where the point is not solid: ``ends`` ((n, 2) float64) are the ``count`` candidates' values at the
    row's two ends, ``labels`` their label numbers."""
    best, winner = -np.inf, -1
    top, second = -np.inf, -np.inf
    for j in range(count):
        value = ends[j, 0] + t * (ends[j, 1] - ends[j, 0])
        score = value + boost[labels[j]] if value > 0 else value
        if score > best:
            best, winner = score, j
        if value > top:
            top, second = value, top
        elif value > second:
            second = value
    if winner >= 0 and (top > 0 or second > -crack):
        return winner
    return -1


@helper(JIT)
def _set_run(planes, counts, row, first, stop, code):
    """Set pixels [first, stop) of ``row`` in the solid plane and in material code ``code``'s (code 0: the
    solid plane only; -1: none)."""
    if code >= 0 and stop > first:
        _fill_span(planes[0], row, first, stop)
        counts[0] += stop - first
        if code > 0:
            _fill_span(planes[code], row, first, stop)
            counts[code] += stop - first


@helper(JIT)
def _first_at_or_above(increasing, first, stop, value):
    """The first index in [first, stop) where ``increasing`` reaches ``value`` (``stop`` if none): a binary search."""
    while first < stop:
        middle = (first + stop) // 2
        if increasing[middle] < value:
            first = middle + 1
        else:
            stop = middle
    return first


@helper(JIT)
def _sorted_breaks(ends, count, crack, breaks):
    """Fill ``breaks`` with the fractions along a cell's pixel row where the label rule may change (a field
    crosses 0 or -crack, two fields cross), sorted; returns how many."""
    found = 0
    for j in range(count):
        a, b = ends[j, 0], ends[j, 1]
        if (a > 0) != (b > 0):
            breaks[found] = a / (a - b)
            found += 1
        if (a > -crack) != (b > -crack):
            breaks[found] = (a + crack) / (a - b)
            found += 1
        for i in range(j):
            da, db = ends[i, 0] - a, ends[i, 1] - b
            if (da > 0) != (db > 0):
                breaks[found] = da / (da - db)
                found += 1
    for i in range(1, found):
        key = breaks[i]
        k = i - 1
        while k >= 0 and breaks[k] > key:
            breaks[k + 1] = breaks[k]
            k -= 1
        breaks[k + 1] = key
    return found


@kernel(JIT)
def _label_codes(fields, boost, codes, boxes, crack, row_cell, row_frac, cell_start, col_frac, planes, counts):
    """Set each pixel's bits in ``planes`` ((K + 1, H, ceil(W / 8)) uint8, zeroed, most significant bit first):
    plane 0 the solid mask, plane m the pixels of material code m; ``counts`` ((K + 1,) int64) their set pixels.

    fields: (L, NY, NX) float32, each label's field at the layer's voxel nodes (voxels, positive inside);
    boost: (L,) float32; codes: (L,) uint8 (1..K; 0: in the solid mask only, a one-material stack); boxes: (L, 4) int64, the node ranges [y0, y1) and [x0, x1)
    where a label's field is given (elsewhere it is far outside); crack: voxels, the seam two labels' fields
    may leave between them and still be one solid; row_cell, row_frac: (H,) each pixel row's node row below it
    and its fraction towards the next (cell -1: off the grid); cell_start: (NX,) int64, the first pixel column
    of each node column's cell (the last entry: the end); col_frac: (W,) float32, each pixel column's fraction
    across its cell, increasing within a cell.
    """
    count, rows_n, columns_n = fields.shape
    starts, candidates = _cell_candidates(fields, boxes, crack)
    most = 1
    for cell in range(starts.shape[0] - 1):
        most = max(most, starts[cell + 1] - starts[cell])
    ends = np.zeros((most, 2), dtype=np.float64)
    labels = np.zeros(most, dtype=np.int64)
    breaks = np.zeros(2 * most + most * (most - 1) // 2 + 1, dtype=np.float64)
    for row in range(row_cell.shape[0]):
        cy = row_cell[row]
        if cy < 0 or cy > rows_n - 2:
            continue
        fy = row_frac[row]
        run_code, run_start = -1, 0
        for cx in range(columns_n - 1):
            first, stop = cell_start[cx], cell_start[cx + 1]
            cell = cy * (columns_n - 1) + cx
            if first >= stop:
                continue
            inside = False
            near = 0
            for position in range(starts[cell], starts[cell + 1]):
                label = candidates[position]
                a = fields[label, cy, cx] + fy * (fields[label, cy + 1, cx] - fields[label, cy, cx])
                b = fields[label, cy, cx + 1] + fy * (fields[label, cy + 1, cx + 1] - fields[label, cy, cx + 1])
                if a > -crack or b > -crack:
                    labels[near] = label
                    ends[near, 0], ends[near, 1] = a, b
                    near += 1
                    if a > 0 or b > 0:
                        inside = True
            found = _sorted_breaks(ends, near, crack, breaks) if inside or near >= 2 else 0
            column, low = first, 0.0
            for piece in range(found + 1):
                high = breaks[piece] if piece < found else 1.0
                end = stop if high >= 1.0 else _first_at_or_above(col_frac, column, stop, high)
                if end > column:
                    code = -1
                    if inside or near >= 2:
                        winner = _piece_winner(ends, labels, near, boost, crack,
                                               0.5 * (max(low, 0.0) + min(high, 1.0)))
                        if winner >= 0:
                            code = np.int64(codes[labels[winner]])
                    if code != run_code:
                        _set_run(planes, counts, row, run_start, column, run_code)
                        run_code, run_start = code, column
                    column = end
                low = high
        _set_run(planes, counts, row, run_start, cell_start[columns_n - 1], run_code)
