"""The Voxel Print slice's image data written from runs (heoslice.export.voxel_print_kernels.run_stream): a zlib
stream that inflates (zlib, and Pillow through the PNG) to exactly the scanlines of the straightforward reference,
each sampled pixel the colour of the last label plane holding it; its Adler-32 summed per run in closed form."""

from __future__ import annotations

import io
import zlib

import imagecodecs
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from heoslice.deflate import run_code
from heoslice.export.voxel_print_kernels import _adler_run, run_stream
from heoslice.pngfile import deflated_png
from heoslice.stack.packed import Bits

#: Room enough for any stream of the tests' small slices.
ROOM = 1 << 20


def reference_scanlines(masks: np.ndarray, rows: np.ndarray, columns: np.ndarray, colours: np.ndarray) -> bytes:
    """The PNG scanlines written out literally: per sampled row a 0 filter byte, then per sampled column the
    colour of the pixel's label (0 empty, else the number of the last mask holding it)."""
    out = bytearray()
    for row in rows:
        out.append(0)
        for column in columns:
            label = 0
            for number, mask in enumerate(masks, 1):
                if mask[row, column]:
                    label = number
            out += bytes(colours[label])
    return bytes(out)


def planes_of(masks: np.ndarray) -> list[Bits]:
    """The packed planes of boolean masks (p, h, w), each with the span of rows holding its set pixels."""
    planes = []
    for mask in masks:
        filled = np.flatnonzero(mask.any(axis=1))
        span = (int(filled[0]), int(filled[-1]) + 1) if len(filled) else (0, 0)
        planes.append(Bits(np.packbits(mask, axis=1), span))
    return planes


def stream_of(masks, rows, columns, colours, limit=ROOM) -> bytes | None:
    """run_stream of the masks with the run code of the colours' bytes."""
    code = run_code(frozenset({0, *colours.ravel().tolist()}), 3)
    return run_stream(planes_of(masks), masks.shape[2], np.asarray(rows), np.asarray(columns), colours, code, limit)


@st.composite
def slices(draw):
    """Label planes made of random runs (widths not a multiple of 8 or 64, blank rows around them), with sampled
    rows and columns (non-decreasing, repeated, skipped, or all) and colours."""
    count = draw(st.integers(1, 3))
    height, width = draw(st.integers(1, 12)), draw(st.integers(1, 400))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    masks = np.zeros((count, height, width), dtype=bool)
    for mask in masks:
        for row in range(height):
            if rng.random() < 0.2:
                continue  # a row off this plane
            cuts = np.sort(rng.integers(0, width + 1, rng.integers(0, 9)))
            for start, stop in zip(cuts[::2], cuts[1::2]):
                mask[row, start:stop] = True
        if rng.random() < 0.2:
            mask[rng.random(height) < 0.5] = True  # whole rows: runs over whole words
    if draw(st.booleans()):
        rows = np.arange(height)
    else:
        rows = np.sort(rng.integers(0, height, draw(st.integers(1, 2 * height))))
    if draw(st.booleans()):
        columns = np.arange(width)
    else:
        columns = np.sort(rng.integers(0, width, draw(st.integers(1, 2 * width))))
    colours = rng.integers(0, 256, (count + 1, 3), dtype=np.uint8)
    return masks, rows, columns, colours


@settings(max_examples=300, deadline=None)
@given(slices())
def test_the_stream_inflates_to_the_reference_scanlines(case):
    """Random runs in 1 to 3 planes, any width, rows off the planes, sampled rows and columns: zlib inflates the
    stream to the reference scanlines byte for byte and finds its Adler-32 right; Pillow and libpng decode the PNG
    made of it to the same RGB pixels."""
    masks, rows, columns, colours = case
    data = stream_of(masks, rows, columns, colours)
    expected = reference_scanlines(masks, rows, columns, colours)
    assert zlib.decompress(data) == expected
    assert data[-4:] == zlib.adler32(expected).to_bytes(4, "big")
    png = deflated_png(data, len(columns), len(rows), 3, 8, (600.0, 300.0))
    image = Image.open(io.BytesIO(png))
    assert image.mode == "RGB"
    pixels = np.frombuffer(expected, dtype=np.uint8).reshape(len(rows), -1)[:, 1:].reshape(len(rows), -1, 3)
    assert np.array_equal(np.asarray(image), pixels)
    assert np.array_equal(imagecodecs.png_decode(png).reshape(pixels.shape), pixels)


