"""Compiled kernel of :mod:`heoslice.export.voxel_print` (numba source, compiled at install: :mod:`heoslice.jit`):
a Voxel Print slice's zlib stream written straight from the runs of equal labels of its sampled rows, never the
RGB rows themselves. Each row is a filter byte 0 then, per run of n pixels of one colour, its 3 bytes as
literals and the other 3 (n - 1) as matches at distance 3 (RFC 1951), coded by a
:class:`heoslice.deflate.RunCode`; the stream's Adler-32 (RFC 1950) is summed per run in closed form.
"""

from __future__ import annotations

import numpy as np

from heoslice.jit import EXACT, compiled_module, helper, i64, kernel
from heoslice.layers.packed_kernels import _popcount

if compiled_module() is None:  # the kernel compiles just in time: numba's count of leading zeros (LLVM's ctlz)
    from numba.cpython.unsafe.numbers import leading_zeros

#: The Adler-32 modulus (RFC 1950).
ADLER_BASE = 65521
#: Longest deflate match (RFC 1951); a multiple of 3, so a run's matches never leave a remainder under 3.
LONGEST_MATCH = 258
#: The slot of a :class:`heoslice.deflate.RunCode` table holding literal byte b: LITERAL + b.
LITERAL = 259


@helper(EXACT)
def _put(out, held, count, at, code, bits):
    """Append ``bits`` (at most 32) of ``code``, least significant first, to a stream of ``at`` bytes in ``out``
    and ``count`` bits ``held`` (fewer than 32): 4 bytes are stored whenever 32 bits are held. Returns the new
    (held, count, at), ``at`` -1 when ``out`` is full (and stays -1, nothing more appended)."""
    if at < 0:
        return held, count, at
    held |= code << np.uint64(count)
    count += bits
    if count >= 32:
        if at + 4 > out.shape[0]:
            return held, count - 32, -1
        for k in range(4):
            out[at + k] = np.uint8((held >> np.uint64(8 * k)) & np.uint64(0xFF))
        held >>= np.uint64(32)
        count -= 32
        at += 4
    return held, count, at


