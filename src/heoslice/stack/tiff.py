"""Layer TIFFs: encoding (1-bit, grey, RGBA; strips compressed straight from packed bits) and the
defensive decoding that checks a file's layout against the manifest before any pixel is decoded."""

from __future__ import annotations

import functools
import io
import logging
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from heoslice import __version__
from heoslice.deflate import deflater
from heoslice.errors import VerifyError
from heoslice.stack.manifest import IMAGE_MODES

#: Compression name -> tifffile argument. Default chosen by measurement (see README).
COMPRESSIONS = {"deflate": "adobe_deflate", "packbits": "packbits", "lzw": "lzw", "none": None}
DEFAULT_COMPRESSION = "deflate"
MM_PER_INCH = 25.4
#: TIFF compression codes a layer may use: none, LZW, deflate (Adobe and old code), PackBits.
TIFF_COMPRESSIONS = (1, 5, 8, 32946, 32773)
#: zlib level of a multi-material stack's solid layers, and of its droplet masks where :data:`MASK_DEFLATION`
#: says so: ordered dither's patterns repeat at a short distance, which level 1's matcher misses and level 2's
#: finds, and the solid layers shrink too, for a small part of a graded layer's cost (sizes and times in
#: benchmarks/README.md).
MULTI_MATERIAL_DEFLATE_LEVEL = 2
#: zlib level of a one-material stack's layers: its fastest.
ONE_MATERIAL_DEFLATE_LEVEL = 1


class Deflation(NamedTuple):
    """How a 1-bit file's strips are deflated: the encoder (:data:`heoslice.deflate.ENCODERS`) and its level."""

    encoder: str
    level: int


#: How a multi-material stack's droplet masks are deflated, by the halftoning method that made them (None: none did,
#: each pixel is one part's or label's material): zlib-ng at level 2 for every method. ISA-L's level 2 deflates
#: noise-like masks (blue noise, error diffusion) in 0.4x zlib-ng's time at the same size, but it is not
#: reproducible: inside a slice it once wrote a strip whose bytes differ from what it writes for the same bits
#: anywhere else (the same pixels, one byte shorter; 1 slice in 111 of a graded organ), so a stack's files and
#: hashes would differ between two slices of one model. Figures in benchmarks/README.md.
MASK_DEFLATION = {method: Deflation("zlib-ng", MULTI_MATERIAL_DEFLATE_LEVEL)
                  for method in (None, "ordered", "blue-noise", "error-diffusion")}


def deflate_level(multi_material: bool) -> int:
    """The zlib-ng level of a stack's 1-bit solid layers, with droplet masks (``multi_material``) or without."""
    return MULTI_MATERIAL_DEFLATE_LEVEL if multi_material else ONE_MATERIAL_DEFLATE_LEVEL


def mask_deflation(halftone: str | None) -> Deflation:
    """How a stack's droplet masks made by the halftoning method ``halftone`` (None: not halftoned) are deflated,
    :data:`MASK_DEFLATION`."""
    return MASK_DEFLATION[halftone]


def calibration(dpi: tuple[float, float], spacing_mm: float | None) -> dict:
    """tifffile options that calibrate a layer in millimetres for Fiji/ImageJ, napari and tifffile: resolution
    in pixels per mm (ResolutionUnit none, as ImageJ writes it) and an ImageJ description with unit=mm and
    the layer height as Z spacing."""
    description = "ImageJ=1.11a\nunit=mm\n" + (f"spacing={float(spacing_mm)!r}\n" if spacing_mm else "")
    return {"resolution": (float(dpi[0]) / MM_PER_INCH, float(dpi[1]) / MM_PER_INCH), "resolutionunit": "NONE",
            "description": description, "metadata": None}


def encode_tiff(image: np.ndarray, dpi: tuple[float, float], compression: str,
                spacing_mm: float | None = None) -> bytes:
    """TIFF bytes of one layer image: bool (h, w) as 1-bit, uint8 (h, w) grey, or (h, w, 4) RGBA.

    Calibrated in mm (:func:`calibration`), so viewers show true size and the stack's Z spacing;
    1-bit and grey layers are min-is-white, so solid shows dark on white as in ``preview``.
    """
    import tifffile

    options: dict = {
        **calibration(dpi, spacing_mm),
        "rowsperstrip": 64,
        "compression": COMPRESSIONS[compression],
        "software": f"heoslice {__version__}",
    }
    if compression == "deflate":
        options["compressionargs"] = {"level": 1}
    if image.ndim == 3:
        options.update(photometric="rgb", extrasamples=["unassalpha"])
    else:
        options["photometric"] = "miniswhite"
    buffer = io.BytesIO()
    tifffile.imwrite(buffer, image, **options)
    return buffer.getvalue()


