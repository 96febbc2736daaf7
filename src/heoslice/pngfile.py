"""heoslice's one PNG writer (exports and previews): scanlines to a PNG file (signature, IHDR, pHYs, tEXt,
IDAT, IEND), every row unfiltered and the image data deflated by zlib-ng (:func:`heoslice.deflate.deflater`), or
image data deflated by its caller (:func:`deflated_png`: Voxel Print's slices, written from their runs).

Why not Pillow's encoder: it chooses a filter per row by trying each, then deflates with zlib at level 6,
which costs far more than zlib-ng on the raw rows; imagecodecs' libpng encoder takes no 1-bit images.
A PNG file is a few chunks (the PNG specification, ISO/IEC 15948), so it is written here, and the tests
decode it with Pillow and libpng. Unfiltered rows suit heoslice's images: 1-bit masks (PNG never filters
below a byte per pixel to any gain) and a few flat colours. Figures in benchmarks/README.md.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from heoslice.deflate import deflater

SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: zlib level of the image data: level 2 finds the short repeats of a halftone's dither pattern that level 1
#: misses, for little more time (as :data:`heoslice.stack.tiff.MULTI_MATERIAL_DEFLATE_LEVEL` for the layers).
DEFLATE_LEVEL = 2
#: Samples per pixel -> PNG colour type: greyscale, RGB, RGBA.
COLOUR_TYPES = {1: 0, 3: 2, 4: 6}
#: Largest data of one chunk (the format allows 2**31 - 1 bytes); longer image data takes several IDAT chunks.
MAX_CHUNK = 1 << 30
METRES_PER_INCH = 0.0254


def _chunk(kind: bytes, data: bytes) -> bytes:
    """One PNG chunk: length, type, data, CRC-32 of type and data."""
    return b"".join([struct.pack(">I", len(data)), kind, data, struct.pack(">I", zlib.crc32(data, zlib.crc32(kind)))])


def png_file(rows: np.ndarray, width: int, samples: int, bit_depth: int, dpi: tuple[float, float] | None,
             text: tuple[tuple[str, str], ...] = ()) -> bytes:
    """PNG of the scanlines ``rows`` ((height, ceil(width * samples * bit_depth / 8)) uint8, top row first,
    samples interleaved, pixels most significant bit first below a byte): ``samples`` 1 (grey), 3 (RGB) or
    4 (RGBA) of ``bit_depth`` 1 or 8 bits; ``dpi`` (x, y) in a pHYs chunk as Pillow writes it (none when None);
    each (keyword, Latin-1 text) of ``text`` in a tEXt chunk before the image data."""
    height, stride = rows.shape
    scanlines = np.empty((height, stride + 1), dtype=np.uint8)
    scanlines[:, 0] = 0  # filter type None
    scanlines[:, 1:] = rows
    return scanlines_png(scanlines, width, samples, bit_depth, dpi, text)


def scanlines_png(scanlines: np.ndarray, width: int, samples: int, bit_depth: int, dpi: tuple[float, float] | None,
                  text: tuple[tuple[str, str], ...] = ()) -> bytes:
    """:func:`png_file` of rows already laid out as PNG scanlines: (height, 1 + the row's bytes) uint8, C order,
    each row's first byte its filter type (0) (a caller building large images there saves a copy)."""
    height, stride = scanlines.shape[0], scanlines.shape[1] - 1
    if stride != -(-width * samples * bit_depth // 8) or samples not in COLOUR_TYPES or bit_depth not in (1, 8):
        raise ValueError(f"scanlines_png: rows of {stride} bytes do not hold {width} px of {samples} x {bit_depth} "
                         "bits")
    return deflated_png(deflater(DEFLATE_LEVEL)(np.ascontiguousarray(scanlines)), width, height, samples, bit_depth,
                        dpi, text)


def deflated_png(data: bytes, width: int, height: int, samples: int, bit_depth: int,
                 dpi: tuple[float, float] | None, text: tuple[tuple[str, str], ...] = ()) -> bytes:
    """:func:`png_file` of image data already deflated: ``data`` the zlib stream (RFC 1950) of the PNG scanlines
    of a ``width`` x ``height`` image (each row a filter byte, then its pixels as :func:`png_file` lays them)."""
    if samples not in COLOUR_TYPES or bit_depth not in (1, 8):
        raise ValueError(f"deflated_png: no PNG of {samples} samples of {bit_depth} bits")
    header = struct.pack(">IIBBBBB", width, height, bit_depth, COLOUR_TYPES[samples], 0, 0, 0)
    extra = [] if dpi is None else [
        _chunk(b"pHYs", struct.pack(">IIB", *(int(value / METRES_PER_INCH + 0.5) for value in dpi), 1))]
    extra += [_chunk(b"tEXt", f"{keyword}\x00{value}".encode("latin-1")) for keyword, value in text]
    return b"".join([SIGNATURE, _chunk(b"IHDR", header), *extra,
                     *(_chunk(b"IDAT", data[at:at + MAX_CHUNK]) for at in range(0, len(data), MAX_CHUNK)),
                     _chunk(b"IEND", b"")])


def image_png(image, text: tuple[tuple[str, str], ...] = ()) -> bytes:
    """PNG of a PIL image (grey, RGB or RGBA as it is; any other mode as RGB), without a resolution."""
    samples = {"L": 1, "RGB": 3, "RGBA": 4}.get(image.mode)
    if samples is None:
        image, samples = image.convert("RGB"), 3
    width, height = image.size
    rows = np.frombuffer(image.tobytes(), dtype=np.uint8).reshape(height, width * samples)
    return png_file(rows, width, samples, 8, None, text)


def bilevel_png(bits: np.ndarray, width: int, dpi: tuple[float, float]) -> bytes:
    """1-bit PNG of packed rows ((h, ceil(width / 8)) uint8, a set bit solid) showing solid black on white (as
    the layer TIFFs display); the padding bits of each row's last byte are not read."""
    scanlines = np.empty((bits.shape[0], bits.shape[1] + 1), dtype=np.uint8)
    scanlines[:, 0] = 0  # filter type None
    np.invert(bits, out=scanlines[:, 1:])
    if width % 8:
        scanlines[:, -1] &= np.uint8((0xFF << (8 - width % 8)) & 0xFF)
    return scanlines_png(scanlines, width, 1, 1, dpi)


def labels_png(labels: np.ndarray, colours: np.ndarray, dpi: tuple[float, float]) -> bytes:
    """Truecolour PNG of a label image ((h, w) uint8) with label k in colour ``colours[k]`` ((n, 3) RGB or
    (n, 4) RGBA uint8): the labels mapped through a palette by Pillow, the rows written by :func:`png_file`."""
    from PIL import Image

    height, width = labels.shape
    samples = colours.shape[1]
    mode = {3: "RGB", 4: "RGBA"}[samples]
    image = Image.frombuffer("P", (width, height), np.ascontiguousarray(labels), "raw", "P", 0, 1)
    image.putpalette(np.ascontiguousarray(colours, dtype=np.uint8).tobytes(), mode)
    rows = np.frombuffer(image.convert(mode).tobytes(), dtype=np.uint8).reshape(height, width * samples)
    return png_file(rows, width, samples, 8, dpi)
