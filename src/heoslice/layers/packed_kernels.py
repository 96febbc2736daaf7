"""Compiled kernel over a layer image's packed rows seen as 64-bit words (numba source, compiled at install:
:mod:`heoslice.jit`): a layer's droplet masks folded together, their bits counted and checked against the solid
layer in one pass per file, for the checks that read a whole stack (:func:`heoslice.stack.packed.partition_counts`).
"""

from __future__ import annotations

import numpy as np

from heoslice.jit import EXACT, helper, kernel

#: :func:`fold_words` modes: the first mask starts the union, a later one joins it, the solid layer is compared.
START, JOIN, COMPARE = 0, 1, 2


@helper(EXACT)
def _popcount(word):
    """Set bits of a uint64 (the bit-parallel count, which LLVM turns into the processor's popcount)."""
    word = word - ((word >> np.uint64(1)) & np.uint64(0x5555555555555555))
    word = (word & np.uint64(0x3333333333333333)) + ((word >> np.uint64(2)) & np.uint64(0x3333333333333333))
    word = (word + (word >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return (word * np.uint64(0x0101010101010101)) >> np.uint64(56)


@kernel(EXACT)
def fold_words(union: np.ndarray, words: np.ndarray, first: int, stop: int, mode: int,
               out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Over words first..stop-1 of ``words`` (n,) uint64 (a file's packed rows): out[0] += its set bits, and
    out[1] set to 1 where a bit is wrong for ``mode``: START writes the words into ``union`` (n,) uint64;
    JOIN flags a bit already in ``union`` (a pixel in two masks) and adds the words to it; COMPARE (the solid
    layer) flags a word that differs from ``union`` (a solid pixel in no mask, or a mask pixel outside)."""
    count = np.uint64(0)  # unsigned, as the words: a signed sum would not vectorise
    wrong = np.uint64(0)
    seen, read = union[first:stop], words[first:stop]  # indices from 0 up: no negative-index test, so it vectorises
    if mode == 0:
        for w in range(read.shape[0]):
            word = read[w]
            seen[w] = word
            count += _popcount(word)
    elif mode == 1:
        for w in range(read.shape[0]):
            word = read[w]
            wrong |= seen[w] & word
            seen[w] |= word
            count += _popcount(word)
    else:
        for w in range(read.shape[0]):
            word = read[w]
            wrong |= seen[w] ^ word
            count += _popcount(word)
    out[0] += np.int64(count)
    if wrong:
        out[1] = 1