@pytest.mark.parametrize("width", [63, 64, 65, 130, 200])
def test_one_pixel_at_every_column_of_each_plane_is_placed_exactly(width):
    """A single pixel of plane 1 or 2, or of both, at each column in turn (either side of the 64-pixel words'
    boundaries), on rows of plane 1 full or empty: the stream holds it at that column in that colour, so a run
    boundary or a label off by one fails."""
    colours = np.array([[0, 0, 0], [240, 240, 240], [0, 255, 0]], dtype=np.uint8)
    for column in range(width):
        masks = np.zeros((2, 4, width), dtype=bool)
        masks[0, 0, column] = True  # a pixel of plane 1 on an empty row
        masks[1, 1, column] = True  # a pixel of plane 2 on an empty row
        masks[0, 2] = True  # plane 2's pixel on a full row of plane 1
        masks[1, 2, column] = True
        masks[0, 3] = True  # a hole in a full row of plane 1
        masks[0, 3, column] = False
        rows, columns = np.arange(4), np.arange(width)
        got = np.frombuffer(zlib.decompress(stream_of(masks, rows, columns, colours)), dtype=np.uint8)
        got = got.reshape(4, -1)[:, 1:].reshape(4, width, 3)
        expected = np.zeros((4, width, 3), dtype=np.uint8)
        expected[0, column], expected[1, column] = colours[1], colours[2]
        expected[2], expected[3] = colours[1], colours[1]
        expected[2, column], expected[3, column] = colours[2], colours[0]
        assert np.array_equal(got, expected), column


def test_long_runs_take_the_longest_matches_and_their_remainder():
    """Rows of one colour 1 to 700 px wide (3 (n - 1) bytes after the first pixel: whole 258-byte matches and
    any remainder) inflate to exactly those rows; a row of one colour costs well under a byte per 100 px."""
    colours = np.array([[7, 8, 9], [200, 100, 50]], dtype=np.uint8)
    for width in (1, 2, 3, 86, 87, 88, 172, 173, 700):
        masks = np.zeros((1, 3, width), dtype=bool)
        masks[0, 1] = True
        data = stream_of(masks, np.arange(3), np.arange(width), colours)
        assert zlib.decompress(data) == reference_scanlines(masks, np.arange(3), np.arange(width), colours)
    assert len(data) < 100 + 3 * 700 // 100


def test_a_stream_longer_than_the_limit_is_none():
    """A stream that does not fit the limit is None (the caller deflates the scanlines instead), one that fits
    exactly is kept."""
    rng = np.random.default_rng(5)
    masks = rng.random((2, 20, 300)) < 0.5
    colours = np.array([[0, 0, 0], [1, 2, 3], [4, 5, 6]], dtype=np.uint8)
    data = stream_of(masks, np.arange(20), np.arange(300), colours)
    assert stream_of(masks, np.arange(20), np.arange(300), colours, limit=len(data)) == data
    assert stream_of(masks, np.arange(20), np.arange(300), colours, limit=len(data) - 1) is None
    assert stream_of(masks, np.arange(20), np.arange(300), colours, limit=10) is None


def test_colours_must_be_rgb():
    """The stream codes 3 bytes a pixel: colours of another shape are refused."""
    with pytest.raises(ValueError, match="colours"):
        stream_of(np.zeros((1, 2, 9), dtype=bool), [0, 1], np.arange(9), np.zeros((2, 4), dtype=np.uint8))


def test_a_plane_without_a_colour_is_refused():
    """Every label a plane gives needs a colour row (the kernel reads colours[label] unchecked): two planes with one
    colour besides the background's, or no plane, are refused before anything is coded."""
    colours = np.array([[0, 0, 0], [255, 0, 0]], dtype=np.uint8)
    with pytest.raises(ValueError, match="label planes"):
        stream_of(np.ones((2, 2, 9), dtype=bool), [0, 1], np.arange(9), colours)
    with pytest.raises(ValueError, match="label planes"):
        stream_of(np.ones((0, 2, 9), dtype=bool), [0, 1], np.arange(9), colours)
    assert stream_of(np.ones((1, 2, 9), dtype=bool), [0, 1], np.arange(9), colours) is not None


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 65520), st.integers(0, 65520), st.integers(1, 3000), st.tuples(*[st.integers(0, 255)] * 3))
def test_a_runs_adler_sums_are_zlibs(a, b, n, colour):
    """_adler_run's closed form after n pixels of one colour equals zlib.adler32 over those 3 n bytes, from any
    starting sums; n large enough for the sums to wrap."""
    start = (b << 16) | a
    expected = zlib.adler32(bytes(colour) * n, start)
    assert _adler_run(a, b, n, *colour) == (expected & 0xFFFF, expected >> 16)


def test_a_runs_adler_sums_hold_for_runs_longer_than_the_modulus():
    """Runs of 65,521 px and more (n and n (n - 1) / 2 past the modulus) still sum as zlib does."""
    for n in (65521, 65522, 200_003):
        expected = zlib.adler32(bytes((255, 254, 253)) * n, 12345 << 16 | 54321)
        assert _adler_run(54321, 12345, n, 255, 254, 253) == (expected & 0xFFFF, expected >> 16)
