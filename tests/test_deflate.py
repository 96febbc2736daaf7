"""The one zlib encoder (heoslice.deflate): a stream any inflater reads, by zlib-ng where imagecodecs has it, and
by zlib where the build lacks it: imagecodecs then hands out a placeholder that fails only when called."""

from __future__ import annotations

import types
import zlib

import numpy as np
import pytest

from heoslice import deflate


@pytest.mark.parametrize("level", [1, 2, 6])
def test_the_stream_inflates_to_its_bytes(level):
    data = np.random.default_rng(level).integers(0, 2, 100_000, dtype=np.uint8).tobytes() + bytes(50_000)
    assert zlib.decompress(deflate.deflater(level)(data)) == data


def test_a_build_without_zlib_ng_falls_back_to_zlib(monkeypatch):
    """A placeholder codec (ZLIBNG.available False, zlibng_encode raising when called) is never used: the PNG
    writer, the layers' strips and the printer's chunks all deflate with zlib, byte for byte zlib's stream."""
    import imagecodecs

    def placeholder(*args, **kwargs):
        raise RuntimeError("could not import name 'zlibng_encode'")

    monkeypatch.setattr(imagecodecs, "ZLIBNG", types.SimpleNamespace(available=False), raising=False)
    monkeypatch.setattr(imagecodecs, "zlibng_encode", placeholder, raising=False)
    deflate.deflater.cache_clear()
    try:
        data = bytes(range(256)) * 64
        assert deflate.deflater(2)(data) == zlib.compress(data, 2)
        from heoslice.pngfile import png_file
        from heoslice.printing.protocol import deflate as chunk_deflate
        from heoslice.stack.tiff import _strip_codec

        assert zlib.decompress(chunk_deflate(data)) == data
        assert zlib.decompress(_strip_codec("deflate", 1)(data)) == data
        rows = np.zeros((4, 2), dtype=np.uint8)
        assert png_file(rows, 16, 1, 1, None).startswith(b"\x89PNG")
    finally:
        deflate.deflater.cache_clear()