def _strip_codec(compression: str, level: int = 1, encoder: str = "zlib-ng"):
    """bytes -> compressed bytes for one TIFF strip.

    Deflate is :func:`heoslice.deflate.deflater` at ``level`` (1 unless told) of ``encoder`` (zlib-ng unless
    told), a zlib stream whichever encodes it. Other codecs are tifffile's own.
    """
    import tifffile

    if compression == "deflate":
        return deflater(level, encoder)
    return tifffile.TIFF.COMPRESSORS[tifffile.COMPRESSION[COMPRESSIONS[compression].upper()].value]


@functools.lru_cache(maxsize=32)
def _blank_strip(compression: str, level: int, size: int, encoder: str = "zlib-ng") -> bytes:
    """A strip of ``size`` zero bytes, compressed once: the same bytes every time, for the strips of rows off
    the part (a cross-section spans fewer rows than the image)."""
    return _strip_codec(compression, level, encoder)(bytes(size))


class BilevelForm(NamedTuple):
    """What a 1-bit layer's TIFF layout depends on: size (px), dpi, Z spacing (mm or None), codec, strip rows."""

    height: int
    width: int
    dpi: tuple[float, float]
    compression: str
    spacing_mm: float | None
    rows_per_strip: int


@dataclass(frozen=True, slots=True)
class BilevelLayout:
    """Where tifffile puts a 1-bit layer's strips, for one :class:`BilevelForm`: its header and tags
    (``head``, the bytes up to the first strip) and the file offsets of the StripOffsets and
    StripByteCounts values (uint32 each, little-endian). Strips follow one another to the end of the
    file, so a layer of this form is ``head`` with the two tables patched, then its strips: the bytes
    tifffile writes, without its per-file cost."""

    head: bytes
    offsets_at: int
    counts_at: int


def encode_bilevel_tiff(packed: np.ndarray, width: int, dpi: tuple[float, float], compression: str,
                        spacing_mm: float | None = None, rows_per_strip: int = 256,
                        level: int = ONE_MATERIAL_DEFLATE_LEVEL, rows: tuple[int, int] | None = None,
                        encoder: str = "zlib-ng") -> bytes:
    """TIFF bytes of a 1-bit layer given as packed rows ((h, ceil(width / 8)) uint8, MSB first).

    ``level`` and ``encoder`` are deflate's (:func:`deflate_level` and :func:`mask_deflation` say which a stack
    uses; other codecs ignore them). ``rows`` (first, stop): the only rows that may hold set bits, when the caller knows
    (:func:`heoslice.layers.rasterising.part_rows`); a strip wholly outside them is taken as blank.

    The strips are compressed here, straight from the packed bits (the mask is never expanded to
    one byte per pixel), and laid out as tifffile lays them out for this form
    (:func:`bilevel_layout`, asked once per form): the same bytes as tifffile's own file.
    Strips of 256 rows (~120 KB of bits at 3800 px) are cheaper to write than 64 (figures in
    benchmarks/README.md); the blank strips off ``rows`` are compressed once per size (:func:`_blank_strip`).
    """
    height = packed.shape[0]
    form = BilevelForm(height, width, (float(dpi[0]), float(dpi[1])), compression, spacing_mm, rows_per_strip)
    if COMPRESSIONS[compression] is None:
        return _tifffile_bilevel(packed, form, None)
    codec = _strip_codec(compression, level, encoder)
    first, stop = (0, height) if rows is None else rows
    packed = np.ascontiguousarray(packed)  # each strip's rows are then one run of bytes, compressed where they are
    strips = [codec(memoryview(packed[row:row + rows_per_strip]).cast("B"))
              if first < row + rows_per_strip and row < stop
              else _blank_strip(compression, level, packed[row:row + rows_per_strip].nbytes, encoder)
              for row in range(0, height, rows_per_strip)]
    layout = bilevel_layout(form)
    if layout is None:
        return _tifffile_bilevel(packed, form, strips)
    counts = np.array([len(strip) for strip in strips], dtype="<u4")
    if counts.sum(dtype=np.int64) + len(layout.head) >= 1 << 32:
        return _tifffile_bilevel(packed, form, strips)
    offsets = (len(layout.head) + np.cumsum(counts) - counts).astype("<u4")
    head = bytearray(layout.head)
    head[layout.offsets_at:layout.offsets_at + 4 * len(strips)] = offsets.tobytes()
    head[layout.counts_at:layout.counts_at + 4 * len(strips)] = counts.tobytes()
    return b"".join([head, *strips])


