"""heoslice.stack.packed: layer files read as packed bits give exactly the masks tifffile decodes, read each file
once, decode only the strips asked for, and refuse what the careful reader refuses."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import tifffile
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice import procedural
from heoslice.errors import VerifyError
from heoslice.stack import encode_bilevel_tiff, read_layer_mask, read_manifest
from heoslice.stack import packed
from heoslice.layers.bits import count_solid
from heoslice.stack.packed import layer_bits, read_layer_file, solid_bits, unpack_bits


@pytest.fixture(scope="module")
def channels_stack(tmp_path_factory):
    """A graded stack with droplet masks (white M1 to green M2) of a 6 mm ball, 0.5 mm layers, 300 dpi."""
    from heoslice.cli import main

    folder = tmp_path_factory.mktemp("packed")
    mesh = folder / "ball.ply"
    procedural.sphere(6.0, subdivisions=3).export(mesh)
    try:
        main(["slice", str(mesh), "--layer", "0.5", "--dpi", "300", "--grade", "linear", "--to", "0,255,0",
              "--channels", "-o", str(folder / "stack")])
    except SystemExit as done:
        assert done.code in (0, None)
    return folder / "stack"


@pytest.fixture(scope="module")
def tall_stack(tmp_path_factory):
    """A graded stack with droplet masks of a 10 x 60 x 4 mm box (long in y: its layers three strips tall),
    1 mm layers, 300 dpi."""
    import trimesh

    from heoslice.cli import main

    folder = tmp_path_factory.mktemp("tall")
    mesh = folder / "box.stl"
    trimesh.creation.box(extents=(10.0, 60.0, 4.0)).export(mesh)
    try:
        main(["slice", str(mesh), "--layer", "1", "--dpi", "300", "--grade", "linear", "--to", "0,255,0",
              "--nozzle", "0.5", "--channels", "-o", str(folder / "stack")])
    except SystemExit as done:
        assert done.code in (0, None)
    return folder / "stack"


def test_bits_are_the_masks_tifffile_decodes(channels_stack):
    """Every layer and droplet mask, unpacked, equals tifffile's own decoding of the file, and its set bits
    are the manifest's solid pixel count; the padding bits are zero."""
    manifest = read_manifest(channels_stack)
    width = manifest["image"]["width"]
    assert width % 8, "the test needs rows with padding bits"
    for entry in manifest["layers"]:
        solid, masks = layer_bits(channels_stack, manifest, entry["index"])
        files = [entry, *entry["channels"]]
        for bits, record in zip([solid, *masks], files):
            expected = tifffile.imread(channels_stack / record["file"]).astype(bool)
            assert np.array_equal(unpack_bits(bits.rows, width), expected)
            assert count_solid(bits.rows) == int(expected.sum())
            assert not (bits.rows[:, -1] & np.uint8(0xFF >> (width % 8))).any()
            assert not bits.rows[:bits.span[0]].any() and not bits.rows[bits.span[1]:].any()
        assert count_solid(solid.rows) == entry["solid_pixels"]


