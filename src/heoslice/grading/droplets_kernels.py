"""Compiled halftoning of a labelled layer into bit-packed droplet masks (:mod:`heoslice.grading.droplets`), and
the table of the choices a family's cells agree on."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from heoslice.jit import EXACT, f32, helper, i64, kernel


class LabelledLayer(NamedTuple):
    """A layer's labels ((rows, cols) uint8/16/32, 0 empty; any strides, one value broadcast over the box too) from
    pixel (row0, col0), and its packed solid mask ((h, ceil(w/8)) uint8, rows MSB first, padding bits
    clear)."""

    label: np.ndarray
    row0: int
    col0: int
    packed: np.ndarray


class LayerMixes(NamedTuple):
    """What each label's pixels mix: the family of each label ((labels,) int), its fraction of the target
    ((labels,) float), per family (box row, box column, cell pixels, cells per row, first cell in
    ``mixes``) ((families, 5) int), every family's per-cell start mixes flattened ((cells * K,) float),
    and the target's mix ((K,) float)."""

    family_of_label: np.ndarray
    fraction: np.ndarray
    layout: np.ndarray
    mixes: np.ndarray
    target: np.ndarray


class Dither(NamedTuple):
    """The layer's ordered-dither ``tile`` ((n, n) thresholds in (0, 1), n a power of two), the ``table``
    of channels per label and dither level ((labels, n * n) int8, -1: mix per pixel) and the
    ``base_channel`` of solid pixels without a label."""

    tile: np.ndarray
    table: np.ndarray
    base_channel: int


@helper(EXACT)
def _moved_sums(start, f, target, sums):  # pragma: no cover - compiled
    """The running sums of a start mix ((K,) float32) moved by the fraction f towards ``target`` (eq. 1),
    over all channels but the last, into ``sums``; returns the scale of the thresholds (the moved mix's
    total, or 1 where it is not positive). A pixel jets the first channel whose sum exceeds its threshold
    times the scale: the halftone's float32 arithmetic, in the one order both kernels use."""
    total = np.float32(0.0)
    running = np.float32(0.0)
    for m in range(len(start)):
        share = start[m] + f * (target[m] - start[m])
        total += share
        if m < len(start) - 1:
            running += share
            sums[m] = running
    return total if total > np.float32(0.0) else np.float32(1.0)


@helper(EXACT)
def _chunk_word(words, line, k, spread):  # pragma: no cover - compiled
    """The pattern word of chunk k (16 pixels of ``line``): each pixel's label word (``words`` by label)
    masked to its own column in every 16-bit field (``spread``: a 1 in the low bit of each field used)."""
    value = np.int64(0)
    for j in range(16):
        value |= words[line[16 * k + j]] & (spread << (15 - j))
    return value


@helper(EXACT)
def _chunk_solid(solid, k):  # pragma: no cover - compiled
    """(high byte, low byte, 16-bit mask) of chunk k's solid pixels, from the packed solid row ``solid``."""
    high = np.int64(solid[2 * k])
    low = np.int64(solid[2 * k + 1])
    return high, low, (high << 8) | low


@helper(EXACT, inline=False)
def _droplet_run(line, solid, pattern, first, planes, count, channels, uniform):  # pragma: no cover - compiled
    """The common case of :func:`_droplet_bits`: ``count`` chunks of 16 pixels of a row, from chunk
    ``first``, all inside the labels, K <= 4 channels (one pattern word: ``pattern`` (blocks,
    labels) int64 at the row's tile phase); ``line`` (labels), ``solid`` and ``planes`` ((K,
    bytes)) start at chunk ``first``; ``uniform`` the one label of every pixel, or -1 (a chunk's
    word is then its label's, whole, not gathered pixel by pixel). Returns how many chunks it wrote:
    it stops before the first one with a solid pixel whose label has no table entry (left to the
    per-pixel mix). A small kernel of its own, so the 16-pixel loop keeps its registers; K = 2
    writes the second plane as the solid byte less the first."""
    wrap = pattern.shape[0] - 1
    if channels == 2:
        for k in range(count):
            high, low, mask = _chunk_solid(solid, k)
            if mask == 0:
                continue
            words = pattern[np.uint64((first + k) & wrap)]
            value = words[uniform] if uniform >= 0 else _chunk_word(words, line, k, np.int64(0x10001))
            if (value >> 16) & mask:
                return k
            value &= mask
            if high:
                planes[0, 2 * k] = value >> 8
                planes[1, 2 * k] = high ^ (value >> 8)
            if low:
                planes[0, 2 * k + 1] = value & 255
                planes[1, 2 * k + 1] = low ^ (value & 255)
        return count
    spread = np.int64(0x0001000100010001)
    for k in range(count):
        high, low, mask = _chunk_solid(solid, k)
        if mask == 0:
            continue
        words = pattern[np.uint64((first + k) & wrap)]
        value = words[uniform] if uniform >= 0 else _chunk_word(words, line, k, spread)
        if (value >> (16 * (channels - 1))) & mask:
            return k
        union = np.int64(0)
        for m in range(channels):
            v = mask & ~union if m == channels - 1 else (value >> (16 * m)) & mask
            if high:
                planes[m, 2 * k] = v >> 8
            if low:
                planes[m, 2 * k + 1] = v & 255
            union |= v
    return count


