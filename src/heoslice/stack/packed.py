"""Layer files read as packed bits: each file read, hashed and parsed once, its strips inflated straight to
packed rows (a 1-bit layer is never expanded to a byte per pixel), so that checks and outputs over a whole
stack run at disk and decode speed. The layout checks are :func:`heoslice.stack.tiff.checked_page`'s, made
before any strip is inflated; what is decoded is exactly what was hashed.

Packed rows are (height, ceil(width / 8)) uint8, most significant bit first, a set bit a solid pixel (the
value tifffile reads from a min-is-white 1-bit file), the padding bits of each row's last byte zero.
"""

from __future__ import annotations

import functools
import hashlib
import io
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from heoslice.errors import VerifyError
from heoslice.stack.read import read_checked, read_small_regular, resolve_inside
from heoslice.stack.tiff import checked_page, decode_solid, file_limit, open_tiff

#: TIFF compression code -> imagecodecs decoder names, the first it has taken, for the strips of 1-bit layers
#: (1: stored as is). zlib-ng inflates a layer's strips several times faster than zlib (benchmarks/README.md).
STRIP_DECODERS = {5: ("lzw_decode",), 8: ("zlibng_decode", "zlib_decode"), 32946: ("zlibng_decode", "zlib_decode"),
                  32773: ("packbits_decode",)}


@dataclass(frozen=True, slots=True)
class StripPage:
    """What reading a plain 1-bit layer needs of its TIFF page (the attributes of tifffile's TiffPage of the
    same names), for a file whose layout matched one tifffile parsed and checked before (:class:`_Layout`)."""

    imagelength: int
    imagewidth: int
    rowsperstrip: int
    bitspersample: int
    samplesperpixel: int
    fillorder: int
    predictor: int
    compression: int
    dataoffsets: tuple[int, ...]
    databytecounts: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class LayerFile:
    """One checked layer file: its bytes (as hashed) and its page (tifffile's, or a :class:`StripPage` of the
    same layout), checked against ``manifest`` for ``mode``."""

    name: str
    data: bytes
    page: object
    manifest: dict
    mode: str | None

    def tiff_page(self):
        """tifffile's page of the file, parsed and checked from its bytes."""
        if not isinstance(self.page, StripPage):
            return self.page
        return checked_page(open_tiff(io.BytesIO(self.data), self.name), self.name, len(self.data), self.manifest,
                            self.mode)


@dataclass(frozen=True, slots=True)
class _Layout:
    """The layout of a plain 1-bit layer file that tifffile parsed and :func:`checked_page` passed: its bytes
    before the first strip (``head``, holding the header, the one IFD and every tag value) with the
    StripOffsets and StripByteCounts tables (uint32 little-endian, ``strips`` each, at ``offsets_at`` and
    ``counts_at``) zeroed. Another file with the same head but for those tables is the same page with other
    strips: its tables are read here and checked by the same rules, and tifffile is not asked again."""

    head: bytes
    offsets_at: int
    counts_at: int
    page: StripPage


#: Layouts learned in this process, by what :func:`checked_page` checked them against (mode, width, height, dpi).
_LAYOUTS: dict[tuple, _Layout] = {}


def _learn_layout(page, data: bytes) -> _Layout | None:
    """The :class:`_Layout` of a checked tifffile page of ``data``, or None when it is not a plain little-endian
    1-bit page whose header, IFD and tag values all lie before its first strip."""
    if (page.bitspersample, page.samplesperpixel, page.fillorder, page.predictor) != (1, 1, 1, 1):
        return None
    tiff = page.parent
    offsets_tag, counts_tag = page.tags.get(273), page.tags.get(279)
    if tiff.byteorder != "<" or tiff.is_bigtiff or offsets_tag is None or counts_tag is None:
        return None
    if offsets_tag.dtype != 4 or counts_tag.dtype != 4 or offsets_tag.count != counts_tag.count:
        return None
    strips = offsets_tag.count
    head = min(page.dataoffsets)
    ifd_end = page.offset + 2 + 12 * len(page.tags) + 4
    if ifd_end > head or any(tag.valueoffset + tag.valuebytecount > head for tag in page.tags.values()):
        return None
    masked = bytearray(data[:head])
    for at in (offsets_tag.valueoffset, counts_tag.valueoffset):
        masked[at:at + 4 * strips] = bytes(4 * strips)
    fields = StripPage(page.imagelength, page.imagewidth, _strip_rows(page), 1, 1, 1, 1, int(page.compression),
                       (), ())
    return _Layout(bytes(masked), offsets_tag.valueoffset, counts_tag.valueoffset, fields)


