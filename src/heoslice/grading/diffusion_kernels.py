"""Compiled loops of :mod:`heoslice.grading.diffusion`: a labelled layer's per-pixel mix, and the serpentine
vector error diffusion of a mix into bit-packed droplet masks."""

from __future__ import annotations

import numpy as np

from heoslice.grading.droplets_kernels import _moved_sums
from heoslice.jit import EXACT, helper, kernel


@kernel(EXACT, label_arg=0)
def _pixel_mixes(layer, mixing, base_channel, out):  # pragma: no cover - compiled
    """Each pixel's mix ((rows, cols, K) float32 into ``out``, summing to 1) over a labelled layer's box: a
    labelled pixel's family start mix at its lattice cell moved by its label's fraction towards the target
    (eq. 1, in :func:`heoslice.grading.droplets_kernels._moved_sums`' float32 arithmetic), a solid pixel
    without a label (or whose moved mix has no positive total) all ``base_channel``, an empty pixel all 0."""
    label, r0, c0, packed, rows = layer
    family_of_label, fraction, layout, mixes, target = mixing
    channels = out.shape[2]
    cols = label.shape[1]
    repeated = label.shape[0] == 1
    sums = np.empty(channels, dtype=np.float32)
    for r in range(rows):
        line = label[0 if repeated else r]
        row = r0 + r
        mixed_label, cell_from, cell_to = -1, 0, 0
        scale = np.float32(1.0)
        positive = True
        for c in range(cols):
            col = c0 + c
            if not (packed[row, col >> 3] >> (7 - (col & 7))) & 1:
                continue
            number = line[c]
            if number == 0:
                out[r, c, base_channel] = 1.0
                continue
            if number != mixed_label or not cell_from <= col < cell_to:
                family = family_of_label[number]
                cell = layout[family, 2]
                j = (col - layout[family, 1]) // cell
                start = layout[family, 4] + (((row - layout[family, 0]) // cell) * layout[family, 3] + j) * channels
                scale = _moved_sums(mixes[start:start + channels], fraction[number], target, sums)
                cell_from = layout[family, 1] + j * cell
                mixed_label, cell_to = number, cell_from + cell
                positive = True
                if channels > 1:
                    total = sums[channels - 2] + (mixes[start + channels - 1] + fraction[number]
                                                  * (target[channels - 1] - mixes[start + channels - 1]))
                    positive = total > np.float32(0.0)
            if not positive:
                out[r, c, base_channel] = 1.0
                continue
            below = np.float32(0.0)
            for m in range(channels - 1):
                out[r, c, m] = (sums[m] - below) / scale
                below = sums[m]
            out[r, c, channels - 1] = max(np.float32(1.0) - below / scale, np.float32(0.0))
    return out


@helper(EXACT)
def _held_signature(mix, r, c, channels):  # pragma: no cover - compiled
    """The materials pixel (r, c) mixes, as bits (bit m: it holds material m), when it holds two or more; 0 for
    a pixel of one material or none; -1 for a mix of more than 62 materials (no bit set for them)."""
    bits = np.int64(0)
    held = 0
    for m in range(channels):
        if mix[r, c, m] > np.float32(0.0):
            held += 1
            if m < 62:
                bits |= np.int64(1) << m
    if held < 2:
        return np.int64(0)
    return bits if channels <= 62 else np.int64(-1)


@kernel(EXACT)
def _diffuse(mix, carry, weights, shares, start, flip, planes, r0, c0):  # pragma: no cover - compiled
    """Serpentine vector error diffusion of ``mix`` ((rows, cols, K) float32, all 0 at empty pixels) into the
    bit-packed ``planes`` ((K, h, ceil(w / 8)) uint8, the box's pixel (0, 0) at (r0, c0); bits only set).

    Each solid pixel takes, among the materials its own mix holds (> 0), the one whose share plus the error
    arriving at it (from the pixels before it in the layer, and ``carry``: the layer before's, (rows, cols,
    K) float32) is largest. The difference between the corrected mix and the material taken goes to the
    pixels after it by ``weights`` ((3, 5) float32: this row and the two below, columns -2 .. 2 along the
    row's direction, summing to 1) times 1 - ``shares[0]``, and ``shares[0]`` of it to the same pixel of the
    next layer (written in place into ``carry``; 0 at empty pixels). A material's error goes only to the
    pixels after it that mix the material with others, its weights scaled up to make up for those that do not
    (so the error stays in its region and the region's total is kept); a pixel of one material takes it and
    passes no error on, so a region of one material stays pure. Where a material's mixed region starts from
    above (no error comes from the rows above), ``shares[1]`` times the choice of the threshold mask
    ``start`` ((n, n) float32 thresholds, n a power of two, anchored at the layer's pixel (0, 0)) less the mix
    is added to what arrives. Rows run left to right when (row + flip) is even, else right to left."""
    rows, cols, channels = mix.shape
    layer_share, top_share = np.float32(shares[0]), np.float32(shares[1])
    wrap = start.shape[0] - 1
    signature = np.empty((rows, cols), dtype=np.int64)
    for r in range(rows):
        for c in range(cols):
            signature[r, c] = _held_signature(mix, r, c, channels)
    # pixels whose 3 x 5 neighbourhood (this row and the two below, two columns either side) all mix as they do:
    # their error reaches every weight, whichever way their row runs
    level = np.zeros((rows, cols), dtype=np.bool_)  # the pixel and the two on either side mix alike
    for r in range(rows):
        for c in range(2, cols - 2):
            own = signature[r, c]
            level[r, c] = (own != 0 and own != -1 and signature[r, c - 2] == own and signature[r, c - 1] == own
                           and signature[r, c + 1] == own and signature[r, c + 2] == own)
    interior = np.zeros((rows, cols), dtype=np.bool_)
    for r in range(rows - 2):
        for c in range(cols):
            own = signature[r, c]
            interior[r, c] = (level[r, c] and level[r + 1, c] and level[r + 2, c] and signature[r + 1, c] == own
                              and signature[r + 2, c] == own)
    errors = np.zeros((3, channels, cols + 4), dtype=np.float32)
    taps = 0  # the nonzero weights: rows below, columns along the row's direction, weight
    tap_row = np.empty(15, dtype=np.int64)
    tap_col = np.empty(15, dtype=np.int64)
    tap_weight = np.empty(15, dtype=np.float32)
    for dr in range(3):
        for dc in range(5):
            if weights[dr, dc] != np.float32(0.0):
                tap_row[taps], tap_col[taps], tap_weight[taps] = dr, dc - 2, weights[dr, dc]
                taps += 1
    ahead_1, ahead_2 = weights[0, 3], weights[0, 4]
    kept = np.float32(1.0) - layer_share
    left = np.zeros((channels, cols + 4), dtype=np.float32)  # each pixel's error, for the rows below
    for r in range(rows):
        errors[0, :, :] = errors[1]
        errors[1, :, :] = errors[2]
        errors[2, :, :] = 0.0
        left[:, :] = 0.0
        forward = ((r + flip) & 1) == 0
        step = 1 if forward else -1
        row = r0 + r
        for k in range(cols):
            c = k if forward else cols - 1 - k
            own = signature[r, c]
            col = c0 + c
            if own == 0:  # empty, or one material: taken as it is, no error passed on
                pick = -1
                for m in range(channels):
                    carry[r, c, m] = np.float32(0.0)
                    if pick < 0 and mix[r, c, m] > np.float32(0.0):
                        pick = m
                if pick >= 0:
                    planes[pick, row, col >> 3] |= np.uint8(0x80 >> (col & 7))
                continue
            above = signature[r - 1, c] if r > 0 else np.int64(0)
            starts = own != above or own == -1
            chosen = channels - 1
            if starts:  # the threshold mask's choice where a region starts from above
                threshold = start[row & wrap, col & wrap]
                running = np.float32(0.0)
                for m in range(channels - 1):
                    running += mix[r, c, m]
                    if threshold < running:
                        chosen = m
                        break
            pick = 0
            best = -np.inf
            for m in range(channels):
                share_m = mix[r, c, m]
                if share_m > np.float32(0.0):
                    value = share_m + errors[0, m, c + 2] + carry[r, c, m]
                    if starts and (r == 0 or mix[r - 1, c, m] <= np.float32(0.0) or above == 0):
                        value += top_share * ((np.float32(1.0) if m == chosen else np.float32(0.0)) - share_m)
                    left[m, c + 2] = value
                    if value > best:
                        best, pick = value, m
            left[pick, c + 2] -= np.float32(1.0)
            # the pixels after it that mix as this one does take its error by their weights as they are
            same = interior[r, c]
            for m in range(channels):
                if mix[r, c, m] <= np.float32(0.0):
                    carry[r, c, m] = np.float32(0.0)
                    continue
                reach = np.float32(1.0)
                if not same:
                    reach = np.float32(0.0)
                    for t in range(taps):
                        rr, cc = r + tap_row[t], c + step * tap_col[t]
                        if rr < rows and 0 <= cc < cols and signature[rr, cc] != 0 and mix[rr, cc, m] > 0.0:
                            reach += tap_weight[t]
                error = left[m, c + 2]
                carry[r, c, m] = error * layer_share
                error = error * kept / reach if reach > np.float32(0.0) else np.float32(0.0)
                left[m, c + 2] = error
                errors[0, m, c + 2 + step] += error * ahead_1
                errors[0, m, c + 2 + 2 * step] += error * ahead_2
            planes[pick, row, col >> 3] |= np.uint8(0x80 >> (col & 7))
        # the rows below take each pixel's error by their weights, mirrored on a row run right to left
        for below in range(1, 3):
            for dc in range(5):
                w = weights[below, dc if forward else 4 - dc]
                if w == np.float32(0.0):
                    continue
                shift = dc - 2
                for m in range(channels):
                    target, source = errors[below, m], left[m]
                    for c in range(max(0, -shift), min(cols, cols - shift)):
                        target[c + 2 + shift] += source[c + 2] * w
    return planes
