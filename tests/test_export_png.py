"""heoslice.export.png: a 1-bit layer written from its packed bits is the same PNG file as from its pixels."""

from __future__ import annotations

import numpy as np
import pytest

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


@pytest.mark.parametrize("option, value", [("--pitch", "0.05"), ("--dpi", "300"), ("--background", "10,10,10")])
def test_options_png_does_not_use_are_refused(tmp_path, run_cli, option, value):
    """--pitch, --dpi and --background with --format png (which writes the stack's own resolution and colours):
    one line naming the option, exit 2, nothing written, rather than ignored."""
    from heoslice import procedural

    procedural.box((6.0, 6.0, 2.0)).export(tmp_path / "box.ply")
    assert run_cli("slice", tmp_path / "box.ply", "--layer", "1", "--dpi", "50", "-o", tmp_path / "stack")[0] == 0
    code, out, err = run_cli("export", tmp_path / "stack", "--format", "png", option, value, "-o", tmp_path / "o.zip")
    assert code == 2 and err.count("\n") == 1 and f"{option}: --format png does not use it" in err, err
    assert not (tmp_path / "o.zip").exists()
