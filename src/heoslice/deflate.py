"""heoslice's zlib encoders, for the layers' TIFF strips, every PNG and the printer's chunks: a zlib stream
(RFC 1950) at a given level, by zlib-ng (imagecodecs) where this build of imagecodecs has it, else by the standard
library's zlib; or, for the benchmarks' comparisons (``benchmarks/bench_encode.py``), by ISA-L's igzip (isal, in the
test extra), which no stack uses: faster on noise-like masks, but not reproducible byte for byte
(:data:`heoslice.stack.tiff.MASK_DEFLATION`). Any inflater reads every one; figures in benchmarks/README.md. And the codes of
one dynamic-Huffman block (RFC 1951) for data that is a few literals and many matches at one distance
(:func:`run_code`), with which Voxel Print's slices are written from their runs without an encoder.
"""

from __future__ import annotations

import functools
import heapq
import zlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: The encoders by name, each with its levels: zlib-ng's 0-9 (zlib's meaning), ISA-L's 0-3.
ENCODERS = {"zlib-ng": range(10), "isa-l": range(4)}


@functools.cache
def deflater(level: int, encoder: str = "zlib-ng") -> Callable[[bytes], bytes]:
    """bytes -> their zlib stream at ``level`` of ``encoder`` (:data:`ENCODERS`).

    zlib-ng falls back to zlib where imagecodecs lacks it: imagecodecs answers an import of a codec it was built
    without with a placeholder that fails only when called, so zlib-ng's availability is asked, never inferred
    from an import. ISA-L has no fallback (a silent change of encoder would change the bytes compared): it needs
    isal, which the test extra installs."""
    if level not in ENCODERS.get(encoder, ()):
        raise ValueError(f"deflate: no level {level} for encoder {encoder!r} (encoders: {', '.join(ENCODERS)})")
    if encoder == "isa-l":
        from isal import isal_zlib

        return functools.partial(isal_zlib.compress, level=level)
    try:
        import imagecodecs
    except ImportError:
        imagecodecs = None
    codec = getattr(imagecodecs, "ZLIBNG", None)
    if codec is not None and codec.available:
        return functools.partial(imagecodecs.zlibng_encode, level=level)
    return functools.partial(zlib.compress, level=level)


#: RFC 1951 3.2.5: the first length and the extra bits of each length code 257..285, and of each distance code 0..29.
LENGTH_BASES = (3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 15, 17, 19, 23, 27, 31, 35, 43, 51, 59, 67, 83, 99, 115, 131, 163,
                195, 227, 258)
LENGTH_EXTRA = (0,) * 8 + (1,) * 4 + (2,) * 4 + (3,) * 4 + (4,) * 4 + (5,) * 4 + (0,)
DISTANCE_BASES = (1, 2, 3, 4, 5, 7, 9, 13, 17, 25, 33, 49, 65, 97, 129, 193, 257, 385, 513, 769, 1025, 1537, 2049,
                  3073, 4097, 6145, 8193, 12289, 16385, 24577)
