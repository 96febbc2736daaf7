"""Compiled loops of :mod:`heoslice.grading.diffusion`: serpentine vector error diffusion into bit-packed droplet
masks, row by row over the solid pixels only, of a given per-pixel mix or of a labelled layer's mix made on the
fly (one pass: no per-pixel mix array for the layer): read from a table of each label's mix where every family's
cells hold one start mix (a grade from one colour), else made per row where a pixel's label changed."""

from __future__ import annotations

import numpy as np

from heoslice.grading.droplets_kernels import _moved_sums, _solid_span
from heoslice.jit import EXACT, helper, kernel

#: Columns of padding on either side of the error rows: a pixel's error reaches two columns either way, and
#: the rows below gather from two columns either way of those.
PAD = 4


@helper(EXACT)
def _cell_mix(number, start, mixing, base_channel, scratch):  # pragma: no cover - compiled
    """The mix of label ``number``'s pixels whose lattice cell's start mix begins at ``start`` of the mixes, into
    ``scratch[1]`` ((2, K) float32, scratch[0] the running sums): the start mix moved by the label's fraction towards
    the target (eq. 1, in :func:`heoslice.grading.droplets_kernels._moved_sums`' float32 arithmetic), all
    ``base_channel`` where the moved mix has no positive total."""
    family_of_label, fraction, layout, mixes, target = mixing
    channels = scratch.shape[1]
    sums, cell_mix = scratch[0], scratch[1]
    cell_mix[:] = np.float32(0.0)
    scale = _moved_sums(mixes[start:start + channels], fraction[number], target, sums)
    positive = True
    if channels > 1:
        total = sums[channels - 2] + (mixes[start + channels - 1] + fraction[number]
                                      * (target[channels - 1] - mixes[start + channels - 1]))
        positive = total > np.float32(0.0)
    if not positive:
        cell_mix[base_channel] = 1.0
    else:
        below = np.float32(0.0)
        for m in range(channels - 1):
            cell_mix[m] = (sums[m] - below) / scale
            below = sums[m]
        cell_mix[channels - 1] = max(np.float32(1.0) - below / scale, np.float32(0.0))


@helper(EXACT)
def _label_mixes(mixing, base_channel, scratch, table):  # pragma: no cover - compiled
    """Each label's mix into ``table`` ((labels, K) float32) where its family's cells all hold one start mix (the
    mix then depends on the label alone; label 0 all ``base_channel``); returns whether every family's do."""
    family_of_label, fraction, layout, mixes, target = mixing
    channels = table.shape[1]
    families = layout.shape[0]
    uniform = np.ones(families, dtype=np.bool_)
    for family in range(families):
        first = layout[family, 4]
        end = layout[family + 1, 4] if family + 1 < families else mixes.shape[0]
        for k in range(first + channels, end):
            if mixes[k] != mixes[first + (k - first) % channels]:
                uniform[family] = False
                break
    table[:] = np.float32(0.0)
    table[0, base_channel] = 1.0
    for number in range(1, table.shape[0]):
        family = family_of_label[number]
        if uniform[family]:
            _cell_mix(number, layout[family, 4], mixing, base_channel, scratch)
            table[number] = scratch[1]
    for family in range(families):
        if not uniform[family]:
            return False
    return True


@helper(EXACT)
def _table_row_mixes(line, c0, lo, hi, solid, table, out):  # pragma: no cover - compiled
    """:func:`_row_mixes` of box columns lo .. hi - 1 of one row when every label's mix is its row of ``table``
    (:func:`_label_mixes`): a solid pixel's label's, an empty one's all 0."""
    channels = out.shape[1]
    for c in range(lo, hi):
        col = c0 + c
        on = np.float32((solid[col >> 3] >> (7 - (col & 7))) & 1)
        number = line[c]
        for m in range(channels):
            out[c, m] = table[number, m] * on