def _known_page(data: bytes, layout: _Layout) -> StripPage | None:
    """The page of ``data`` when its head is ``layout``'s and its strip tables pass :func:`checked_page`'s
    rules (each strip non-empty, within the file, at most what its pixels can need); None otherwise."""
    head, page = layout.head, layout.page
    strips = -(-page.imagelength // page.rowsperstrip)
    if len(data) < len(head):
        return None
    masked = bytearray(data[:len(head)])
    table = f"<{strips}I"  # a dozen strips: Python's ints beat numpy's per-call cost here
    offsets = struct.unpack_from(table, masked, layout.offsets_at)
    counts = struct.unpack_from(table, masked, layout.counts_at)
    for at in (layout.offsets_at, layout.counts_at):
        masked[at:at + 4 * strips] = bytes(4 * strips)
    if masked != head:
        return None
    most, size = 2 * page.rowsperstrip * row_bytes(page.imagewidth) + 1024, len(data)
    if any(not 0 < count <= most or offset < 8 or offset + count > size for offset, count in zip(offsets, counts)):
        return None
    page = StripPage(page.imagelength, page.imagewidth, page.rowsperstrip, page.bitspersample, page.samplesperpixel,
                     page.fillorder, page.predictor, page.compression, offsets, counts)
    if len(data) > file_limit(page):
        return None
    return page


def _checked(data: bytes, name: str, manifest: dict, mode: str | None):
    """The checked page of a layer file's bytes: a :class:`StripPage` when its layout is one seen before,
    else tifffile's page after :func:`checked_page` (and its layout learned)."""
    image = manifest["image"]
    key = (mode, image["width"], image["height"], tuple(manifest["dpi"]))
    layout = _LAYOUTS.get(key)
    if layout is not None:
        page = _known_page(data, layout)
        if page is not None:
            return page
    page = checked_page(open_tiff(io.BytesIO(data), name), name, len(data), manifest, mode)
    if layout is None:
        learned = _learn_layout(page, data)
        if learned is not None:
            _LAYOUTS[key] = learned
    return page


def row_bytes(width: int) -> int:
    """Bytes of one packed row of ``width`` pixels."""
    return -(-width // 8)


def _fast_bound(manifest: dict) -> int:
    """Most bytes a 1-bit layer file of the manifest's size can need (:func:`file_limit` of that layout with
    one strip per row): a larger file is read the careful way (:func:`read_checked`), its header first."""
    height = manifest["image"]["height"]
    return 2 * height * row_bytes(manifest["image"]["width"]) + 1024 * height + (1 << 20)


def read_layer_file(path: Path | str | None, name: str, sha256: str | None, manifest: dict,
                    mode: str | None) -> LayerFile:
    """The bytes and checked page of one layer file: inside the stack (``path`` None otherwise), a regular file,
    its layout passing :func:`checked_page` (``mode`` a manifest image mode, or None for a droplet mask), at
    most what that layout can need, and matching ``sha256`` when given; VerifyError naming ``name`` otherwise.
    Memory: bounded by twice the raw 1-bit image (a larger file is bounded by its own checked layout)."""
    if path is None:
        raise VerifyError(f"{name}: lies outside the stack")
    try:
        data = read_small_regular(path, name, _fast_bound(manifest))
    except OSError as err:
        raise VerifyError(f"{name}: cannot read ({err.strerror})") from err
    if data is None:
        data = read_checked(path, name, sha256, manifest, mode)
        sha256 = None
    page = _checked(data, name, manifest, mode)
    limit = file_limit(page)
    if len(data) > limit:
        raise VerifyError(f"{name}: file is {len(data)} bytes, more than its image can need ({limit})")
    if sha256 is not None and hashlib.sha256(data).hexdigest() != sha256:
        raise VerifyError(f"{name}: sha256 does not match the manifest (file altered)")
    return LayerFile(name, data, page, manifest, mode)


def _strip_rows(page) -> int:
    return min(int(page.rowsperstrip or page.imagelength), page.imagelength)


#: Compressed strips known to inflate to zeros (the blank strips off the part, the same bytes in every layer
#: of a stack), by (compression code, bytes inflated, the strip's bytes): skipped instead of inflated (the same
#: bytes stored raw, or inflating to another length, are not blank). Only short strips are remembered, at most this many: strips of
#: at most _BLANK_STRIP_BYTES, and at most 1 / _BLANK_RATIO (+ 64 bytes) of what they inflate to (zeros
#: deflate about 1000:1; a strip holding part of the layer is rarely that short, and is not searched for a set
#: bit each time it is read).
_BLANK_STRIPS: set[tuple[int, int, bytes]] = set()
_MAX_BLANK_STRIPS, _BLANK_STRIP_BYTES, _BLANK_RATIO = 64, 4096, 256


#: Strips inflated earlier while reading one layer's files (:func:`solid_bits`' ``inflated``): (compression code,
#: bytes inflated, the strip's bytes) -> its packed rows. A droplet mask's strip off the other materials is the
#: layer's own strip byte for byte (a layer of one material: the whole file), and is copied, not inflated again.
InflatedStrips = dict[tuple[int, int, bytes], np.ndarray]


def _plain_strips(page) -> list[tuple[int, int, bool, int, int]] | None:
    """(first row, bytes it inflates to, short enough to be blank, offset, bytes) of each strip of a plain
    1-bit page (one sample, bit order and no predictor as heoslice writes them) compressed by a code
    STRIP_DECODERS knows; None for another page, which the generic decoder reads. Blank strips are the short
    ones of :data:`_BLANK_STRIPS`."""
    if (page.bitspersample, page.samplesperpixel) != (1, 1) or page.fillorder != 1 or page.predictor != 1:
        return None
    if int(page.compression) != 1 and int(page.compression) not in STRIP_DECODERS:
        return None
    rows, height, width = _strip_rows(page), page.imagelength, row_bytes(page.imagewidth)
    strips = []
    for number, (offset, count) in enumerate(zip(page.dataoffsets, page.databytecounts)):
        expected = min(rows, height - number * rows) * width
        strips.append((number * rows, expected, count <= min(_BLANK_STRIP_BYTES, expected // _BLANK_RATIO + 64),
                       offset, count))
    return strips


def _inflate_strip(decode, strip: memoryview, target: np.ndarray, expected: int) -> bool:
    """Inflate one strip into ``target`` (``expected`` + 1 bytes: room to tell a longer strip, its last byte then
    zeroed); whether it inflated to exactly ``expected`` bytes (False for a corrupt strip too: the generic
    decoder reports it). ``decode`` None: stored as is."""
    try:
        if decode is None:
            done = min(len(strip), expected + 1)
            target[:done] = np.frombuffer(strip[:done], dtype=np.uint8)
        else:
            done = len(decode(strip, out=target))
    except Exception:  # noqa: BLE001 - a corrupt strip: the generic decoder reports it
        return False
    target[expected] = 0
    return done == expected


def _learned_blank(key: tuple, short: bool, inflated: np.ndarray) -> bool:
    """Whether a strip just inflated (``inflated``: its bytes) is blank, remembered as such (module limits)."""
    if short and len(_BLANK_STRIPS) < _MAX_BLANK_STRIPS and not inflated.any():
        _BLANK_STRIPS.add(key)
        return True
    return False


def _inflate_bits(layer: LayerFile, flat: np.ndarray, inflated: InflatedStrips | None = None) -> tuple[int, int] | None:
    """Inflate every strip of a plain 1-bit page into ``flat`` (the packed rows of the image, one spare byte
    after them); return the rows (first, stop) that may hold set bits (blank strips are known by their bytes
    and zeroed, not inflated; a strip in ``inflated`` is copied from there, and the strips inflated here are
    added to it). None (``flat`` partly written) when the page or a strip is not laid out as heoslice writes it."""
    strips = _plain_strips(layer.page)
    if strips is None:
        return None
    code = int(layer.page.compression)
    decode, view, width = _strip_decoder(code), memoryview(layer.data), row_bytes(layer.page.imagewidth)
    keyed = inflated is not None and decode is not None
    span = [layer.page.imagelength, 0]
    for row, expected, short, offset, count in strips:
        at = row * width
        key = (code, expected, bytes(view[offset:offset + count]) if short or keyed else None)
        if short and key in _BLANK_STRIPS:
            flat[at:at + expected] = 0
            continue
        known = inflated.get(key) if keyed else None
        target = flat[at:at + expected + 1]
        if known is not None:
            target[:expected] = known
        elif not _inflate_strip(decode, view[offset:offset + count], target, expected):
            return None
        elif _learned_blank(key, short, target[:expected]):
            continue
        elif keyed:
            inflated[key] = target[:expected]
        span = [min(span[0], row), max(span[1], row + expected // width)]
    return (span[0], span[1]) if span[0] < span[1] else (0, 0)


#: Lines of strips read earlier from one layer's files (:func:`line_bits`' ``seen``): (compression code, bytes
#: inflated, the strip's bytes, the line's row within the strip (a y cut; -1 for an x cut, whose column spans the
#: strip)) -> the strip's pixels on the line. The row within the strip is part of the key because files of one
#: layer may be cut into strips of different heights: equal strips may start on different rows.
SeenLines = dict[tuple[int, int, bytes, int], np.ndarray]


def line_bits(layer: LayerFile, alpha: bool, axis: str, line: int, seen: SeenLines | None = None) -> np.ndarray:
    """The solid pixels of a checked layer file (as :func:`solid_bits`) along image column ``line`` (``axis``
    'x': (height,) bool) or row ``line`` ('y': (width,) bool), without the whole layer in memory: a y cut
    inflates only the strip holding its row, an x cut each strip in turn into one strip-sized buffer (blank
    strips known by their bytes are not inflated). ``seen`` (one dict for the files of one layer) lets a strip
    met before give its line without being inflated again."""
    page = layer.page
    if not 0 <= line < (page.imagewidth if axis == "x" else page.imagelength):
        raise ValueError(f"line_bits: {axis} line {line} lies outside the {page.imagewidth} x {page.imagelength} image")
    strips = _plain_strips(page)
    if strips is None:
        bits = solid_bits(layer, alpha)
        return _line_of(bits.rows, axis, line, page.imagewidth)
    code = int(page.compression)
    decode, view, width = _strip_decoder(code), memoryview(layer.data), row_bytes(page.imagewidth)
    out = np.zeros(page.imagelength if axis == "x" else page.imagewidth, dtype=bool)
    buffer = np.empty(_strip_rows(page) * width + 1, dtype=np.uint8)
    for row, expected, short, offset, count in strips:
        held = expected // width
        if axis == "y" and not row <= line < row + held:
            continue
        key = (code, expected, bytes(view[offset:offset + count]) if short or seen is not None else None)
        if short and key in _BLANK_STRIPS:
            continue
        seen_key = (*key, line - row if axis == "y" else -1)
        known = None if seen is None else seen.get(seen_key)
        if known is None:
            target = buffer[:expected + 1]
            if not _inflate_strip(decode, view[offset:offset + count], target, expected):
                return _line_of(solid_bits(layer, alpha).rows, axis, line, page.imagewidth)
            if _learned_blank(key, short, target[:expected]):
                continue
            rows = target[:expected].reshape(held, width)
            known = _line_of(rows, axis, line - row if axis == "y" else line, page.imagewidth)
            if seen is not None:
                seen[seen_key] = known
        if axis == "x":
            out[row:row + held] = known
        else:
            out[:] = known
    return out


def _line_of(rows: np.ndarray, axis: str, line: int, width: int) -> np.ndarray:
    """Pixels of packed rows along column ``line`` (axis 'x') or row ``line`` ('y'), bool."""
    if axis == "y":
        return unpack_bits(rows[line:line + 1], width)[0]
    return (rows[:, line // 8] >> (7 - line % 8)) & 1 != 0


def _known_blank(layer: LayerFile) -> bool:
    """Whether every strip of a plain 1-bit page is one known to inflate to zeros (a droplet mask of a material
    absent from its layer), so that nothing need be inflated or zeroed."""
    page = layer.page
    if (page.bitspersample, page.samplesperpixel) != (1, 1) or page.fillorder != 1 or page.predictor != 1:
        return False
    rows, width, height = _strip_rows(page), row_bytes(page.imagewidth), page.imagelength
    code, data = int(page.compression), layer.data
    for number, (offset, count) in enumerate(zip(page.dataoffsets, page.databytecounts)):
        expected = min(rows, height - number * rows) * width  # as _inflate_bits tells a blank strip
        if count > min(_BLANK_STRIP_BYTES, expected // _BLANK_RATIO + 64) or \
                (code, expected, bytes(data[offset:offset + count])) not in _BLANK_STRIPS:
            return False
    return True


@functools.lru_cache(maxsize=4)
def _blank_rows(height: int, width: int) -> np.ndarray:
    """Zero packed rows of a layer size, shared and read-only (a blank file's :class:`Bits`)."""
    rows = np.zeros((height, width), dtype=np.uint8)
    rows.flags.writeable = False
    return rows


@functools.cache
def _strip_decoder(code: int):
    """imagecodecs' decoder of a strip compression code (None: stored as is)."""
    import imagecodecs

    if code == 1:
        return None
    return next(getattr(imagecodecs, name) for name in STRIP_DECODERS[code] if hasattr(imagecodecs, name))


@dataclass(frozen=True, slots=True)
class Bits:
    """A layer file's solid pixels as packed rows (``rows``, module docstring) and the span of rows
    (first, stop) outside which they are all zero."""

    rows: np.ndarray
    span: tuple[int, int]


def solid_bits(layer: LayerFile, alpha: bool, inflated: InflatedStrips | None = None) -> Bits:
    """The solid pixels of a checked layer file (:class:`Bits`): a set sample of a 1-bit or grey file, any
    non-zero sample of a colour one (its alpha when ``alpha``). ``inflated`` (one dict for the files of one
    layer, :data:`InflatedStrips`) lets a strip already inflated be copied instead; the rows it holds are
    the returned Bits' own, not to be written while it is in use."""
    page = layer.page
    height, width = page.imagelength, row_bytes(page.imagewidth)
    if _known_blank(layer):
        return Bits(_blank_rows(height, width), (0, 0))
    flat = np.empty(height * width + 1, dtype=np.uint8)  # _inflate_bits writes or zeroes every row
    flat[-1] = 0
    out = flat[:-1].reshape(height, width)
    span = _inflate_bits(layer, flat, inflated)
    if span is None:
        mask = np.zeros((height, page.imagewidth), dtype=bool)
        decode_solid(layer.tiff_page(), layer.name, alpha, out=mask)
        return Bits(np.packbits(mask, axis=1), (0, height))
    if page.imagewidth % 8:
        out[span[0]:span[1], -1] &= np.uint8((0xFF << (8 - page.imagewidth % 8)) & 0xFF)
    return Bits(out, span)


def partition_counts(layer: Bits, masks: list[Bits]) -> tuple[list[int], bool]:
    """Set bits of a layer's solid pixels and of each of its droplet masks ([layer's, each mask's]), and whether
    the masks partition the layer (no pixel in two masks, their union exactly the layer's solid pixels): one
    compiled pass per file over the rows holding set bits (:func:`heoslice.layers.packed_kernels.fold_words`);
    one count when a single mask is the layer's own Bits object (its file the layer's bytes) and the others hold
    no set row."""
    from heoslice.layers.packed_kernels import COMPARE, JOIN, START

    if not masks:
        raise ValueError("partition_counts: a layer without droplet masks has nothing to partition it")
    whole = [mask is layer for mask in masks]  # a mask read from the layer's own bytes (one material)
    if sum(whole) == 1 and all(same or mask.span[0] >= mask.span[1] for same, mask in zip(whole, masks)):
        count = int(_fold([layer], layer.span, [COMPARE], against_self=True)[0, 0])  # the others blank: a partition
        return [count, *(count if same else 0 for same in whole)], True
    files = [*masks, layer]
    span = min(b.span[0] for b in files), max(b.span[1] for b in files)
    out = _fold(files, span, [START] + [JOIN] * (len(masks) - 1) + [COMPARE])
    counts = [int(count) for count in out[:, 0]]
    return [counts[-1], *counts[:-1]], not out[:, 1].any()


def _fold(files: list[Bits], span: tuple[int, int], modes: list[int], against_self: bool = False) -> np.ndarray:
    """(len(files), 2) int64: :func:`heoslice.layers.packed_kernels.fold_words` of each file in ``modes`` over the
    words of rows span[0]..span[1]-1 (set bits, wrong flag), the files folded into one union in turn, or each
    compared with itself (``against_self``: its count alone). Whole arrays are passed, their words aligned."""
    from heoslice.layers.packed_kernels import fold_words

    first, stop = span
    out = np.zeros((len(files), 2), dtype=np.int64)
    if first >= stop:
        return out
    width = files[0].rows.shape[1]
    flats = [np.ascontiguousarray(b.rows).reshape(-1) for b in files]
    whole = len(flats[0]) // 8
    low, high = first * width // 8, min(whole, -(-stop * width // 8))
    tail = len(flats[0]) - 8 * whole  # the last bytes, short of a word: one zero-padded word of their own
    union = None if against_self else np.empty(whole, dtype=np.uint64)
    union_tail = np.empty(1, dtype=np.uint64)
    for number, (flat, mode) in enumerate(zip(flats, modes)):
        words = flat[:8 * whole].view(np.uint64)
        fold_words(words if against_self else union, words, low, high, mode, out[number])
        if tail and stop * width > 8 * whole:
            padded = np.zeros(8, dtype=np.uint8)
            padded[:tail] = flat[8 * whole:]
            padded_words = padded.view(np.uint64)
            fold_words(padded_words if against_self else union_tail, padded_words, 0, 1, mode, out[number])
    return out


def layer_files(directory: Path, manifest: dict, index: int, channels: bool = True,
                solid: bool = True) -> tuple[LayerFile | None, list[LayerFile]]:
    """The files of layer ``index`` of a stack, each checked (inside, layout, sha256) and read once: (its own
    file, [each droplet mask's] in the order of its ``channels`` list, empty unless ``channels``); with
    ``solid`` False the layer's own file is not read (None in its place: a verified stack's masks hold its
    solid pixels)."""
    root = Path(directory).resolve()
    entry = manifest["layers"][index]
    layer = (read_layer_file(resolve_inside(root, entry["file"], resolved=True), f"layer {index}: {entry['file']}",
                             entry["sha256"], manifest, manifest["image"].get("mode", "1")) if solid else None)
    masks = [read_layer_file(resolve_inside(root, channel["file"], resolved=True),
                             f"layer {index}: {channel['file']}", channel["sha256"], manifest, None)
             for channel in (entry.get("channels") or [] if channels else [])]
    return layer, masks


def layer_bits(directory: Path, manifest: dict, index: int, channels: bool = True,
               solid: bool = True) -> tuple[Bits | None, list[Bits]]:
    """Layer ``index`` of a stack as packed rows (:func:`layer_files` read by :func:`solid_bits`): (its solid
    pixels or None, [each droplet mask's])."""
    layer, masks = layer_files(directory, manifest, index, channels, solid)
    return (None if layer is None else solid_bits(layer, manifest["mask"] == "alpha"),
            [solid_bits(mask, False) for mask in masks])


def unpack_bits(bits: np.ndarray, width: int) -> np.ndarray:
    """(h, width) bool of packed rows."""
    return np.unpackbits(bits, axis=1, count=width).astype(bool)
