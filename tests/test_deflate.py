"""The zlib encoders (heoslice.deflate): a stream any inflater reads, by zlib-ng where imagecodecs has it, and
by zlib where the build lacks it (imagecodecs then hands out a placeholder that fails only when called); by ISA-L
(isal, a dependency) for noise-like masks."""

from __future__ import annotations

import types
import zlib

import numpy as np
import pytest

from heoslice import deflate


@pytest.mark.parametrize(("level", "encoder"), [(1, "zlib-ng"), (2, "zlib-ng"), (6, "zlib-ng"), (0, "isa-l"),
                                               (2, "isa-l"), (3, "isa-l")])
def test_the_stream_inflates_to_its_bytes(level, encoder):
    data = np.random.default_rng(level).integers(0, 2, 100_000, dtype=np.uint8).tobytes() + bytes(50_000)
    assert zlib.decompress(deflate.deflater(level, encoder)(data)) == data


def test_isa_l_is_its_own_encoder():
    """ISA-L's stream is isal's (not zlib-ng's at the same level). A level the encoder lacks, or an unknown
    encoder, is refused."""
    from isal import isal_zlib

    data = np.packbits(np.random.default_rng(3).random((256, 800)) < 0.3, axis=1).tobytes()
    assert deflate.deflater(2, "isa-l")(data) == isal_zlib.compress(data, 2) != deflate.deflater(2)(data)
    for level, encoder in ((4, "isa-l"), (10, "zlib-ng"), (1, "brotli")):
        with pytest.raises(ValueError, match="no level"):
            deflate.deflater(level, encoder)


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