@helper(EXACT)
def _row_mixes(line, row, c0, lo, hi, solid, mixing, base_channel, scratch, out):  # pragma: no cover - compiled
    """Each pixel's mix of box columns lo .. hi - 1 of one row into ``out`` ((cols, K) float32, summing to 1):
    a labelled solid pixel's family start mix at its lattice cell moved by its label's fraction towards the
    target (eq. 1, in :func:`heoslice.grading.droplets_kernels._moved_sums`' float32 arithmetic), a solid
    pixel without a label (or whose moved mix has no positive total) all ``base_channel``, an empty one all 0.
    ``line`` holds the row's labels from box column 0 (layer column ``c0``), ``solid`` the layer's packed row;
    ``scratch`` ((2, K) float32) the running sums and the mix of the cell last met."""
    family_of_label, fraction, layout, mixes, target = mixing
    channels = out.shape[1]
    mixed_label, cell_from, cell_to = -1, 0, 0
    cell_mix = scratch[1]
    for c in range(lo, hi):
        col = c0 + c
        if not (solid[col >> 3] >> (7 - (col & 7))) & 1:
            for m in range(channels):
                out[c, m] = np.float32(0.0)
            continue
        number = line[c]
        if number != mixed_label or not cell_from <= col < cell_to:
            if number == 0:
                cell_mix[:] = np.float32(0.0)
                cell_mix[base_channel] = 1.0
                mixed_label, cell_from, cell_to = 0, col, col + 1
            else:
                family = family_of_label[number]
                cell = layout[family, 2]
                j = (col - layout[family, 1]) // cell
                start = layout[family, 4] + (((row - layout[family, 0]) // cell) * layout[family, 3] + j) * channels
                _cell_mix(number, start, mixing, base_channel, scratch)
                cell_from = layout[family, 1] + j * cell
                mixed_label, cell_to = number, cell_from + cell
        for m in range(channels):
            out[c, m] = cell_mix[m]


@helper(EXACT)
def _kept_row_mixes(line, row, c0, lo, hi, solid, mixing, base_channel, scratch, out, keys,
                    renew):  # pragma: no cover - compiled
    """:func:`_row_mixes` of box columns lo .. hi - 1 of one row into ``out``, remaking only the pixels whose key
    changed from the row before: a pixel's mix depends on its label, its column and its family's row of lattice
    cells alone, so ``keys`` ((cols,) int64) holds the label each pixel of ``out`` was made for (-1 empty, -2
    none) and ``renew`` (a family's row of cells changed) remakes the whole span and forgets every other
    column's key (made for the cells before: a span widening again later in these cells remakes them)."""
    if renew:
        keys[:] = -2
        _row_mixes(line, row, c0, lo, hi, solid, mixing, base_channel, scratch, out)
    c = lo
    while c < hi:
        col = c0 + c
        key = np.int64(line[c]) if (solid[col >> 3] >> (7 - (col & 7))) & 1 else np.int64(-1)
        if key == keys[c]:
            c += 1
            continue
        begin = c
        keys[c] = key
        c += 1
        while c < hi:  # the run of pixels whose key changed
            col = c0 + c
            key = np.int64(line[c]) if (solid[col >> 3] >> (7 - (col & 7))) & 1 else np.int64(-1)
            if key == keys[c]:
                break
            keys[c] = key
            c += 1
        if not renew:
            _row_mixes(line, row, c0, begin, c, solid, mixing, base_channel, scratch, out)


@helper(EXACT, inline=False)
def _diffuse_row(mixrow, span, place, errors, spread, state, settings, planes):  # pragma: no cover - compiled
    """Diffuse one row of the box (see :func:`_diffuse`): ``mixrow`` ((cols, K) float32) at box columns span =
    (lo, hi), place = (box row r, layer row, layer column of box column 0); ``errors`` the ring of the error
    reaching rows r, r + 1, r + 2 ((3, K + 1, cols + 2 PAD) float32, row r at r % 3; channel K the weight of
    error that reached the pixel), ``spread`` = (this row's outgoing errors ((K + 1, cols + 2 PAD) float32,
    zero), each ring row's columns holding anything ((3, 2) int64)); the ring row r is left zero for row r + 3."""
    lo, hi = span
    r, row, c0 = place
    carry_in, dr, dc, fresh, carry_out = state
    weights, shares, start, flip = settings
    left, dirty = spread
    channels = mixrow.shape[1]
    cur = errors[r % 3]
    layer_share, top_share, charge = np.float32(shares[0]), np.float32(shares[1]), np.float32(shares[2])
    balance = np.float32(0.5) - np.float32(0.5 * channels - 1.0) / np.float32(channels)
    kept = np.float32(1.0) - layer_share
    forward = ((row + flip) & 1) == 0
    step = 1 if forward else -1
    ahead_1, ahead_2 = weights[0, 3], weights[0, 4]
    wrap = start.shape[0] - 1
    thresholds = start[row & wrap]
    cr = r + dr
    carried = fresh == 0 and 0 <= cr < carry_in.shape[0]
    carried_cols = carry_in.shape[1]
    written = False
    for k in range(hi - lo):
        c = lo + k if forward else hi - 1 - k
        held = 0
        only = 0
        for m in range(channels):
            if mixrow[c, m] > np.float32(0.0):
                held += 1
                only = m
        if held == 0:
            continue
        col = c0 + c
        if held == 1:  # one material: taken as it is, no error passed on
            planes[only, row, col >> 3] |= np.uint8(0x80 >> (col & 7))
            continue
        written = True
        fed = cur[channels, c + PAD]
        bias = min(top_share * (np.float32(1.0) - fed), np.float32(1.0)) if fed < np.float32(0.99) else np.float32(0.0)
        chosen = -1
        if bias > np.float32(0.0) or fresh:  # the threshold mask's choice (a region's start, a run's first layer)
            threshold = thresholds[col & wrap]
            total = np.float32(0.0)
            for m in range(channels):
                total += mixrow[c, m]
            threshold *= total
            running = np.float32(0.0)
            chosen = channels - 1
            for m in range(channels - 1):
                running += mixrow[c, m]
                if threshold < running:
                    chosen = m
                    break
        inside = carried and 0 <= c + dc < carried_cols
        missing = max(np.float32(1.0) - fed, np.float32(0.0)) * charge
        pick = 0
        best = -np.inf
        for m in range(channels):
            share_m = mixrow[c, m]
            if share_m > np.float32(0.0):
                value = share_m + cur[m, c + PAD]
                if missing > np.float32(0.0):
                    value += missing * (balance - share_m)
                jetted = np.float32(1.0) if m == chosen else np.float32(0.0)
                steady = charge * (balance - share_m)
                if fresh:
                    value += layer_share * (share_m - jetted + steady)
                else:
                    value += layer_share * steady
                    if inside:
                        value += carry_in[cr, c + dc, m]
                left[m, c + PAD] = value
                decided = value + bias * (jetted - share_m)
                if decided > best:
                    best, pick = decided, m
        left[pick, c + PAD] -= np.float32(1.0)
        for m in range(channels):
            error = left[m, c + PAD]
            if mixrow[c, m] > np.float32(0.0):
                carry_out[r, c, m] = (error - charge * (balance - mixrow[c, m])) * layer_share
                error *= kept
                left[m, c + PAD] = error
                cur[m, c + PAD + step] += error * ahead_1
                cur[m, c + PAD + 2 * step] += error * ahead_2
        left[channels, c + PAD] = np.float32(1.0)
        cur[channels, c + PAD + step] += ahead_1
        cur[channels, c + PAD + 2 * step] += ahead_2
        planes[pick, row, col >> 3] |= np.uint8(0x80 >> (col & 7))
    _spread_below(left, errors, dirty, (r, lo, hi, channels + 1), forward, weights, written)


@helper(EXACT)
def _spread_below(left, errors, dirty, span, forward, weights, written):  # pragma: no cover - compiled
    """After box row r (span = (r, lo, hi, n)): when the row ``written`` errors, the rows below take each pixel's
    first n channels of ``left`` by their weights (mirrored on a row run right to left), and ``left`` is zeroed;
    the ring row r is zeroed for row r + 3 (over the columns ``dirty`` says it holds anything)."""
    r, lo, hi, count = span
    if written:
        for below in range(1, 3):
            slot = (r + below) % 3
            target_row = errors[slot]
            dirty[slot, 0] = min(dirty[slot, 0], lo + PAD - 2)
            dirty[slot, 1] = max(dirty[slot, 1], hi + PAD + 2)
            # pixel c takes from the pixels c - 2 .. c + 2 of this row by the weights, reversed on a forward row
            taps = weights[below, ::-1] if forward else weights[below]
            w_0, w_1, w_2, w_3, w_4 = taps[0], taps[1], taps[2], taps[3], taps[4]
            for m in range(count):
                target, source = target_row[m], left[m]
                for c in range(lo + PAD - 2, hi + PAD + 2):
                    u = np.uint64(c)  # unsigned: no negative-index wrap to test (the loop vectorises)
                    target[u] += (source[u - np.uint64(2)] * w_0 + source[u - np.uint64(1)] * w_1 + source[u] * w_2
                                  + source[u + np.uint64(1)] * w_3 + source[u + np.uint64(2)] * w_4)
        for m in range(count):
            left[m, lo + PAD:hi + PAD] = np.float32(0.0)
    slot = r % 3
    dirty[slot, 0] = min(dirty[slot, 0], lo + PAD - 2)
    dirty[slot, 1] = max(dirty[slot, 1], hi + PAD + 2)
    cur = errors[slot]
    for m in range(count):
        cur[m, dirty[slot, 0]:dirty[slot, 1]] = np.float32(0.0)
    dirty[slot, 0], dirty[slot, 1] = cur.shape[1], 0


@helper(EXACT, inline=False)
def _diffuse_pair_row(mixing, span, place, errors, spread, state, settings, planes):  # pragma: no cover - compiled
    """:func:`_diffuse_row` of two materials, on material 0's error alone (the other's is its negative: every error
    passed on, carried or added sums to 0 over the two, where a pixel holds both): the same choices, half the
    arithmetic; ``errors`` (3, 2, cols + 2 PAD) and ``left`` (2, cols + 2 PAD) hold that error and the weight,
    the carried errors are (rows, cols, 1). The one serial step from pixel to pixel is kept short: the pixel
    before's error reaches the next as its value times the weight ahead (the share kept in the layer folded in)
    less that weight where it took material 0, added last; the two pixels before's error and weight stay in
    registers, and the droplet bits are gathered a byte at a time. ``mixing`` = (line, table, solid): box column
    c's mix is ``table[line[c]]`` ((2,) float32) where the packed row ``solid`` has its pixel, else none (a
    labelled row's labels and its labels' mixes, or an identity line and the row's per-pixel mixes)."""
    line, table, solid = mixing
    lo, hi = span
    r, row, c0 = place
    carry_in, dr, dc, fresh, carry_out = state
    weights, shares, start, flip = settings
    left, dirty = spread
    cur = errors[r % 3]
    cur_error, cur_fed, left_error, left_fed = cur[0], cur[1], left[0], left[1]
    layer_share, top_share, charge = np.float32(shares[0]), np.float32(shares[1]), np.float32(shares[2])
    kept = np.float32(1.0) - layer_share
    forward = ((row + flip) & 1) == 0
    ahead_1, ahead_2 = weights[0, 3], weights[0, 4]
    kept_1, kept_2 = ahead_1 * kept, ahead_2 * kept
    wrap = start.shape[0] - 1
    thresholds = start[row & wrap]
    cr = r + dr
    # the box columns whose pixel the layer before's error covers (none on a fresh layer or outside its rows)
    from_col, to_col = (max(lo, -dc), min(hi, carry_in.shape[1] - dc)) \
        if fresh == 0 and 0 <= cr < carry_in.shape[0] else (0, 0)
    incoming = carry_in[min(max(cr, 0), max(carry_in.shape[0] - 1, 0))].reshape(carry_in.shape[1])
    outgoing = carry_out[r].reshape(carry_out.shape[1])
    shares_of = table.reshape(2 * table.shape[0])  # one dimension: no stride to multiply per pixel
    half = np.float32(0.5)
    written = False
    # the pixel before's value times kept_1 and the part of kept_1 to take off (kept_1 where it took material 0), and
    # its error; the error of the pixel two before; the weight of error that reached the two pixels before (0: none)
    ahead_value = ahead_taken = error_1 = error_2 = np.float32(0.0)
    fed_1 = fed_2 = np.float32(0.0)
    held_byte, bits_0, bits_1 = -1, np.uint8(0), np.uint8(0)  # the packed byte being gathered, each plane's bits
    first, step = (lo, 1) if forward else (hi - 1, -1)
    for k in range(hi - lo):
        c = first + step * k
        u = np.uint64(c)  # unsigned indices: no negative-index wrap to test
        p = np.uint64(c + PAD)
        col = c0 + c
        at = np.uint64(col)
        number = np.uint64(line[u]) << np.uint64(1)
        on = np.float32((solid[at >> np.uint64(3)] >> (np.uint64(7) - (at & np.uint64(7)))) & np.uint64(1))
        share_0, share_1 = shares_of[number] * on, shares_of[number + np.uint64(1)] * on
        if not (share_0 > np.float32(0.0) and share_1 > np.float32(0.0)):
            if share_0 > np.float32(0.0) or share_1 > np.float32(0.0):
                if col >> 3 != held_byte:
                    if held_byte >= 0:
                        planes[0, row, held_byte] |= bits_0
                        planes[1, row, held_byte] |= bits_1
                    held_byte, bits_0, bits_1 = col >> 3, np.uint8(0), np.uint8(0)
                if share_0 > np.float32(0.0):
                    bits_0 |= np.uint8(0x80 >> (col & 7))
                else:
                    bits_1 |= np.uint8(0x80 >> (col & 7))
            ahead_value = ahead_taken = np.float32(0.0)
            error_2, error_1, fed_2, fed_1 = error_1, np.float32(0.0), fed_1, np.float32(0.0)
            continue
        written = True
        total = share_0 + share_1
        steady = charge * (half - share_0)
        base = share_0 + (cur_error[p] + error_2 * kept_2)
        fed = cur_fed[p] + fed_1 * ahead_1 + fed_2 * ahead_2
        threshold = half * total
        if fed < np.float32(0.99) or fresh:
            jetted = np.float32(1.0) if thresholds[at & np.uint64(wrap)] * total < share_0 else np.float32(0.0)
            if fed < np.float32(0.99):
                missing = max(np.float32(1.0) - fed, np.float32(0.0))
                threshold -= min(top_share * missing, np.float32(1.0)) * (jetted - share_0)
                base += missing * charge * (half - share_0)
            if fresh:
                base += layer_share * (share_0 - jetted + steady)
        if not fresh:
            base += layer_share * steady
            if from_col <= c < to_col:
                base += incoming[np.uint64(c + dc)]
        value = (base + ahead_value) - ahead_taken
        take = value >= threshold
        ahead_value = value * kept_1
        ahead_taken = kept_1 * np.float32(take)
        error = value - (np.float32(1.0) if take else np.float32(0.0))
        outgoing[u] = (error - steady) * layer_share
        left_error[p] = error * kept
        left_fed[p] = np.float32(1.0)
        error_2, error_1, fed_2, fed_1 = error_1, error, fed_1, np.float32(1.0)
        if col >> 3 != held_byte:
            if held_byte >= 0:
                planes[0, row, held_byte] |= bits_0
                planes[1, row, held_byte] |= bits_1
            held_byte, bits_0, bits_1 = col >> 3, np.uint8(0), np.uint8(0)
        bit = np.uint8(0x80 >> (col & 7))
        bits_0 |= bit * np.uint8(take)
        bits_1 |= bit * np.uint8(not take)
    if held_byte >= 0:
        planes[0, row, held_byte] |= bits_0
        planes[1, row, held_byte] |= bits_1
    _spread_below(left, errors, dirty, (r, lo, hi, 2), forward, weights, written)


@kernel(EXACT)
def _diffuse(mix, origin, state, settings, planes):  # pragma: no cover - compiled
    """Serpentine vector error diffusion of ``mix`` ((rows, cols, K) float32, all 0 at empty pixels) into the
    bit-packed ``planes`` ((K, h, ceil(w / 8)) uint8, bits only set), the box's pixel (0, 0) at layer pixel
    ``origin`` (row, col).

    Each solid pixel takes, among the materials its own mix holds (> 0), the one whose share plus the error
    arriving at it is largest: the error of the pixels before it in the layer, and of the layer before, from
    ``state`` = (its carried error (rows', cols', n) float32 (n = 1 for K = 2: material 0's), this box's
    offset (row, col) in it, fresh, this layer's carried error (rows, cols, n) float32, zero, written). The
    difference between the share plus error and the material taken goes to the pixels after it by the
    weights of ``settings`` = (weights ((3, 5) float32: this row and the two below, columns -2 .. 2 along the
    row's direction, summing to 1), shares (layer share, top share, charge), the threshold mask ((n, n)
    float32, n a power of two, anchored at the layer's pixel (0, 0)), flip) times 1 - layer share; the layer
    share of it, less its steady part S_m = charge (1/2 - s_m - (K/2 - 1)/K), to the same pixel of the next
    layer, which adds layer share times S_m back (so layers of different mixes trade no material); a fresh
    layer adds instead layer share times (s_m + S_m less the mask's choice). Error reaching a pixel that does
    not hold its material, or an empty pixel, is dropped; a pixel of one material passes none on, so a region
    of one material stays pure. Where a weight w < 1 of error reached a pixel (a region's first rows and
    sides), (1 - w) S_m is added to its error (the steady error it would hold inside the region) and
    min(1, top share (1 - w)) times the mask's choice less the mix to its decision only, so a region starts as
    the mask would print it. Rows run left to right when (layer row + flip) is even, else right to left."""
    rows, cols, channels = mix.shape
    pair = channels == 2
    identity = np.arange(cols)
    everywhere = np.full(((origin[1] + cols) >> 3) + 1, 0xFF, dtype=np.uint8)
    errors = np.zeros((3, 2 if pair else channels + 1, cols + 2 * PAD), dtype=np.float32)
    left = np.zeros((2 if pair else channels + 1, cols + 2 * PAD), dtype=np.float32)
    dirty = np.zeros((3, 2), dtype=np.int64)
    dirty[:, 0] = cols + 2 * PAD
    for r in range(rows):
        if pair:
            _diffuse_pair_row((identity, mix[r], everywhere), (0, cols), (r, origin[0] + r, origin[1]), errors,
                              (left, dirty), state, settings, planes)
        else:
            _diffuse_row(mix[r], (0, cols), (r, origin[0] + r, origin[1]), errors, (left, dirty), state, settings,
                         planes)
    return planes


@kernel(EXACT, label_arg=0)
def _diffuse_labelled(layer, mixing, base_channel, state, settings, planes):  # pragma: no cover - compiled
    """:func:`_diffuse` of a labelled layer's mix (as :func:`heoslice.grading.droplets_kernels.droplet_bits`
    reads it: ``layer`` = (labels of the box, its first row and column, the packed solid mask, its rows),
    ``mixing`` its families' mixes), each row's read from each label's mix (:func:`_label_mixes`) where every
    family's cells hold one start mix, else made over its solid span only where a pixel's label changed from the
    row before (:func:`_kept_row_mixes`); solid pixels outside the box are left to the caller."""
    label, r0, c0, packed, rows = layer
    cols = label.shape[1]
    channels = planes.shape[0]
    repeated = label.shape[0] == 1
    width = packed.shape[1]
    pair = channels == 2
    mixrow = np.zeros((cols, channels), dtype=np.float32)
    identity = np.arange(cols)
    scratch = np.zeros((2, channels), dtype=np.float32)
    keys = np.full(cols, -2, dtype=np.int64)
    family_of_label, fraction, layout, mixes, target = mixing
    bands = np.full(layout.shape[0], np.iinfo(np.int64).min, dtype=np.int64)
    table = np.zeros((family_of_label.shape[0], channels), dtype=np.float32)
    by_label = _label_mixes(mixing, base_channel, scratch, table)
    errors = np.zeros((3, 2 if pair else channels + 1, cols + 2 * PAD), dtype=np.float32)
    left = np.zeros((2 if pair else channels + 1, cols + 2 * PAD), dtype=np.float32)
    dirty = np.zeros((3, 2), dtype=np.int64)
    dirty[:, 0] = cols + 2 * PAD
    for r in range(rows):
        row = r0 + r
        solid = packed[row]
        first, last = _solid_span(solid, width)
        lo = max(first * 8 - c0, 0)
        hi = min(last * 8 + 8 - c0, cols)
        if lo < hi and by_label:
            if pair:
                _diffuse_pair_row((label[0 if repeated else r], table, solid), (lo, hi), (r, row, c0), errors,
                                  (left, dirty), state, settings, planes)
                continue
            _table_row_mixes(label[0 if repeated else r], c0, lo, hi, solid, table, mixrow)
        elif lo < hi:
            renew = False
            for family in range(layout.shape[0]):
                band = (row - layout[family, 0]) // layout[family, 2]
                renew |= band != bands[family]
                bands[family] = band
            _kept_row_mixes(label[0 if repeated else r], row, c0, lo, hi, solid, mixing, base_channel, scratch,
                            mixrow, keys, renew)
        else:
            lo = hi = 0
        if pair:
            _diffuse_pair_row((identity, mixrow, solid), (lo, hi), (r, row, c0), errors, (left, dirty), state,
                              settings, planes)
        else:
            _diffuse_row(mixrow, (lo, hi), (r, row, c0), errors, (left, dirty), state, settings, planes)
    return planes
