"""The volume route's compiled kernel (numba source, compiled at install: :mod:`heoslice.jit`): one layer's
label fields resampled at the pixel centres into the layer's packed 1-bit solid mask and one mask per
material code (a span of pixels set at once where a voxel cell is one label's throughout).

The fields are given on the layer's plane at the voxel nodes (already interpolated along z), so a pixel's
value is their bilinear interpolation: exactly the trilinear interpolation of the voxel fields. A pixel
belongs to the label of highest score (its field, plus the label's boost where the field is positive);
the layer is solid where a label's field is positive, or where two labels' fields both come within a
``crack`` of it (the seam between two touching labels, whose fields need not meet exactly: a gap of
background between labels is a voxel or more wide and stays). Along a pixel row the fields
are linear within each voxel cell, so a cell whose two ends agree on the winner (inside at both ends) and
in which no field changes sign is filled at once; only the cells a boundary crosses are evaluated per pixel.
"""

from __future__ import annotations

import numpy as np

from heoslice.jit import JIT, kernel
from heoslice.layers.rasterising_kernels import _fill_span


@kernel(JIT)
def _label_codes(fields, boost, codes, boxes, crack, row_cell, row_frac, cell_start, col_frac, planes, counts):
    """Set each pixel's bits in ``planes`` ((K + 1, H, ceil(W / 8)) uint8, zeroed, most significant bit first):
    plane 0 the solid mask, plane m the pixels of material code m; ``counts`` ((K + 1,) int64) their set pixels.

    fields: (L, NY, NX) float32, each label's field at the layer's voxel nodes (voxels, positive inside);
    boost: (L,) float32; codes: (L,) uint8 (1..K); boxes: (L, 4) int64, the node ranges [y0, y1) and [x0, x1)
    where a label's field is given (elsewhere it is far outside); crack: voxels, the seam two labels' fields
    may leave between them and still be one solid; row_cell, row_frac: (H,) each pixel row's node row below it
    and its fraction towards the next (cell -1: off the grid); cell_start: (NX,) int64, the first pixel column
    of each node column's cell (the last entry: the end); col_frac: (W,) float32, each pixel column's fraction
    across its cell.

    A label at or below -crack at a cell's four corners is so everywhere in the cell (bilinear), so it can
    neither make a pixel solid nor win one: each cell's candidates are the other labels, listed once.
    """
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
    for row in range(row_cell.shape[0]):
        cy = row_cell[row]
        if cy < 0 or cy > rows_n - 2:
            continue
        fy = row_frac[row]
        for cx in range(columns_n - 1):
            first, stop = cell_start[cx], cell_start[cx + 1]
            cell = cy * (columns_n - 1) + cx
            if first >= stop or starts[cell] == starts[cell + 1]:
                continue
            best_a, best_b = -np.inf, -np.inf
            win_a, win_b = -1, -1
            mixed = False
            inside = False
            near = 0
            for position in range(starts[cell], starts[cell + 1]):
                label = candidates[position]
                va = fields[label, cy, cx] + fy * (fields[label, cy + 1, cx] - fields[label, cy, cx])
                vb = fields[label, cy, cx + 1] + fy * (fields[label, cy + 1, cx + 1] - fields[label, cy, cx + 1])
                sa = va + boost[label] if va > 0 else va
                sb = vb + boost[label] if vb > 0 else vb
                if sa > best_a:
                    best_a, win_a = sa, label
                if sb > best_b:
                    best_b, win_b = sb, label
                if (va > 0) != (vb > 0):
                    mixed = True
                if va > 0 or vb > 0:
                    inside = True
                if va > -crack or vb > -crack:
                    near += 1
            if not inside and near < 2:
                continue
            if not mixed and win_a == win_b and win_a >= 0:
                wa = fields[win_a, cy, cx] + fy * (fields[win_a, cy + 1, cx] - fields[win_a, cy, cx])
                wb = fields[win_a, cy, cx + 1] + fy * (fields[win_a, cy + 1, cx + 1] - fields[win_a, cy, cx + 1])
                if wa > 0 and wb > 0:
                    code = codes[win_a]
                    _fill_span(planes[0], row, first, stop)
                    _fill_span(planes[code], row, first, stop)
                    counts[0] += stop - first
                    counts[code] += stop - first
                    continue
            for column in range(first, stop):
                fx = col_frac[column]
                best, winner = -np.inf, -1
                top, second = -np.inf, -np.inf
                for position in range(starts[cell], starts[cell + 1]):
                    label = candidates[position]
                    va = fields[label, cy, cx] + fy * (fields[label, cy + 1, cx] - fields[label, cy, cx])
                    vb = fields[label, cy, cx + 1] + fy * (fields[label, cy + 1, cx + 1] - fields[label, cy, cx + 1])
                    value = va + fx * (vb - va)
                    score = value + boost[label] if value > 0 else value
                    if score > best:
                        best, winner = score, label
                    if value > top:
                        top, second = value, top
                    elif value > second:
                        second = value
                if winner >= 0 and (top > 0 or second > -crack):
                    code = codes[winner]
                    bit = np.uint8(0x80 >> (column & 7))
                    planes[0, row, column >> 3] |= bit
                    planes[code, row, column >> 3] |= bit
                    counts[0] += 1
                    counts[code] += 1