@helper(EXACT, inline=False)
def _pattern_words(table, level, channels, size, words, blocks):  # pragma: no cover - compiled
    """The choice table as bit patterns ((size, words, blocks, labels) int64, see :func:`_droplet_bits`): per
    tile row, block of 16 columns and label, one 16-bit field per channel but the last and one for the
    columns without a table entry, four fields to a word. Each label's bit at each dither level is placed once
    (in column 0's place of its field), then shifted to every column that has that level, all labels at a time
    (the innermost, contiguous loop: a tile of 64 has 16 times the columns of ordered dither's 16)."""
    wrap = size - 1
    labels, count = table.shape
    first = np.zeros((words, count, labels), dtype=np.int64)
    for number in range(labels):
        for lv in range(count):
            got = np.int64(table[number, lv])
            if got != channels - 1:
                slot = channels - 1 if got < 0 else got
                first[slot >> 2, lv, number] = np.int64(1) << (16 * (slot & 3) + 15)
    spread = np.int64(0x0001000100010001)
    pattern = np.zeros((size, words, blocks, labels), dtype=np.int64)
    for phase in range(size):
        for block in range(blocks):
            for j in range(16):
                # column j's bit in every field: it drops the copies of the sign bit an arithmetic shift makes
                column = spread << (15 - j)
                at = first[:, level[phase, (block * 16 + j) & wrap]]
                for w in range(words):
                    bits = at[w]
                    out = pattern[phase, w, block]
                    for number in range(labels):
                        out[number] |= (bits[number] >> j) & column
    return pattern


@helper(EXACT)
def _solid_span(solid, width):  # pragma: no cover - compiled
    """(first, last) bytes of a packed row that hold solid pixels (first > last: none), skipping empty
    stretches 16 bytes at a time."""
    first, last = 0, width - 1
    while first + 16 <= width:
        seen = 0
        for k in range(16):
            seen |= solid[first + k]
        if seen:
            break
        first += 16
    while first <= last and solid[first] == 0:
        first += 1
    if first > last:
        return first, last
    while last - 16 >= first:
        seen = 0
        for k in range(16):
            seen |= solid[last - k]
        if seen:
            break
        last -= 16
    while solid[last] == 0:
        last -= 1
    return first, last