@helper(EXACT)
def _adler_run(a, b, n, red, green, blue):
    """Adler-32 sums (A, B) after n pixels of (red, green, blue): A += n s and B += 3 n A + 3 s n (n - 1) / 2
    + n (3 red + 2 green + blue), s = red + green + blue, modulo 65521 (the sum of each byte's running A)."""
    s = red + green + blue
    m = n % ADLER_BASE
    pairs = (n * (n - 1) // 2) % ADLER_BASE
    b = (b + (3 * m * a) % ADLER_BASE + (3 * s * pairs) % ADLER_BASE + (m * (3 * red + 2 * green + blue))
         % ADLER_BASE) % ADLER_BASE
    return (a + m * s) % ADLER_BASE, b


@helper(EXACT)
def _too_many_runs(words, row_of, top, scale, least_bits, room):
    """Whether the sampled rows' runs, estimated by their pixels unlike the one before in some plane (scaled by
    ``scale``, the sampled columns per stack column, up to 1), would need more than ``room`` bytes at
    ``least_bits`` a run: a dithered layer is found by a popcount a word before any of it is coded."""
    changes_seen = 0
    for y in range(row_of.shape[0]):
        row = row_of[y]
        if row < 0:
            continue
        for w in range(words.shape[2]):
            changes = np.uint64(0)
            for p in range(words.shape[0]):
                word = words[p, row, w]
                before = words[p, row, w - 1] << np.uint64(63) if w else word & top
                changes |= word ^ ((word >> np.uint64(1)) | before)
            changes_seen += np.int64(_popcount(changes))
    return changes_seen * min(scale, 1.0) * least_bits > 8.0 * room


@kernel(EXACT)
def _run_stream(words, row_of, width, first, colours, codes, lengths, header, header_bits,
                out):  # pragma: no cover - compiled
    """Write the zlib stream into ``out`` and return its length in bytes, or -1 when it does not fit
    (:func:`run_stream`; ``words`` the sampled rows' byte-swapped words, pixel 0 their top bit)."""
    full, top = np.uint64(0xFFFFFFFFFFFFFFFF), np.uint64(1) << np.uint64(63)
    planes, words_per_row, labels = words.shape[0], words.shape[2], colours.shape[0]
    # a run's first pixel (its three literals) by label, and k matches of the longest length as one code
    first_code, first_bits = np.zeros(labels, dtype=np.uint64), np.zeros(labels, dtype=np.int64)
    for label in range(labels):
        for channel in range(3):
            slot = LITERAL + colours[label, channel]
            first_code[label] |= codes[slot] << np.uint64(first_bits[label])
            first_bits[label] += lengths[slot]
    if _too_many_runs(words, row_of, top, first[width] / max(width, 1), first_bits.min(), out.shape[0]):
        return -1
    longest = max(1, 32 // lengths[LONGEST_MATCH])
    repeat_code, repeat_bits = np.zeros(longest + 1, dtype=np.uint64), np.zeros(longest + 1, dtype=np.int64)
    for k in range(1, longest + 1):
        repeat_code[k] = repeat_code[k - 1] | (codes[LONGEST_MATCH] << np.uint64(repeat_bits[k - 1]))
        repeat_bits[k] = repeat_bits[k - 1] + lengths[LONGEST_MATCH]
    held, count, at = np.uint64(0), 0, 0
    for byte in range((header_bits + 7) // 8):
        held, count, at = _put(out, held, count, at, np.uint64(header[byte]), min(8, header_bits - 8 * byte))
    a, b = 1, 0
    runs = np.empty(2 * (width + 1), dtype=np.int64)  # (label, slice pixels) of a row's runs
    for y in range(row_of.shape[0]):
        held, count, at = _put(out, held, count, at, codes[LITERAL], lengths[LITERAL])  # filter byte 0
        b = (b + a) % ADLER_BASE
        row = row_of[y]
        made = 0
        if row < 0:
            runs[0], runs[1], made = 0, first[width], 1
        else:
            label, start = -1, 0  # the run being read, from stack column start
            for w in range(words_per_row):
                uniform = 0  # the label of all 64 pixels, or -2 when they differ (a full plane hides those before it)
                changes = np.uint64(0)  # bit 63 - q set where pixel q differs from pixel q - 1 in some plane
                for p in range(planes):
                    word = words[p, row, w]
                    changes |= word ^ (word >> np.uint64(1))
                    if word == full:
                        uniform = max(uniform, p + 1)
                    elif word != 0:
                        uniform = -2
                if uniform == label:
                    continue
                changes = (changes & ~top) | top  # pixel 0 is compared with the run being read
                while changes:
                    q = leading_zeros(changes)
                    column = w * 64 + q
                    if column >= width:
                        break
                    changes ^= top >> np.uint64(q)
                    here = 0
                    for p in range(planes):
                        if words[p, row, w] & (top >> np.uint64(q)):
                            here = p + 1
                    if here != label:
                        n = first[column] - first[start]
                        if label >= 0 and n > 0:
                            if made and runs[2 * made - 2] == label:
                                runs[2 * made - 1] += n
                            else:
                                runs[2 * made], runs[2 * made + 1] = label, n
                                made += 1
                        label, start = here, column
            n = first[width] - first[start]
            if n > 0:
                if made and runs[2 * made - 2] == label:
                    runs[2 * made - 1] += n
                else:
                    runs[2 * made], runs[2 * made + 1] = label, n
                    made += 1
        for r in range(made):
            label, n = runs[2 * r], runs[2 * r + 1]
            if first_bits[label] <= 32:
                held, count, at = _put(out, held, count, at, first_code[label], first_bits[label])
            else:
                for channel in range(3):
                    slot = LITERAL + colours[label, channel]
                    held, count, at = _put(out, held, count, at, codes[slot], lengths[slot])
            left = 3 * (n - 1)
            k = left // LONGEST_MATCH
            while k > 0:
                batch = min(k, longest)
                held, count, at = _put(out, held, count, at, repeat_code[batch], repeat_bits[batch])
                k -= batch
            rest = left % LONGEST_MATCH
            if rest:
                held, count, at = _put(out, held, count, at, codes[rest], lengths[rest])
            a, b = _adler_run(a, b, n, colours[label, 0], colours[label, 1], colours[label, 2])
        if at < 0:
            return -1
    held, count, at = _put(out, held, count, at, codes[LITERAL + 256], lengths[LITERAL + 256])  # end of block
    tail = (count + 7) // 8  # the bits still held, the last byte padded with zeros
    if at < 0 or at + tail + 4 > out.shape[0]:
        return -1
    for k in range(tail):
        out[at + k] = np.uint8((held >> np.uint64(8 * k)) & np.uint64(0xFF))
    at += tail
    checksum = (b << 16) | a
    for k in range(4):
        out[at + k] = np.uint8((checksum >> (24 - 8 * k)) & 0xFF)
    return at + 4


def run_stream(planes: list, width: int, rows: np.ndarray, columns: np.ndarray, colours: np.ndarray, code,
               limit: int) -> bytes | None:
    """The zlib stream of the PNG scanlines of a Voxel Print slice (filter byte 0, then the colour (``colours``
    (labels, 3) uint8) of each sampled pixel's label: :func:`heoslice.export.voxel_print.labels_of`'s, of the
    packed ``planes`` (:class:`heoslice.stack.packed.Bits`, ``width`` px wide) at ``rows`` x ``columns``, both
    non-decreasing), coded by ``code`` (:func:`heoslice.deflate.run_code` of every colour byte and 0, distance 3);
    None when it would be longer than ``limit`` bytes (a layer of many short runs, left to a general encoder)."""
    if colours.ndim != 2 or colours.shape[1] != 3:
        raise ValueError(f"run_stream: colours of shape {colours.shape}, not (labels, 3)")
    if not 0 < len(planes) < colours.shape[0]:  # the kernel reads colours[label] unchecked
        raise ValueError(f"run_stream: {len(planes)} label planes for {colours.shape[0] - 1} colours of labels")
    first, stop = min(bits.span[0] for bits in planes), max(bits.span[1] for bits in planes)
    inside = (rows >= first) & (rows < stop)
    row_of = np.full(len(rows), -1, dtype=np.int64)
    row_of[inside] = np.arange(np.count_nonzero(inside))
    row_bytes = planes[0].rows.shape[1]
    words = np.empty((len(planes), np.count_nonzero(inside), -(-row_bytes // 8)), dtype=np.uint64)
    for plane, bits in zip(words.view(np.uint8), planes):
        np.take(bits.rows, rows[inside], axis=0, out=plane[:, :row_bytes])
        plane[:, row_bytes:] = 0
    words.byteswap(inplace=True)  # pixel 0 of each word its top bit, as in the packed bytes
    edges = i64(np.searchsorted(columns, np.arange(width + 1), side="left"))
    out = np.empty(limit, dtype=np.uint8)
    written = _run_stream(words, row_of, int(width), edges, i64(colours), code.codes, code.lengths, code.header,
                          int(code.header_bits), out)
    return None if written < 0 else out[:written].tobytes()
