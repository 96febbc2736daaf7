"""The zlib encoders (heoslice.deflate): a stream any inflater reads, by zlib-ng where imagecodecs has it, and
by zlib where the build lacks it (imagecodecs then hands out a placeholder that fails only when called); by ISA-L
(isal, the test extra) for the benchmarks' comparisons; the codes of a block of runs (run_code) by RFC 1951's rules."""

from __future__ import annotations

import itertools
import types
import zlib
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

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


@settings(max_examples=200, deadline=None)
@given(st.dictionaries(st.integers(0, 285), st.integers(1, 10**6), min_size=2, max_size=60), st.integers(7, 15))
def test_huffman_lengths_make_a_complete_code_within_the_limit(weights, limit):
    """huffman_lengths gives every symbol a length of at most ``limit`` bits whose Kraft sum is exactly 1 (a
    complete prefix code, as zlib's inflater requires of a dynamic block), a heavier symbol never longer."""
    lengths = deflate.huffman_lengths(weights, limit)
    assert set(lengths) == set(weights) and max(lengths.values()) <= limit
    assert sum(Fraction(1, 2 ** length) for length in lengths.values()) == 1
    if max(weights.values()) < 2**limit // len(weights):  # weights never halved: Huffman's own code
        for s, t in itertools.combinations(weights, 2):
            assert weights[s] <= weights[t] or lengths[s] <= lengths[t]


def test_canonical_codes_are_rfc_1951s_example():
    """RFC 1951 3.2.2's example: lengths (3, 3, 3, 3, 3, 2, 4, 4) give codes 010, 011, 100, 101, 110, 00, 1110,
    1111 (written here bit-reversed, least significant bit first)."""
    codes = deflate.canonical_codes([3, 3, 3, 3, 3, 2, 4, 4])
    expected = ["010", "011", "100", "101", "110", "00", "1110", "1111"]
    assert codes == [int(code[::-1], 2) for code in expected]


@pytest.mark.parametrize("distance", [1, 3, 4, 300, 32768])
def test_a_run_code_stream_of_literals_and_matches_inflates(distance):
    """A stream written with run_code's header and codes (random literals from its set, then matches of every
    length at its distance, the end of the block) inflates with zlib to the bytes they stand for."""
    rng = np.random.default_rng(distance)
    literals = frozenset(rng.integers(0, 256, 5).tolist())
    code = deflate.run_code(literals, distance)
    value, count, data = int.from_bytes(code.header.tobytes(), "little"), code.header_bits, bytearray()

    def put(bits, length):
        nonlocal value, count
        value |= int(bits) << count
        count += int(length)

    value &= (1 << count) - 1
    for _ in range(distance):
        byte = int(rng.choice(sorted(literals)))
        put(code.codes[259 + byte], code.lengths[259 + byte])
        data.append(byte)
    for length in list(range(3, 259)) + rng.integers(3, 259, 50).tolist():
        put(code.codes[length], code.lengths[length])
        for _ in range(length):
            data.append(data[-distance])
    put(code.codes[259 + 256], code.lengths[259 + 256])
    stream = value.to_bytes((count + 7) // 8, "little") + zlib.adler32(bytes(data)).to_bytes(4, "big")
    assert zlib.decompress(stream) == bytes(data)
    assert all(code.lengths[259 + byte] == 0 for byte in range(256) if byte not in literals)
