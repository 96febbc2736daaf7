"""heoslice.pngfile: the PNGs it writes decode, with Pillow and with libpng (imagecodecs), to the pixels
and resolution of the PNG Pillow's own encoder writes of the same image (the export's encoder before)."""

from __future__ import annotations

import io
import struct
import zlib

import imagecodecs
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from heoslice import pngfile
from heoslice.pngfile import bilevel_png, image_png, labels_png, png_file

DPI = (600.0, 300.0)


def pillow_png(image: Image.Image) -> bytes:
    """The reference: Pillow's encoder, as the export wrote its PNGs before."""
    buffer = io.BytesIO()
    image.save(buffer, format="PNG", dpi=(round(DPI[0]), round(DPI[1])))
    return buffer.getvalue()


def decoded(data: bytes) -> tuple[str, np.ndarray, tuple]:
    """(Pillow's mode, its pixels, its dpi) of a PNG, after checking libpng decodes the same pixels."""
    image = Image.open(io.BytesIO(data))
    image.load()
    pixels = np.asarray(image)
    by_libpng = imagecodecs.png_decode(data)
    expected = pixels.astype(np.uint8) * 255 if image.mode == "1" else pixels
    assert np.array_equal(by_libpng.reshape(expected.shape), expected)
    return image.mode, pixels, image.info["dpi"]


def chunks(data: bytes) -> list[bytes]:
    """The chunk types of a PNG, each chunk's CRC-32 checked (the PNG specification's layout)."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    found, at = [], 8
    while at < len(data):
        (length,) = struct.unpack(">I", data[at:at + 4])
        kind, body = data[at + 4:at + 8], data[at + 8:at + 8 + length]
        (crc,) = struct.unpack(">I", data[at + 8 + length:at + 12 + length])
        assert crc == zlib.crc32(kind + body)
        found.append(kind)
        at += 12 + length
    return found


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 70), st.integers(1, 20), st.integers(0, 2**32 - 1))
def test_a_1_bit_png_shows_the_mask_as_pillows_does(width, height, seed):
    """Any mask (widths with and without padding bits): the 1-bit PNG from its packed bits decodes to
    Pillow's own 1-bit PNG of it (solid black on white), at the same dpi."""
    mask = np.random.default_rng(seed).random((height, width)) < 0.5
    ours = decoded(bilevel_png(np.packbits(mask, axis=1), width, DPI))
    reference = decoded(pillow_png(Image.fromarray(~mask)))
    assert ours[0] == reference[0] == "1"
    assert np.array_equal(ours[1], reference[1]) and np.array_equal(ours[1], ~mask)
    assert ours[2] == reference[2]


@pytest.mark.parametrize("samples", [3, 4])
def test_a_label_png_shows_each_label_in_its_colour_as_pillows_does(samples):
    """Labels through a palette of RGB (voxel-print) or RGBA (gcvf) colours: the PNG decodes to Pillow's own
    truecolour PNG of ``colours[labels]``, mode and dpi included."""
    rng = np.random.default_rng(samples)
    colours = rng.integers(0, 256, (7, samples)).astype(np.uint8)
    labels = rng.integers(0, 7, (41, 67)).astype(np.uint8)
    labels[:10] = 0
    ours = decoded(labels_png(labels, colours, DPI))
    reference = decoded(pillow_png(Image.fromarray(colours[labels], {3: "RGB", 4: "RGBA"}[samples])))
    assert ours[0] == reference[0] and ours[2] == reference[2]
    assert np.array_equal(ours[1], reference[1])


def test_long_image_data_is_split_into_idat_chunks_that_decode_as_one(monkeypatch):
    """Image data longer than one chunk holds goes into consecutive IDAT chunks (each CRC right), and the file
    decodes to the same pixels."""
    rng = np.random.default_rng(7)
    rows = rng.integers(0, 256, (30, 90)).astype(np.uint8)
    whole = png_file(rows, 30, 3, 8, DPI)
    monkeypatch.setattr(pngfile, "MAX_CHUNK", 100)
    split = png_file(rows, 30, 3, 8, DPI)
    assert chunks(whole) == [b"IHDR", b"pHYs", b"IDAT", b"IEND"]
    kinds = chunks(split)
    assert kinds[:2] == [b"IHDR", b"pHYs"] and kinds[-1] == b"IEND" and set(kinds[2:-1]) == {b"IDAT"}
    assert len(kinds) > 5
    assert np.array_equal(decoded(split)[1], rows.reshape(30, 30, 3))


def test_image_data_deflated_elsewhere_makes_the_same_file():
    """deflated_png of the zlib stream of the scanlines (filter byte 0 a row) is the file png_file writes of
    the same rows with the same stream: the same chunks and pixels; a colour type PNG lacks is refused."""
    rows = np.random.default_rng(8).integers(0, 256, (7, 33)).astype(np.uint8)
    scanlines = np.concatenate([np.zeros((7, 1), dtype=np.uint8), rows], axis=1)
    stream = pngfile.deflater(pngfile.DEFLATE_LEVEL)(scanlines.tobytes())
    assert pngfile.deflated_png(stream, 11, 7, 3, 8, DPI) == png_file(rows, 11, 3, 8, DPI)
    assert np.array_equal(decoded(pngfile.deflated_png(zlib.compress(scanlines.tobytes()), 11, 7, 3, 8, DPI))[1],
                          rows.reshape(7, 11, 3))
    with pytest.raises(ValueError, match="samples"):
        pngfile.deflated_png(stream, 11, 7, 2, 8, DPI)


def test_rows_that_do_not_fit_the_width_are_refused():
    """Scanlines of the wrong length for the width, samples and bit depth: ValueError, not a corrupt file."""
    with pytest.raises(ValueError, match="do not hold"):
        png_file(np.zeros((4, 5), dtype=np.uint8), 41, 1, 1, DPI)


@pytest.mark.parametrize("mode", ["L", "RGB", "RGBA", "P"])
def test_a_pil_image_becomes_a_png_of_its_pixels_with_its_text_and_no_resolution(mode):
    """image_png (the previews): grey, RGB and RGBA kept as they are, another mode as RGB; the text chunks
    read back by Pillow; no pHYs chunk (a preview has no print resolution)."""
    rng = np.random.default_rng(len(mode))
    image = Image.fromarray(rng.integers(0, 256, (23, 31, 3)).astype(np.uint8), "RGB").convert(mode)
    data = image_png(image, (("Software", "heoslice preview"),))
    decoded_image = Image.open(io.BytesIO(data))
    expected = image if mode != "P" else image.convert("RGB")
    assert decoded_image.mode == expected.mode and decoded_image.text == {"Software": "heoslice preview"}
    assert np.array_equal(np.asarray(decoded_image), np.asarray(expected))
    assert "dpi" not in decoded_image.info and b"pHYs" not in chunks(data)
    assert np.array_equal(imagecodecs.png_decode(data).reshape(np.asarray(expected).shape), np.asarray(expected))