@functools.lru_cache(maxsize=16)
def bilevel_layout(form: BilevelForm) -> BilevelLayout | None:
    """The :class:`BilevelLayout` tifffile gives a 1-bit layer of ``form`` (as
    :func:`encode_bilevel_tiff` builds it), read from a file it writes with placeholder strips of
    distinct lengths; None when its layout is not the one described there (tifffile changed)."""
    import tifffile

    strips = -(-form.height // form.rows_per_strip)
    sample = [bytes([number % 251]) * (3 + 2 * number) for number in range(strips)]
    data = _tifffile_bilevel(None, form, sample)
    with tifffile.TiffFile(io.BytesIO(data)) as tiff:
        page = tiff.pages.first
        tags = page.tags
        offsets, counts = list(page.dataoffsets), list(page.databytecounts)
        offsets_tag, counts_tag = tags.get(273), tags.get(279)
        if tiff.byteorder != "<" or tiff.is_bigtiff or offsets_tag is None or counts_tag is None:
            return None
        if offsets_tag.dtype != 4 or counts_tag.dtype != 4:
            return None
        positions = (offsets_tag.valueoffset, counts_tag.valueoffset)
    first = offsets[0]
    expected = list(first + np.cumsum([0] + [len(s) for s in sample[:-1]]))
    if counts != [len(s) for s in sample] or offsets != expected or first + sum(counts) != len(data):
        return None
    if b"".join(sample) != data[first:]:
        return None
    return BilevelLayout(data[:first], positions[0], positions[1])


def _tifffile_bilevel(packed: np.ndarray | None, form: BilevelForm, strips: list[bytes] | None) -> bytes:
    """tifffile's own file of a 1-bit layer of ``form``: from encoded ``strips``, or (no compression)
    from the ``packed`` bits expanded."""
    import tifffile

    height, width, dpi, compression, spacing_mm, rows_per_strip = form
    options: dict = {
        **calibration(dpi, spacing_mm),
        "photometric": "miniswhite",
        "rowsperstrip": rows_per_strip,
        "software": f"heoslice {__version__}",
    }
    buffer = io.BytesIO()
    if strips is None:
        mask = np.unpackbits(packed, axis=1, count=width).astype(bool)
        tifffile.imwrite(buffer, mask, **options)
    else:
        tifffile.imwrite(buffer, data=iter(strips), shape=(height, width), dtype=bool,
                         compression=COMPRESSIONS[compression], **options)
    return buffer.getvalue()


def quiet_tifffile() -> None:
    """tifffile logs warnings about odd files to stderr; heoslice reports problems itself, one line each."""
    logging.getLogger("tifffile").setLevel(logging.CRITICAL)


def checked_page(tiff, name: str, file_size: int, manifest: dict, mode: str | None):
    """The single page of a layer TIFF after checking its layout against the manifest, before any decoding.

    Refused: several pages, tiles, unknown compression or sample layout, a size or
    resolution other than the manifest's, a strip count that does not fit the image,
    a strip claiming more bytes than any encoding of its pixels can need
    (decompression bombs) or lying past the end of the file.
    """
    try:
        return _checked_page_unsafe(tiff, name, file_size, manifest, mode)
    except VerifyError:
        raise
    except Exception as err:  # tifffile raises many types on malformed tags
        raise VerifyError(f"{name}: malformed TIFF ({' '.join(str(err).split())[:120]})") from err


def _checked_page_unsafe(tiff, name: str, file_size: int, manifest: dict, mode: str | None):
    width, height, dpi = manifest["image"]["width"], manifest["image"]["height"], manifest["dpi"]
    try:
        page = tiff.pages.first
    except IndexError:
        raise VerifyError(f"{name}: TIFF has no image") from None
    if tiff.pages.is_multipage:
        raise VerifyError(f"{name}: TIFF has more than one page")
    if (page.imagewidth, page.imagelength) != (width, height):
        raise VerifyError(f"{name}: is {page.imagewidth} x {page.imagelength} pixels, manifest says {width} x {height}")
    if page.is_tiled or page.planarconfig != 1 or int(page.compression) not in TIFF_COMPRESSIONS:
        raise VerifyError(f"{name}: TIFF layout not written by heoslice (tiles, planar or compression "
                          f"{int(page.compression)})")
    layout = (page.bitspersample, page.samplesperpixel)
    if layout not in ((1, 1), (8, 1), (8, 3), (8, 4)):
        raise VerifyError(f"{name}: {page.bitspersample}-bit x {page.samplesperpixel} samples is not a layer format")
    if mode is not None and layout != IMAGE_MODES[mode]:
        raise VerifyError(f"{name}: pixels are {page.bitspersample}-bit x {page.samplesperpixel}, "
                          f"manifest says mode {mode!r}")
    rows = min(int(page.rowsperstrip or height), height)
    strips = -(-height // rows)
    raw = rows * -(-width * page.samplesperpixel * page.bitspersample // 8)
    offsets, counts = page.dataoffsets, page.databytecounts
    if len(offsets) != strips or len(counts) != strips:
        raise VerifyError(f"{name}: has {len(offsets)} strips, its size needs {strips}")
    for number, (offset, count) in enumerate(zip(offsets, counts)):
        if count > 2 * raw + 1024:
            raise VerifyError(f"{name}: strip {number} claims {count} bytes, more than any encoding of its "
                              f"{raw} bytes of pixels needs (refused before decoding)")
        if count == 0 or offset < 8 or offset + count > file_size:
            raise VerifyError(f"{name}: strip {number} lies outside the file or is empty")
    tags = page.tags
    if "XResolution" not in tags or "YResolution" not in tags:
        raise VerifyError(f"{name}: has no resolution tags")
    xres, yres = tags["XResolution"].value, tags["YResolution"].value
    try:
        found = (xres[0] / xres[1], yres[0] / yres[1])
    except (TypeError, IndexError, ZeroDivisionError):
        raise VerifyError(f"{name}: malformed resolution tags") from None
    unit = int(tags["ResolutionUnit"].value) if "ResolutionUnit" in tags else 2
    per_inch = {1: MM_PER_INCH, 2: 1.0, 3: 2.54}.get(unit)  # none (px/mm, as heoslice writes), inch, cm
    if per_inch is None or not all(abs(value * per_inch - wanted) <= 1e-8 + 1e-6 * abs(wanted)  # np.allclose's rule
                                   for value, wanted in zip(found, dpi)):
        shown = (f"{found[0] * per_inch:g} x {found[1] * per_inch:g} dpi" if per_inch is not None
                 else f"{found[0]:g} x {found[1]:g} per unit {unit}")
        raise VerifyError(f"{name}: resolution {shown}, manifest says {dpi[0]:g} x {dpi[1]:g} dpi")
    return page


def decode_solid(page, name: str, alpha: bool, out: np.ndarray | None = None) -> int:
    """Count solid pixels strip by strip (memory: one strip); fill ``out`` ((h, w) bool) when given."""
    total = 0
    try:
        for segment, index, shape in page.segments(maxworkers=1):
            if segment is None:
                raise VerifyError(f"{name}: a strip is missing")
            pixels = segment.reshape(shape[1], shape[2], shape[3])
            solid = pixels[:, :, 3] > 0 if alpha and shape[3] == 4 else np.any(pixels != 0, axis=2)
            total += int(np.count_nonzero(solid))
            if out is not None:
                out[index[2]:index[2] + shape[1], index[3]:index[3] + shape[2]] = solid
    except VerifyError:
        raise
    except Exception as err:  # imagecodecs and tifffile raise many types on corrupt strips
        raise VerifyError(f"{name}: cannot decode ({' '.join(str(err).split())[:120]})") from err
    return total


def open_tiff(source, name: str):
    import tifffile

    quiet_tifffile()
    try:
        return tifffile.TiffFile(source)
    except Exception as err:  # tifffile raises many types on corrupt files
        raise VerifyError(f"{name}: not a readable TIFF ({' '.join(str(err).split())[:120]})") from err


def file_limit(page) -> int:
    """Most bytes a layer file with this page's layout can need: every strip at its bound, plus 1 MiB of tags."""
    raw = page.imagelength * -(-page.imagewidth * page.samplesperpixel * page.bitspersample // 8)
    return 2 * raw + 1024 * len(page.dataoffsets) + (1 << 20)


