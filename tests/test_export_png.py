"""heoslice.export.png: a 1-bit layer written from its packed bits is the same PNG file as from its pixels."""

from __future__ import annotations

import numpy as np

from heoslice.export.png import png_bytes
from heoslice.pngfile import bilevel_png


def test_png_from_packed_bits_is_the_png_from_pixels():
    """For masks of widths that leave padding bits (and padding bits set, as a decoder may leave them), the
    PNG made from packed rows is byte for byte the PNG made from the bool pixels."""
    rng = np.random.default_rng(46)
    for width, height in ((53, 37), (64, 5), (1, 9), (1001, 3)):
        mask = rng.random((height, width)) < 0.4
        mask[: height // 2] = False
        bits = np.packbits(mask, axis=1)
        if width % 8:
            bits[:, -1] |= np.uint8(0xFF >> (width % 8))  # padding bits are not pixels
        assert bilevel_png(bits, width, (600.0, 300.0)) == png_bytes(mask, (600.0, 300.0))