DISTANCE_EXTRA = (0, 0, 0, 0) + tuple(k // 2 for k in range(2, 28))
#: RFC 1951 3.2.7: the order in which a dynamic block gives its code length code's lengths.
CODE_LENGTH_ORDER = (16, 17, 18, 0, 8, 7, 9, 6, 10, 5, 11, 4, 12, 3, 13, 2, 14, 1, 15)
#: A zlib stream's first two bytes (RFC 1950): deflate with a 32 KB window, no dictionary, "fastest" level.
ZLIB_HEADER = b"\x78\x01"
#: The symbol weights a :class:`RunCode` is made for: matches of the longest length (most of a run's bytes),
#: then each literal, the other lengths and the end of the block.
RUN_WEIGHTS = {"longest": 256, "literal": 16, "length": 2, "end": 1}


@dataclass(frozen=True)
class RunCode:
    """A zlib stream's beginning and the codes of one dynamic-Huffman deflate block (RFC 1951 3.2.7) for data
    written as a few literals and many matches at one distance: ``header`` (its first ``header_bits`` bits,
    least significant first) is the zlib header and the block's header; ``codes`` / ``lengths`` (516,) uint64 /
    int64 the bits to write (least significant first) for a match of length L at the distance (slot L, 3..258,
    with its extra bits), literal byte b (slot 259 + b; length 0 for a literal without a code) and the end of the
    block (slot 515); none longer than 32 bits."""

    header: np.ndarray
    header_bits: int
    codes: np.ndarray
    lengths: np.ndarray


def huffman_lengths(weights: dict[int, int], limit: int) -> dict[int, int]:
    """Code lengths (at most ``limit`` bits) of a complete prefix code for the symbols of ``weights`` (symbol ->
    weight > 0, at least two symbols): Huffman's, the weights halved until its lengths fit the limit."""
    while True:
        heap = [(weight, symbol, (symbol,)) for symbol, weight in sorted(weights.items())]
        heapq.heapify(heap)
        depth = dict.fromkeys(weights, 0)
        while len(heap) > 1:
            w1, t1, s1 = heapq.heappop(heap)
            w2, t2, s2 = heapq.heappop(heap)
            for symbol in s1 + s2:
                depth[symbol] += 1
            heapq.heappush(heap, (w1 + w2, min(t1, t2), s1 + s2))
        if max(depth.values()) <= limit:
            return depth
        weights = {symbol: (weight + 1) // 2 for symbol, weight in weights.items()}


def canonical_codes(lengths: list[int]) -> list[int]:
    """The canonical Huffman code of each symbol of ``lengths`` (RFC 1951 3.2.2), bit-reversed to be written
    least significant bit first (0 for a length 0)."""
    counts = [0] * (max(lengths) + 2)
    for length in lengths:
        counts[length] += 1
    counts[0] = 0
    next_code, code = [0] * len(counts), 0
    for bits in range(1, len(counts)):
        code = (code + counts[bits - 1]) << 1
        next_code[bits] = code
    codes = []
    for length in lengths:
        value = 0
        if length:
            value, next_code[length] = next_code[length], next_code[length] + 1
        codes.append(int(f"{value:0{length}b}"[::-1], 2) if length else 0)
    return codes


def _code_of(value: int, bases: tuple[int, ...], extra: tuple[int, ...]) -> tuple[int, int, int]:
    """(code index, extra bits' value, their count) of a length or a distance (RFC 1951 3.2.5)."""
    index = max(k for k, base in enumerate(bases) if base <= value)
    return index, value - bases[index], extra[index]


@functools.cache
def run_code(literals: frozenset[int], distance: int) -> RunCode:
    """The :class:`RunCode` of a block whose literals are among ``literals`` (bytes), matches of every length at
    ``distance`` (1..32768) alone, weighted by :data:`RUN_WEIGHTS`."""
    weights = {256: RUN_WEIGHTS["end"], 285: RUN_WEIGHTS["longest"]}
    weights.update(dict.fromkeys(range(257, 285), RUN_WEIGHTS["length"]))
    weights.update(dict.fromkeys(sorted(literals), RUN_WEIGHTS["literal"]))
    found = huffman_lengths(weights, 15)
    literal_lengths = [found.get(symbol, 0) for symbol in range(286)]
    literal_codes = canonical_codes(literal_lengths)
    distance_code, distance_value, distance_bits = _code_of(distance, DISTANCE_BASES, DISTANCE_EXTRA)
    other = 1 if distance_code == 0 else 0  # a second code of 1 bit, never used, so the distance code is complete
    distance_lengths = [1 if k in (distance_code, other) else 0 for k in range(max(distance_code, other) + 1)]
    distance_codes = canonical_codes(distance_lengths)
    codes, lengths = np.zeros(516, dtype=np.uint64), np.zeros(516, dtype=np.int64)
    for length in range(3, 259):
        index, value, bits = _code_of(length, LENGTH_BASES, LENGTH_EXTRA)
        parts = [(literal_codes[257 + index], literal_lengths[257 + index]), (value, bits),
                 (distance_codes[distance_code], 1), (distance_value, distance_bits)]
        codes[length], lengths[length] = _joined(parts)
    for symbol in range(257):
        codes[259 + symbol], lengths[259 + symbol] = literal_codes[symbol], literal_lengths[symbol]
    if lengths.max() > 32:  # the coders append at most 32 bits at once
        raise ValueError(f"run_code: a match at distance {distance} takes {lengths.max()} bits, more than 32")
    header, header_bits = _joined([(byte, 8) for byte in ZLIB_HEADER] + _block_header(literal_lengths,
                                                                                      distance_lengths))
    return RunCode(np.frombuffer(header.to_bytes((header_bits + 7) // 8, "little"), dtype=np.uint8), header_bits,
                   codes, lengths)


def _joined(parts: list[tuple[int, int]]) -> tuple[int, int]:
    """Bit strings (value, count), each least significant bit first, as one: (value, total count)."""
    value, count = 0, 0
    for bits, length in parts:
        value |= bits << count
        count += length
    return value, count


def _block_header(literal_lengths: list[int], distance_lengths: list[int]) -> list[tuple[int, int]]:
    """The bits of a last, dynamic-Huffman block's header (RFC 1951 3.2.3, 3.2.7) for these code lengths:
    BFINAL, BTYPE, HLIT, HDIST, HCLEN, the code length code and the lengths coded by it (runs of zeros by
    symbols 17 and 18)."""
    sequence, lengths, at = [], literal_lengths + distance_lengths, 0
    while at < len(lengths):
        zeros = 0
        while at + zeros < len(lengths) and lengths[at + zeros] == 0 and zeros < 138:
            zeros += 1
        if zeros >= 11:
            sequence.append((18, zeros - 11, 7))
        elif zeros >= 3:
            sequence.append((17, zeros - 3, 3))
        else:
            sequence.append((lengths[at], 0, 0))
            zeros = 1
        at += zeros
    counts: dict[int, int] = {}
    for symbol, _, _ in sequence:
        counts[symbol] = counts.get(symbol, 0) + 1
    if len(counts) == 1:
        counts[next(k for k in range(19) if k not in counts)] = 1
    code_lengths = huffman_lengths(counts, 7)
    order = [code_lengths.get(symbol, 0) for symbol in CODE_LENGTH_ORDER]
    while len(order) > 4 and order[-1] == 0:
        order.pop()
    length_codes = canonical_codes([code_lengths.get(symbol, 0) for symbol in range(19)])
    bits = [(1, 1), (2, 2), (len(literal_lengths) - 257, 5), (len(distance_lengths) - 1, 5), (len(order) - 4, 4)]
    bits += [(length, 3) for length in order]
    for symbol, extra, extra_bits in sequence:
        bits += [(length_codes[symbol], code_lengths[symbol]), (extra, extra_bits)]
    return bits
