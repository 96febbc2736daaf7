"""Compiled kernel of :mod:`heoslice.stack.report`: one layer of a stack against a design whose every solid pixel
has its own designed share (a field interior's f(r)), in one pass over the layer's packed rows: the bands of r and
the worst window, without a per-pixel array of shares or bands made for them (:func:`design_tally`).
"""

from __future__ import annotations

import numpy as np

from heoslice.jit import EXACT, helper, kernel


@kernel(EXACT)
def design_tally(solid: np.ndarray, masks: np.ndarray, box: np.ndarray, codes: np.ndarray, shares: np.ndarray,
                 bands: np.ndarray, start: int, target: int, width: int, window: np.ndarray, row_starts: np.ndarray,
                 col_starts: np.ndarray, least: int, counts: np.ndarray, delivered: np.ndarray, planned: np.ndarray,
                 worst: np.ndarray) -> None:  # pragma: no cover - compiled
    """Tally a layer of ``width`` pixels against a per-pixel design.

    solid (h, bytes) and masks (K, h, bytes) uint8: the layer's solid pixels and droplet masks, rows packed MSB
    first; box (4,) int64: first row, end row, first column, end column of ``codes`` ((rows, columns) uint16), each
    solid pixel's code inside it (r's step), read through the tables ``shares`` (n,) float32 (the target's designed
    share; the start's is 1 - share in float32, the other masks' 0) and ``bands`` (n,) int64 (its band of r),
    a code past n - 1 read as n - 1; a solid pixel outside the box has no design (no band, shares 0).

    Out (zeroed by the caller): per band, counts (B,) solid pixels, delivered (K, B) set mask pixels among them and
    planned (K, B) the designed shares summed (float64). The windows: ``window`` (2,) rows and columns, their first
    rows ``row_starts`` and columns ``col_starts`` (increasing, each window cut at the layer's edge); a window of at
    least ``least`` solid pixels is compared, each mask's share of its solid against the designed; worst (6,)
    float64: the mask, first row, first column, solid pixels, designed and delivered share of the largest |delivered
    - designed| (the first in mask order, then in reading order of the windows; mask -1 when no window is compared).
    One pass over the rows keeps the column sums of the rows so far; a window's column sums are those at its end
    less those taken at its first row (kept while it is open), and its sum over its columns a difference of their
    prefix sums. A row's pixels add into the band table a run of one band at a time, each mask's pixels of a run
    counted a byte at a time (no branch on a dithered bit).
    """
    height, count, row_bytes = solid.shape[0], masks.shape[0], solid.shape[1]
    row0, row1, col0, col1 = box[0], box[1], box[2], box[3]
    last = shares.shape[0] - 1
    one = np.float32(1.0)
    for k in range(6):
        worst[k] = 0.0
    worst[0] = -1.0
    # the bytes holding solid pixels: every column sum outside them stays 0
    used = np.zeros(row_bytes, np.uint8)
    for i in range(height):
        for byte in range(row_bytes):
            used[byte] |= solid[i, byte]
    low, high = row_bytes, 0
    for byte in range(row_bytes):
        if used[byte]:
            low, high = min(low, byte), byte + 1
    if high <= low:
        return
    first_col, end_col = 8 * low, min(8 * high, width)
    span = end_col - first_col
    # the column sums over rows 0 .. i - 1 (solid, each mask among the solid, start's and target's designed share)
    sums = np.zeros((count + 3, span))
    windows = row_starts.shape[0]
    ends = np.empty(windows, np.int64)
    for w in range(windows):
        ends[w] = min(row_starts[w] + window[0], height)
    ring = 1  # windows open at once (a contiguous run of them: starts and ends both increase)
    for w in range(windows):
        opened = 0
        for v in range(w + 1):
            if ends[v] > row_starts[w]:
                opened += 1
        ring = max(ring, opened)
    taken = np.zeros((ring, count + 3, span))  # the sums at each open window's first row
    prefix = np.zeros((count + 3, span + 1))
    best = np.full(count, -1.0)
    found = np.zeros((count, 5))
    run_masks = np.zeros(count, np.int64)  # a run of pixels of one band: each mask's set pixels among them
    ones = np.zeros(256, np.int64)  # set bits per byte value
    for value in range(256):
        ones[value] = ones[value >> 1] + (value & 1)
    opening, closing = 0, 0
    for i in range(height + 1):
        while closing < windows and ends[closing] == i:
            slot = closing % ring
            for q in range(count + 3):
                for j in range(span):
                    prefix[q, j + 1] = prefix[q, j] + (sums[q, j] - taken[slot, q, j])
            for first in col_starts:
                stop = min(first + window[1], width)
                a, b = min(max(first - first_col, 0), span), min(max(stop - first_col, 0), span)
                pixels = prefix[0, b] - prefix[0, a]
                if pixels < least or pixels <= 0:
                    continue
                for k in range(count):
                    got = (prefix[3 + k, b] - prefix[3 + k, a]) / pixels
                    wanted = 0.0
                    if k == start:
                        wanted = (prefix[1, b] - prefix[1, a]) / pixels
                    elif k == target:
                        wanted = (prefix[2, b] - prefix[2, a]) / pixels
                    off = abs(got - wanted)
                    if off > best[k]:
                        best[k] = off
                        found[k, 0], found[k, 1], found[k, 2] = row_starts[closing], first, pixels
                        found[k, 3], found[k, 4] = wanted, got
            closing += 1
        if i == height:
            break
        while opening < windows and row_starts[opening] == i:
            taken[opening % ring] = sums
            opening += 1
        coded_row = row0 <= i < row1
        band = -1
        run_count, run_rest, run_share = 0, 0.0, 0.0
        run_masks[:] = 0
        solid_row = sums[0]
        for byte in range(low, high):
            bits = solid[i, byte]
            if bits == 0:
                continue
            base = 8 * byte - first_col
            in_image = min(8, end_col - 8 * byte)  # the last byte may reach past the image
            _add_bits(solid_row, base, bits, in_image)
            for k in range(count):
                held = masks[k, i, byte] & bits
                if held != 0:
                    _add_bits(sums[3 + k], base, held, in_image)
            if not coded_row or 8 * byte + 8 <= col0 or 8 * byte >= col1:
                continue
            code_row = codes[i - row0]
            inside = bits
            if 8 * byte < col0:
                inside &= 0xFF >> (col0 - 8 * byte)
            if 8 * byte + 8 > col1:
                inside &= (0xFF << (8 * byte + 8 - col1)) & 0xFF
            segment = 0  # the first bit of this byte in the run at hand
            for t in range(8):
                if (inside >> (7 - t)) & 1 == 0:
                    continue
                code = min(np.int64(code_row[8 * byte + t - col0]), last)
                share = shares[code]
                rest = one - share
                sums[1, base + t] += rest
                sums[2, base + t] += share
                if bands[code] != band:  # the run of one band ends: its sums into the table
                    if band >= 0:
                        part = inside & ((0xFF >> segment) & ~(0xFF >> t))
                        for k in range(count):
                            run_masks[k] += ones[masks[k, i, byte] & part]
                        _add_run(run_count, run_rest, run_share, run_masks, band, start, target, counts, planned,
                                 delivered)
                    band = bands[code]
                    run_count, run_rest, run_share = 0, 0.0, 0.0
                    run_masks[:] = 0
                    segment = t
                run_count += 1
                run_rest += rest
                run_share += share
            if band >= 0:
                part = inside & (0xFF >> segment)
                for k in range(count):
                    run_masks[k] += ones[masks[k, i, byte] & part]
        if band >= 0:
            _add_run(run_count, run_rest, run_share, run_masks, band, start, target, counts, planned, delivered)
    chosen = -1.0
    for k in range(count):
        if best[k] > chosen:
            chosen = best[k]
            worst[0] = k
            for q in range(5):
                worst[q + 1] = found[k, q]


@helper(EXACT)
def _add_bits(row, base, bits, pixels):  # pragma: no cover - compiled
    """Bit 7 - t of ``bits`` (MSB first) added into row[base + t] for t < ``pixels`` (8 but in a last byte that
    reaches past the image)."""
    if pixels == 8:
        for t in range(8):  # a constant count: unrolled
            row[base + t] += (bits >> (7 - t)) & 1
    else:
        for t in range(pixels):
            row[base + t] += (bits >> (7 - t)) & 1


@helper(EXACT)
def _add_run(run_count, run_rest, run_share, run_masks, band, start, target, counts, planned,
             delivered):  # pragma: no cover - compiled
    """A run of pixels of one band (its pixels, start's and target's designed shares summed, each mask's set
    pixels) added into the band table."""
    counts[band] += run_count
    planned[start, band] += run_rest
    planned[target, band] += run_share
    for k in range(delivered.shape[0]):
        delivered[k, band] += run_masks[k]
