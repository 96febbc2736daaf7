"""Compiled loops of :mod:`heoslice.grading.diffusion`: a labelled layer's per-pixel mix, and the serpentine
vector error diffusion of a mix into bit-packed droplet masks."""

from __future__ import annotations

import numpy as np

from heoslice.grading.droplets_kernels import _moved_sums
from heoslice.jit import EXACT, kernel


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
                mixed_label, cell_from, cell_to = number, layout[family, 1] + j * cell, layout[family, 1] + (j + 1) * cell
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


@kernel(EXACT)
def _diffuse(mix, carry, weights, layer_share, flip, planes, r0, c0):  # pragma: no cover - compiled
    """Serpentine vector error diffusion of ``mix`` ((rows, cols, K) float32, all 0 at empty pixels) into the
    bit-packed ``planes`` ((K, h, ceil(w / 8)) uint8, the box's pixel (0, 0) at (r0, c0); bits only set).

    Each solid pixel takes, among the materials its own mix holds (> 0), the one whose share plus the error
    arriving at it (from the pixels before it in the layer, and ``carry``: the layer before's, (rows, cols,
    K) float32) is largest. The difference between the corrected mix and the material taken goes to the
    pixels after it by ``weights`` ((3, 5) float32: this row and the two below, columns -2 .. 2 along the
    row's direction, summing to 1) times 1 - ``layer_share``, and ``layer_share`` of it to the same pixel of
    the next layer (written in place into ``carry``). A pixel of one material takes it and passes no error
    on, and the errors of the materials a pixel does not hold stop there, so a region of one material stays
    pure. Rows run left to right when (row + flip) is even, else right to left."""
    rows, cols, channels = mix.shape
    errors = np.zeros((3, cols + 4, channels), dtype=np.float32)
    share = np.float32(layer_share)
    taps = 0  # the nonzero weights: row below, column offset, weight times 1 - share
    tap_row = np.empty(15, dtype=np.int64)
    tap_col = np.empty(15, dtype=np.int64)
    tap_weight = np.empty(15, dtype=np.float32)
    for dr in range(3):
        for dc in range(5):
            if weights[dr, dc] != np.float32(0.0):
                tap_row[taps], tap_col[taps] = dr, dc - 2
                tap_weight[taps] = weights[dr, dc] * (np.float32(1.0) - share)
                taps += 1
    error = np.empty(channels, dtype=np.float32)
    for r in range(rows):
        errors[0, :, :] = errors[1]
        errors[1, :, :] = errors[2]
        errors[2, :, :] = 0.0
        forward = ((r + flip) & 1) == 0
        step = 1 if forward else -1
        row = r0 + r
        for k in range(cols):
            c = k if forward else cols - 1 - k
            shares = mix[r, c]
            held, pick = 0, 0
            best = -np.inf
            for m in range(channels):
                if shares[m] > np.float32(0.0):
                    held += 1
                    value = shares[m] + errors[0, c + 2, m] + carry[r, c, m]
                    error[m] = value
                    if value > best:
                        best, pick = value, m
                else:
                    error[m] = np.float32(0.0)
            if held == 0:
                continue
            if held > 1:
                error[pick] -= np.float32(1.0)
                for t in range(taps):
                    line = errors[tap_row[t], c + 2 + step * tap_col[t]]
                    w = tap_weight[t]
                    for m in range(channels):
                        line[m] += error[m] * w
                for m in range(channels):
                    carry[r, c, m] = error[m] * share
            else:
                for m in range(channels):
                    carry[r, c, m] = np.float32(0.0)
            col = c0 + c
            planes[pick, row, col >> 3] |= np.uint8(0x80 >> (col & 7))
    return planes
