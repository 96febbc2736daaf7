"""heoslice.stack.packed: layer files read as packed bits give exactly the masks tifffile decodes, read each file
once, decode only the strips asked for, and refuse what the careful reader refuses."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import tifffile

from heoslice import procedural
from heoslice.errors import VerifyError
from heoslice.stack import encode_bilevel_tiff, read_layer_mask, read_manifest
from heoslice.stack import packed
from heoslice.stack.packed import count_bits, layer_bits, read_layer_file, solid_bits, unpack_bits


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
            assert count_bits(bits.rows) == int(expected.sum())
            assert not (bits.rows[:, -1] & np.uint8(0xFF >> (width % 8))).any()
            assert not bits.rows[:bits.span[0]].any() and not bits.rows[bits.span[1]:].any()
        assert count_bits(solid.rows) == entry["solid_pixels"]


def test_rows_decode_only_their_strips(channels_stack):
    """With rows (first, stop) the strips holding them are decoded exactly and every other row is zero."""
    manifest = read_manifest(channels_stack)
    index = len(manifest["layers"]) // 2
    whole = read_layer_mask(channels_stack, manifest, index)
    line = whole.shape[0] // 2
    solid, _ = layer_bits(channels_stack, manifest, index, channels=False, rows=(line, line + 1))
    got = unpack_bits(solid.rows, whole.shape[1])
    assert np.array_equal(got[line], whole[line]) and whole[line].any()
    strip = int(tifffile.TiffFile(channels_stack / manifest["layers"][index]["file"]).pages.first.rowsperstrip)
    start = line // strip * strip
    assert not got[:start].any() and not got[start + strip:].any()


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