@kernel(EXACT, label_arg=0)
def _droplet_bits(layer, mixing, dither, planes):  # pragma: no cover - compiled
    """Set one bit per solid pixel in the plane of the material it jets (see :func:`droplet_bits`).

    The table is first turned into bit patterns: per tile row, block of 16 columns and label,
    one 16-bit field per channel but the last (the block's columns where the label jets it)
    and one more for the columns without a table entry, four fields to an int64 word. A row
    is then halftoned 16 pixels at a time, OR-ing each pixel's word masked to its own column
    (no branch, no compare per channel); the last channel's byte is the solid byte less the
    others', and the pixels without a table entry take the general per-pixel mix (its running sums made
    once per label and lattice cell along a row, each pixel then compares its threshold). With one
    word (K <= 4), the chunks inside the labels go to :func:`_droplet_run` until one has such
    a pixel; after it, the run resumes past the next chunk without any (no call per chunk
    along a family of per-pixel mixes)."""
    label, r0, c0, packed, rows = layer
    family_of_label, fraction, layout, mixes, target = mixing
    tile, level, table, base_channel = dither
    channels = planes.shape[0]
    size = tile.shape[0]
    wrap = size - 1
    blocks = max(size, 16) // 16
    words = (channels + 3) // 4
    cols = label.shape[1]
    repeated = label.shape[0] == 1  # one row of labels for every row of the box
    uniform = np.int64(label[0, 0]) if repeated and cols else np.int64(-1)  # one label at every pixel, or -1
    for c in range(cols if repeated else 0):
        if label[0, c] != uniform:
            uniform = np.int64(-1)
            break
    width = packed.shape[1]
    spread = np.int64(0x0001000100010001)
    pattern = _pattern_words(table, level, channels, size, words, blocks)
    outside = np.zeros(words, dtype=np.int64)
    if base_channel < channels - 1:
        outside[base_channel >> 2] = np.int64(0xFFFF) << (16 * (base_channel & 3))
    acc = np.zeros(words, dtype=np.int64)
    extra = np.zeros(channels, dtype=np.int64)
    sums = np.empty(channels, dtype=np.float32)
    scale = np.float32(1.0)
    empty = label.ravel()[:0]
    for row in range(packed.shape[0]):
        solid = packed[row]
        first, last = _solid_span(solid, width)
        if first > last:
            continue
        r = row - r0
        inside = 0 <= r < rows
        line = label[0 if repeated else r] if inside else empty
        left, right = (c0, c0 + cols) if inside else (0, 0)
        phase = row & wrap
        thresholds = tile[phase]
        mixed_label, mixed_until = -1, 0  # the label and the column bound of the cell whose mix ``sums`` holds
        chunk, end = first >> 1, (last >> 1) + 1
        run_from, run_to = end, end
        if words == 1 and inside:
            run_from = max(chunk, (c0 + 15) >> 4)
            run_to = min(end, (c0 + cols) >> 4, width >> 1)
        while chunk < end:
            if chunk == run_from < run_to:
                chunk += _droplet_run(line[16 * chunk - c0:], solid[2 * chunk:], pattern[phase, 0], chunk,
                                      planes[:, row, 2 * chunk:], run_to - chunk, channels, uniform)
                run_from = chunk + 1
                continue
            high = np.int64(solid[2 * chunk])
            low = np.int64(solid[2 * chunk + 1]) if 2 * chunk + 1 < width else np.int64(0)
            mask = (high << 8) | low
            if mask == 0:
                chunk += 1
                continue
            col = chunk * 16
            block = chunk & (blocks - 1)
            if left <= col and col + 16 <= right:
                pixels = line[col - c0:col - c0 + 16]
                for w in range(words):
                    bits = pattern[phase, w, block]
                    value = np.int64(0)
                    for j in range(16):
                        value |= bits[pixels[j]] & (spread << (15 - j))
                    acc[w] = value
            else:
                for w in range(words):
                    bits = pattern[phase, w, block]
                    value = np.int64(0)
                    for j in range(16):
                        c = col + j
                        value |= (bits[line[c - c0]] if left <= c < right else outside[w]) & (spread << (15 - j))
                    acc[w] = value
            missing = (acc[(channels - 1) >> 2] >> (16 * ((channels - 1) & 3))) & mask
            if missing:
                for bit in range(16):
                    if not (missing >> (15 - bit)) & 1:
                        continue
                    c = col + bit
                    number = line[c - c0]
                    if number != mixed_label or c >= mixed_until:
                        # a new label or lattice cell: its eq. 1 mix, kept as running sums for the cell's pixels
                        family = family_of_label[number]
                        cell = layout[family, 2]
                        j = (c - layout[family, 1]) // cell
                        start = (layout[family, 4]
                                 + (((row - layout[family, 0]) // cell) * layout[family, 3] + j) * channels)
                        scale = _moved_sums(mixes[start:start + channels], fraction[number], target, sums)
                        mixed_label, mixed_until = number, layout[family, 1] + (j + 1) * cell
                    t = thresholds[c & wrap] * scale
                    pick = channels - 1
                    for m in range(channels - 1):
                        if t < sums[m]:
                            pick = m
                            break
                    extra[pick] |= 32768 >> bit
            union = np.int64(0)
            for m in range(channels):
                value = mask & ~union if m == channels - 1 else ((acc[m >> 2] >> (16 * (m & 3))) | extra[m]) & mask
                if high:
                    planes[m, row, 2 * chunk] = value >> 8
                if low:
                    planes[m, row, 2 * chunk + 1] = value & 255
                union |= value
            if missing:
                extra[:] = 0
                if run_from == chunk + 1:
                    run_from += 1
            chunk += 1
    return planes


def droplet_bits(layer: LabelledLayer, mixing: LayerMixes, dither: Dither, planes: np.ndarray) -> np.ndarray:
    """Halftone a labelled layer into bit-packed droplet masks, in place in ``planes`` ((K, h, ceil(w/8)) uint8).

    label ((rows, cols) uint8/16/32, 0 empty) covers the layer from pixel (row0, col0); a labelled
    pixel's mix is its family's start mix at its lattice cell (``mixes`` flat, family f's
    cells from layout[f, 4], cells of layout[f, 2] pixels from row layout[f, 0], column
    layout[f, 1], layout[f, 3] cells per row) moved by fraction[label] towards ``target``
    (eq. 1); the pixel jets the first material whose running sum of the mix exceeds the
    threshold ``tile``[row % n, col % n] (n a power of two) times the mix's total
    (the running-sum choice of :mod:`heoslice.grading.halftone`, in the same float32 arithmetic, so the
    masks agree bit for bit). ``packed`` is the layer's solid mask ((h, ceil(w/8)) uint8,
    rows MSB first, padding bits clear); its solid pixels without a label jet
    ``base_channel``. ``table`` ((labels, n * n) int8) short-cuts all that for a label
    whose entry at the pixel's threshold level is not -1 (the level of threshold t is
    t L - 1/2, L = table.shape[1] levels: the tile holds values (k + 1/2) / L); its row 0 (no
    label) must hold ``base_channel``. Bytes of ``planes`` without a solid pixel are left as
    they are.
    """
    tile, table, base_channel = dither
    count = table.shape[1]  # the levels: n^2 for a tile of every level once, fewer for a tile that repeats them
    # C order whatever the tile's layout (a transposed one is Fortran-ordered): one compiled signature
    level = np.ascontiguousarray(np.rint(np.asarray(tile, dtype=np.float64) * count - 0.5).astype(np.int64))
    label = layer.label
    rows = label.shape[0]
    if rows > 1 and label.strides[0] == 0:
        label = label[:1]  # labels that do not change down the box: their one row serves every row
    label = np.ascontiguousarray(label)
    layer = (label, int(layer.row0), int(layer.col0), np.ascontiguousarray(layer.packed), rows)
    mixing = (i64(mixing.family_of_label), f32(mixing.fraction), i64(mixing.layout), f32(mixing.mixes),
              f32(mixing.target))
    return _droplet_bits(layer, mixing, (f32(tile), level, np.ascontiguousarray(table, dtype=np.int8),
                                         int(base_channel)), planes)


@kernel(EXACT)
def _agreed_choices(cells, moved, target, levels):  # pragma: no cover - compiled
    """(len(moved), len(levels)) int8: for each fraction f of ``moved`` ((l,) float32), the channel every
    cell's mix ((n, K) float32) moved by f towards ``target`` ((K,) float32) jets at each threshold level
    ((t,) float32, ascending), -1 where the cells do not agree.

    A mix jets the first channel m whose running sum exceeds the level times its total (in the float32
    arithmetic of :func:`_droplet_bits`); the running sums ascend, so channel m's own condition holds below
    a level index b_m (ascending in m too), found by bisection, and the choice at level i is the first m
    with i < b_m: the cells agree at i exactly when, for every m, i is below every cell's b_m or at or
    above all of them.
    """
    channels, count = cells.shape[1], len(levels)
    out = np.full((len(moved), count), -1, dtype=np.int8)
    sums = np.empty(channels, dtype=np.float32)
    low = np.empty(max(channels - 1, 1), dtype=np.int64)
    high = np.empty(max(channels - 1, 1), dtype=np.int64)
    first = np.empty(max(channels - 1, 1), dtype=np.int64)
    for label in range(len(moved)):
        f = moved[label]
        low[:] = count
        high[:] = 0
        for c in range(len(cells)):
            scale = _moved_sums(cells[c], f, target, sums)
            for m in range(channels - 1):
                running = sums[m]
                below, above = 0, count
                while below < above:
                    middle = (below + above) // 2
                    if levels[middle] * scale < running:
                        below = middle + 1
                    else:
                        above = middle
                low[m] = min(low[m], below)
                high[m] = max(high[m], below)
                if c == 0:
                    first[m] = below
        if len(cells) == 0:
            continue
        for i in range(count):
            pick = channels - 1
            agreed = True
            for m in range(channels - 1):
                agreed &= i < low[m] or i >= high[m]
                if pick == channels - 1 and i < first[m]:
                    pick = m
            if agreed:
                out[label, i] = pick
    return out


def agreed_choices(cells: np.ndarray, moved: np.ndarray, target: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """:func:`_agreed_choices` of cell mixes ((n, K)), fractions ((l,)), a target mix ((K,)) and threshold
    levels ((t,)), all taken as float32."""
    return _agreed_choices(f32(cells), f32(moved), f32(target), f32(levels))