@pytest.mark.parametrize("axis", ["x", "y"])
def test_a_line_is_the_layers_line(tall_stack, axis):
    """line_bits along a column (x) or a row (y) of every file of a layer equals that line of tifffile's decoding
    of the file, through the part's middle, at the image's edges and on a strip boundary; strips shared through
    ``seen`` give the same lines."""
    from heoslice.stack.packed import layer_files, line_bits

    manifest = read_manifest(tall_stack)
    index = len(manifest["layers"]) // 2
    entry = manifest["layers"][index]
    layer, masks = layer_files(tall_stack, manifest, index)
    strip = int(tifffile.TiffFile(tall_stack / entry["file"]).pages.first.rowsperstrip)
    assert manifest["image"]["height"] > strip, "the test needs more than one strip"
    size = manifest["image"]["width"] if axis == "x" else manifest["image"]["height"]
    for line in sorted({0, size // 2, size - 1} | ({strip - 1, strip} if axis == "y" else set())):
        seen: packed.SeenLines = {}
        for file, record in zip([layer, *masks], [entry, *entry["channels"]]):
            whole = tifffile.imread(tall_stack / record["file"]).astype(bool)
            expected = whole[:, line] if axis == "x" else whole[line]
            assert np.array_equal(line_bits(file, False, axis, line, seen), expected)
            assert np.array_equal(line_bits(file, False, axis, line), expected)
    middle = size // 2
    assert line_bits(layer, False, axis, middle).any(), "the middle line crosses the part"


def test_a_line_is_read_from_its_strips_alone(tall_stack, monkeypatch):
    """heoslice's own files are read along the line strip by strip, never through the whole-layer reader (which a
    failing strip falls back to): the fast path is the one the other tests check."""
    from heoslice.stack.packed import layer_files, line_bits

    manifest = read_manifest(tall_stack)
    layer, masks = layer_files(tall_stack, manifest, len(manifest["layers"]) // 2)

    def whole_layer(*_args, **_kwargs):
        raise AssertionError("line_bits fell back to the whole layer")

    monkeypatch.setattr(packed, "solid_bits", whole_layer)
    for file in [layer, *masks]:
        for axis, line in (("x", manifest["image"]["width"] // 2), ("y", manifest["image"]["height"] // 2)):
            line_bits(file, False, axis, line, {})
    with pytest.raises(ValueError, match="outside"):
        line_bits(layer, False, "y", manifest["image"]["height"])


def test_lines_shared_between_files_of_other_strip_heights(tmp_path):
    """Files of one layer cut into strips of other heights may hold byte-identical strips starting on other rows:
    a y cut's row shared through ``seen`` is taken only from a strip holding the same row at the same place, and
    a strip met again at the same place gives its line without being inflated (each file's line is its own)."""
    from heoslice.stack.packed import line_bits

    width, height = 40, 267
    solid, mask = np.zeros((height, width), bool), np.zeros((height, width), bool)
    for k in range(11):  # the solid's last strip (rows 256..266) is the mask's 24th (rows 253..263), byte for byte
        solid[256 + k, :30 - 2 * k] = True
        mask[253 + k, :30 - 2 * k] = True
    manifest = {"image": {"width": width, "height": height}, "dpi": [300.0, 300.0], "mask": "nonzero"}
    files = {}
    for name, pixels, rows in (("solid", solid, 256), ("mask", mask, 11), ("again", solid, 256)):
        (tmp_path / f"{name}.tif").write_bytes(encode_bilevel_tiff(np.packbits(pixels, axis=1), width,
                                                                   (300.0, 300.0), "deflate", rows_per_strip=rows))
        files[name] = read_layer_file(tmp_path / f"{name}.tif", f"{name}.tif", None, manifest, None)
    page_solid, page_mask = (tifffile.TiffFile(tmp_path / f"{n}.tif").pages.first for n in ("solid", "mask"))
    last = (page_solid.dataoffsets[-1], page_solid.databytecounts[-1])
    strip = (page_mask.dataoffsets[23], page_mask.databytecounts[23])
    solid_bytes, mask_bytes = (tmp_path / "solid.tif").read_bytes(), (tmp_path / "mask.tif").read_bytes()
    assert solid_bytes[last[0]:sum(last)] == mask_bytes[strip[0]:sum(strip)], "the layout the test needs"
    for axis, lines in (("y", range(250, height)), ("x", range(width))):
        for line in lines:
            seen: packed.SeenLines = {}
            for name, pixels in (("solid", solid), ("mask", mask), ("again", solid)):
                expected = pixels[:, line] if axis == "x" else pixels[line]
                assert np.array_equal(line_bits(files[name], False, axis, line, seen), expected), (name, axis, line)


def test_a_known_layout_is_checked_like_a_new_one(tmp_path):
    """A file matching a layout seen before still has its strip table checked: a strip pointing past the end
    of the file is refused with the careful reader's message."""
    packed._LAYOUTS.clear()
    rows = np.zeros((300, 4), np.uint8)
    rows[10:20] = 0xF0
    data = encode_bilevel_tiff(rows, 30, (300.0, 300.0), "deflate")
    manifest = {"image": {"width": 30, "height": 300}, "dpi": [300.0, 300.0], "mask": "nonzero"}
    (tmp_path / "a.tif").write_bytes(data)
    first = read_layer_file(tmp_path / "a.tif", "a.tif", None, manifest, "1")
    assert isinstance(first.page, tifffile.TiffPage)
    second = read_layer_file(tmp_path / "a.tif", "a.tif", None, manifest, "1")
    assert isinstance(second.page, packed.StripPage)
    assert np.array_equal(solid_bits(second, False).rows, solid_bits(first, False).rows)
    page = first.page
    at = page.tags[273].valueoffset
    bad = bytearray(data)
    bad[at:at + 4] = (len(data) + 10).to_bytes(4, "little")
    (tmp_path / "b.tif").write_bytes(bytes(bad))
    with pytest.raises(VerifyError, match="strip 0 lies outside the file"):
        read_layer_file(tmp_path / "b.tif", "b.tif", None, manifest, "1")


def test_a_corrupt_strip_is_one_error_line(channels_stack, tmp_path):
    """A strip whose deflate stream is broken (and the manifest's hash updated to match) is a VerifyError
    naming the file, not a crash."""
    copy = tmp_path / "copy"
    shutil.copytree(channels_stack, copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    entry = manifest["layers"][len(manifest["layers"]) // 2]
    path = copy / entry["file"]
    page = tifffile.TiffFile(path).pages.first
    offset, count = max(zip(page.dataoffsets, page.databytecounts), key=lambda item: item[1])
    data = bytearray(path.read_bytes())
    data[offset + count // 2:offset + count] = bytes(count - count // 2)
    path.write_bytes(bytes(data))
    import hashlib

    entry["sha256"] = hashlib.sha256(bytes(data)).hexdigest()
    with pytest.raises(VerifyError, match=entry["file"]):
        layer_bits(copy, manifest, entry["index"], channels=False)


def _reference_partition(layer: np.ndarray, masks: list[np.ndarray]) -> tuple[list[int], bool]:
    """partition_counts written out on unpacked bools: each file's set pixels, and whether the masks are
    pairwise disjoint and their union is the layer."""
    counts = [int(layer.sum()), *(int(mask.sum()) for mask in masks)]
    held = np.sum(masks, axis=0)
    return counts, bool(np.all(held <= 1) and np.array_equal(held > 0, layer))


def _bits(pixels: np.ndarray) -> packed.Bits:
    """Packed rows of (h, w) bool with the span of rows holding set pixels (as solid_bits gives them)."""
    rows = np.flatnonzero(pixels.any(axis=1))
    return packed.Bits(np.packbits(pixels, axis=1), (int(rows[0]), int(rows[-1]) + 1) if len(rows) else (0, 0))


@settings(max_examples=150, deadline=None)
@given(height=st.integers(1, 9), width=st.integers(1, 70), count=st.integers(1, 3), seed=st.integers(0, 2**32 - 1),
       fault=st.sampled_from(["none", "doubled", "uncovered", "outside"]))
def test_partition_counts_agree_with_the_masks_written_out(height, width, count, seed, fault):
    """Counts and the partition verdict equal the plain numpy reference for any size (rows not a whole number of
    64-bit words, the last word short), any number of masks and each kind of fault, wherever it lies."""
    rng = np.random.default_rng(seed)
    layer = rng.random((height, width)) < 0.6
    owner = rng.integers(0, count, (height, width))
    masks = [layer & (owner == k) for k in range(count)]
    row, column = rng.integers(0, height), rng.integers(0, width)
    if fault == "doubled" and count > 1:
        layer[row, column] = True
        masks[0][row, column] = masks[1][row, column] = True
    elif fault == "uncovered":
        layer[row, column] = True
        for mask in masks:
            mask[row, column] = False
    elif fault == "outside":
        layer[row, column] = False
        masks[-1][row, column] = True
    counts, partitioned = packed.partition_counts(_bits(layer), [_bits(mask) for mask in masks])
    assert (counts, partitioned) == _reference_partition(layer, masks)


def test_partition_counts_see_a_fault_in_the_last_bytes():
    """A pixel in two masks in the bytes after the last whole 64-bit word is found (the tail's own pass)."""
    layer = np.zeros((3, 40), dtype=bool)  # 5 bytes a row, 15 in all: one word and 7 bytes after it
    layer[2, 39] = True
    masks = [layer.copy(), layer.copy()]
    assert packed.partition_counts(_bits(layer), [_bits(mask) for mask in masks]) == ([1, 1, 1], False)
    masks[1][2, 39] = False
    assert packed.partition_counts(_bits(layer), [_bits(mask) for mask in masks]) == ([1, 1, 0], True)


def test_strips_shared_by_a_layers_files_are_inflated_once(tmp_path, monkeypatch):
    """Files read with one ``inflated`` dict (a layer's files) give the rows each gives alone, and a strip whose
    bytes an earlier file held is copied: the second file, equal but for one strip, inflates that strip only."""
    rng = np.random.default_rng(5)
    pixels = rng.random((800, 70)) < 0.5  # noise: every strip long, none known blank
    other = pixels.copy()
    other[5, :] = ~other[5, :]  # the first strip differs
    manifest = {"image": {"width": 70, "height": 800}, "dpi": [300.0, 300.0], "mask": "nonzero"}
    files = []
    for name, image in (("a.tif", pixels), ("b.tif", other)):
        (tmp_path / name).write_bytes(encode_bilevel_tiff(np.packbits(image, axis=1), 70, (300.0, 300.0), "deflate"))
        files.append(read_layer_file(tmp_path / name, name, None, manifest, "1"))
    strips = len(tifffile.TiffFile(tmp_path / "a.tif").pages.first.dataoffsets)
    assert strips > 2, "the test needs several strips"
    decoder = packed._strip_decoder(8)
    calls = []
    monkeypatch.setattr(packed, "_strip_decoder",
                        lambda code: lambda strip, out: calls.append(1) or decoder(strip, out=out))
    inflated = {}
    first = solid_bits(files[0], False, inflated=inflated)
    assert len(calls) == strips
    second = solid_bits(files[1], False, inflated=inflated)
    assert len(calls) == strips + 1
    assert np.array_equal(unpack_bits(first.rows, 70), pixels) and np.array_equal(unpack_bits(second.rows, 70), other)
    assert first.span == second.span == (0, 800)


@settings(max_examples=100, deadline=None)
@given(height=st.integers(1, 9), width=st.integers(1, 70), seed=st.integers(0, 2**32 - 1), others=st.integers(1, 2),
       blank=st.booleans())
def test_a_mask_that_is_the_layers_own_bits_is_partitioned_as_written_out(height, width, seed, others, blank):
    """A droplet mask read from the layer's own bytes (the layer's Bits object itself, a part of one material)
    beside other masks, blank or not: counts and verdict equal the plain numpy reference (a partition only when
    every other mask is blank)."""
    rng = np.random.default_rng(seed)
    layer = rng.random((height, width)) < 0.6
    rest = [np.zeros_like(layer) if blank else rng.random((height, width)) < 0.3 for _ in range(others)]
    bits = _bits(layer)
    counts, partitioned = packed.partition_counts(bits, [bits, *(_bits(mask) for mask in rest)])
    assert (counts, partitioned) == _reference_partition(layer, [layer, *rest])


def test_a_file_of_known_blank_strips_is_not_inflated(tmp_path, monkeypatch):
    """A blank droplet mask whose strips are all known to inflate to zeros (learned from an earlier file) reads as
    zero rows with an empty span without a strip inflated, and its rows cannot be written; a file with one set
    pixel more is inflated as before."""
    monkeypatch.setattr(packed, "_BLANK_STRIPS", set())  # room to learn, whatever this process read before
    manifest = {"image": {"width": 70, "height": 800}, "dpi": [300.0, 300.0], "mask": "nonzero"}
    pixels = np.zeros((800, 70), dtype=bool)
    one = pixels.copy()
    one[700, 3] = True
    for name, image in (("blank.tif", pixels), ("one.tif", one)):
        (tmp_path / name).write_bytes(encode_bilevel_tiff(np.packbits(image, axis=1), 70, (300.0, 300.0), "deflate"))
    blank = read_layer_file(tmp_path / "blank.tif", "blank.tif", None, manifest, None)
    solid_bits(blank, False)  # its strips learned as blank
    decoder = packed._strip_decoder(8)
    calls = []
    monkeypatch.setattr(packed, "_strip_decoder",
                        lambda code: lambda strip, out: calls.append(1) or decoder(strip, out=out))
    again = solid_bits(blank, False)
    assert calls == [] and again.span == (0, 0) and not again.rows.any() and again.rows.shape == (800, 9)
    with pytest.raises(ValueError, match="read-only"):
        again.rows[0, 0] = 1
    bits = solid_bits(read_layer_file(tmp_path / "one.tif", "one.tif", None, manifest, None), False)
    assert calls and np.array_equal(unpack_bits(bits.rows, 70), one) and bits.span[0] <= 700 < bits.span[1]


def test_a_strip_is_known_blank_by_its_codec_and_length_too(tmp_path, monkeypatch):
    """A raw (uncompressed) file whose first strip's bytes are those of a deflated strip learned as blank is read
    as what it holds, set bits and all (the bytes alone once made it all zeros, a review of the blank files'
    shortcut found)."""
    monkeypatch.setattr(packed, "_BLANK_STRIPS", set())
    manifest = {"image": {"width": 8, "height": 2000}, "dpi": [300.0, 300.0], "mask": "nonzero"}
    (tmp_path / "blank.tif").write_bytes(encode_bilevel_tiff(np.zeros((2000, 1), np.uint8), 8, (300.0, 300.0),
                                                             "deflate", rows_per_strip=2000))
    solid_bits(read_layer_file(tmp_path / "blank.tif", "blank.tif", None, manifest, None), False)
    (code, _, blob), = packed._BLANK_STRIPS
    assert code == 8 and any(blob)
    rows = np.frombuffer(blob, dtype=np.uint8)[:, None]  # one byte a row: the raw strip is the blob
    raw = {**manifest, "image": {"width": 8, "height": len(rows)}}
    (tmp_path / "raw.tif").write_bytes(encode_bilevel_tiff(rows, 8, (300.0, 300.0), "none", rows_per_strip=len(rows)))
    bits = solid_bits(read_layer_file(tmp_path / "raw.tif", "raw.tif", None, raw, None), False)
    assert np.array_equal(bits.rows, rows) and bits.span == (0, len(rows))
