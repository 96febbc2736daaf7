"""The stack on disk: format, atomic writing, and `verify` catching every kind of damage.

Stacks are made by the real pipeline from small procedural meshes, then damaged
one way at a time; each damage must be reported (one line), and the untouched
stack must verify clean.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tracemalloc
import zlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import tifffile

from heoslice import procedural
from heoslice.errors import InputError, OutputError, VerifyError
from heoslice.mesh import load_mesh
from heoslice.pipeline import SliceSpec, slice_to_stack
from heoslice.stack import (
    MANIFEST,
    MAX_MANIFEST_BYTES,
    MAX_MANIFEST_CONTAINERS,
    check_image_size,
    decode_mask,
    encode_tiff,
    layer_file_name,
    load_verified,
    prepare_directory,
    read_layer_mask,
    read_manifest,
    stack_volume_mm3,
    verify_stack,
    write_file,
    write_manifest,
)

SPEC = SliceSpec(layer_height_mm=1.0, dpi=(100.0, 100.0), jobs=1)


def make_stack(tmp_path: Path, mesh=None, name: str = "stack", colors: bool = False) -> Path:
    """Slice a procedural mesh (default: 10 mm cube) into a small stack; return its directory. ``colors``: the
    top half coloured M2, the rest M1, sliced as an RGBA preview stack."""
    mesh = mesh if mesh is not None else procedural.box(z_cuts=(3.0, 6.0))
    if colors:
        top = mesh.vertices[:, 2:3] > mesh.bounds[:, 2].mean()
        mesh.visual.vertex_colors = np.where(top, [0, 255, 0, 255], [240, 240, 240, 255]).astype(np.uint8)
    model = tmp_path / f"{name}.ply"
    mesh.export(model)
    directory = tmp_path / name
    slice_to_stack(load_mesh(model), directory, replace(SPEC, channels=False) if colors else SPEC)
    return directory


@pytest.fixture
def stack(tmp_path) -> Path:
    return make_stack(tmp_path)


def edit_manifest(directory: Path, change) -> None:
    """Apply ``change(manifest)`` to a stack's manifest.json in place."""
    path = directory / MANIFEST
    manifest = json.loads(path.read_text())
    change(manifest)
    path.write_text(json.dumps(manifest))


def replace_layer(directory: Path, index: int, data: bytes) -> None:
    """Overwrite layer ``index``'s file and record its new sha256, so only the content check can object."""
    (directory / layer_file_name(index)).write_bytes(data)
    edit_manifest(directory, lambda m: m["layers"][index].update(sha256=hashlib.sha256(data).hexdigest()))


def problems(directory: Path) -> tuple[str, ...]:
    found = verify_stack(directory).problems
    assert all("\n" not in line for line in found)
    return found


def test_fresh_stack_verifies_clean(stack):
    """A stack written by the pipeline has no problems, and its layers decode to the recorded counts."""
    report = verify_stack(stack)
    assert report.ok, report.problems
    manifest = report.manifest
    assert len(manifest["layers"]) == 10
    for entry in manifest["layers"]:
        assert int(read_layer_mask(stack, manifest, entry["index"]).sum()) == entry["solid_pixels"]
    assert stack_volume_mm3(manifest) == pytest.approx(1000.0, rel=0.05)
    assert load_verified(stack) == manifest


def test_rgba_stack_verifies_clean(tmp_path):
    """An RGBA preview stack of a coloured mesh (mask 'alpha') verifies clean."""
    directory = make_stack(tmp_path, colors=True)
    report = verify_stack(directory)
    assert report.ok, report.problems
    assert report.manifest["mask"] == "alpha" and report.manifest["image"]["mode"] == "RGBA"


def test_manifest_written_last_and_atomically(tmp_path, monkeypatch):
    """write_manifest leaves no temporary file; if the rename fails, no manifest.json exists and verify refuses."""
    directory = make_stack(tmp_path)
    assert not (directory / (MANIFEST + ".tmp")).exists()
    manifest = json.loads((directory / MANIFEST).read_text())
    (directory / MANIFEST).unlink()

    def broken_replace(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OutputError, match="no space left on device"):
        write_manifest(directory, manifest)
    assert not (directory / MANIFEST).exists()
    assert "no manifest.json" in problems(directory)[0]


def test_force_removes_the_manifest_before_any_layer(stack, monkeypatch):
    """prepare_directory(force) unlinks manifest.json first: failing half-way leaves no complete-looking stack."""
    removed = []
    real_unlink = Path.unlink

    def unlink(self, *args, **kwargs):
        removed.append(self.name)
        if self.name.startswith("layer_") and len(removed) > 3:
            raise OSError(5, "Input/output error")
        return real_unlink(self, *args, **kwargs)

    monkeypatch.setattr(Path, "unlink", unlink)
    with pytest.raises(OutputError, match="cannot clear old stack"):
        prepare_directory(stack, force=True)
    assert removed[0] == MANIFEST
    assert not (stack / MANIFEST).exists()


def test_non_empty_directory_needs_force(stack):
    """Without --force an existing directory with files is refused; with it the old layers go, but only from
    a folder holding nothing but a stack's files: a file of the user's makes --force refuse, changing nothing."""
    with pytest.raises(OutputError, match="not empty"):
        prepare_directory(stack, force=False)
    (stack / "notes.txt").write_text("mine")
    before = sorted(p.name for p in stack.iterdir())
    with pytest.raises(OutputError, match="not a stack folder heoslice wrote"):
        prepare_directory(stack, force=True)
    assert sorted(p.name for p in stack.iterdir()) == before
    (stack / "notes.txt").unlink()
    prepare_directory(stack, force=True)
    assert list(stack.iterdir()) == []


def test_write_file_disk_full_is_one_line(tmp_path):
    """Writing to a full device (/dev/full) gives a one-line OutputError."""
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full")
    with pytest.raises(OutputError, match="no space left on device") as caught:
        write_file(Path("/dev/full"), b"x" * 100000)
    assert "\n" not in str(caught.value)


def test_write_file_does_not_follow_planted_symlinks(tmp_path):
    """A symlink named like a layer file is never written through; --force removes dangling ones."""
    outside = tmp_path / "outside.txt"
    outside.write_text("precious")
    directory = tmp_path / "d"
    directory.mkdir()
    (directory / "layer_00000.tif").symlink_to(outside)
    with pytest.raises(OutputError):
        write_file(directory / "layer_00000.tif", b"II*\x00")
    assert outside.read_text() == "precious"
    (directory / "layer_00001.tif").symlink_to(tmp_path / "nowhere.txt")
    prepare_directory(directory, force=True)
    assert list(directory.iterdir()) == [] and outside.read_text() == "precious"
    assert not (tmp_path / "nowhere.txt").exists()


def test_image_size_limit():
    """Images above MAX_IMAGE_PIXELS are refused before writing (InputError)."""
    check_image_size(30000, 30000)
    with pytest.raises(InputError, match="exceed the limit"):
        check_image_size(40000, 40000)


# --- damage, one kind at a time ----------------------------------------------------------------


def test_missing_layer_file(stack):
    """A listed layer file that is gone is reported by name."""
    (stack / layer_file_name(4)).unlink()
    assert problems(stack) == ("layer 4: layer_00004.tif is missing",)


def test_a_reader_is_refused_a_missing_file_before_it_reads_a_layer(stack, monkeypatch):
    """open_verified refuses a stack whose last layer's file is gone, naming it, before any layer is read (an
    export writes nothing it would have to remove)."""
    import heoslice.stack.verify as verify

    (stack / layer_file_name(4)).unlink()
    monkeypatch.setattr(verify, "layer_check", lambda *args: pytest.fail("a layer was read"))
    with pytest.raises(VerifyError, match="layer 4: layer_00004.tif is missing"):
        verify.open_verified(stack)


def test_extra_layer_file(stack):
    """A layer file not in the manifest is reported."""
    (stack / layer_file_name(10)).write_bytes((stack / layer_file_name(0)).read_bytes())
    assert problems(stack) == ("layer_00010.tif: layer file not listed in the manifest",)


def test_missing_layer_entry(stack):
    """Dropping the top layer entry leaves an unlisted file and a layer count short of the z-range."""
    edit_manifest(stack, lambda m: m["layers"].pop())
    found = problems(stack)
    assert any("layer_00009.tif: layer file not listed" in line for line in found)
    assert any("9 layers, but the manifest's z-range" in line and "needs 10" in line for line in found)


def test_altered_file(stack):
    """Changing one byte of a layer file breaks its sha256."""
    path = stack / layer_file_name(2)
    data = bytearray(path.read_bytes())
    data[-1] ^= 0xFF
    path.write_bytes(bytes(data))
    assert problems(stack) == ("layer 2: layer_00002.tif: sha256 does not match the manifest (file altered)",)


@pytest.mark.parametrize("name", ["../outside.tif", "/etc/passwd", "sub/../../outside.tif"])
def test_path_escaping_the_stack(stack, name):
    """File names with '..' or absolute paths are refused without opening them."""
    (stack.parent / "outside.tif").write_bytes((stack / layer_file_name(0)).read_bytes())
    edit_manifest(stack, lambda m: m["layers"][1].update(file=name))
    found = problems(stack)
    assert f"layer 1: file {name!r} lies outside the stack" in found


def test_symlink_out_of_the_stack(stack):
    """A layer file that is a symlink to a file outside the stack is refused, even with the right content."""
    outside = stack.parent / "outside.tif"
    outside.write_bytes((stack / layer_file_name(3)).read_bytes())
    (stack / layer_file_name(3)).unlink()
    (stack / layer_file_name(3)).symlink_to(outside)
    assert "layer 3: file 'layer_00003.tif' lies outside the stack" in problems(stack)


def test_manifest_symlink_out_of_the_stack(stack):
    """manifest.json linking outside the stack is refused (reading it would read outside)."""
    outside = stack.parent / "elsewhere.json"
    outside.write_text((stack / MANIFEST).read_text())
    (stack / MANIFEST).unlink()
    (stack / MANIFEST).symlink_to(outside)
    assert "is a link to outside the stack" in problems(stack)[0]


def test_wrong_image_size(stack):
    """A layer of another size (hash updated to match) is reported with both sizes."""
    manifest = read_manifest(stack)
    width, height = manifest["image"]["width"], manifest["image"]["height"]
    replace_layer(stack, 5, encode_tiff(np.zeros((height + 1, width), bool), (100, 100), "deflate"))
    assert problems(stack) == (f"layer 5: layer_00005.tif: is {width} x {height + 1} pixels, "
                               f"manifest says {width} x {height}",)


def test_wrong_dpi(stack):
    """A layer whose resolution tags disagree with the manifest is reported."""
    manifest = read_manifest(stack)
    shape = (manifest["image"]["height"], manifest["image"]["width"])
    replace_layer(stack, 6, encode_tiff(np.zeros(shape, bool), (200, 100), "deflate"))
    assert problems(stack) == ("layer 6: layer_00006.tif: resolution 200 x 100 dpi, manifest says 100 x 100 dpi",)


def test_wrong_pixel_format(stack):
    """An 8-bit layer in a 1-bit stack is reported (mode check)."""
    manifest = read_manifest(stack)
    shape = (manifest["image"]["height"], manifest["image"]["width"])
    replace_layer(stack, 7, encode_tiff(np.zeros(shape, np.uint8), (100, 100), "deflate"))
    assert "manifest says mode '1'" in problems(stack)[0]


def test_wrong_solid_count(stack):
    """A manifest solid pixel count that differs from the image is reported with both numbers."""
    manifest = read_manifest(stack)
    solid = manifest["layers"][0]["solid_pixels"]
    edit_manifest(stack, lambda m: m["layers"][0].update(solid_pixels=solid - 1))
    assert problems(stack) == (f"layer 0: layer_00000.tif: has {solid} solid pixels, manifest says {solid - 1}",)


def test_solid_pixels_decoded_not_trusted(stack):
    """A different image with the hash updated is caught by the solid pixel count."""
    manifest = read_manifest(stack)
    shape = (manifest["image"]["height"], manifest["image"]["width"])
    replace_layer(stack, 8, encode_tiff(np.ones(shape, bool), (100, 100), "packbits"))
    assert problems(stack) == (f"layer 8: layer_00008.tif: has {shape[0] * shape[1]} solid pixels, "
                               f"manifest says {manifest['layers'][8]['solid_pixels']}",)


def test_wrong_layer_height(stack):
    """z_mm values that do not follow z_min + (i + 1/2) h are reported."""
    edit_manifest(stack, lambda m: m["layers"][3].update(z_mm=m["layers"][3]["z_mm"] + 0.2))
    assert problems(stack)[0].startswith("layer 3: z_mm 3.7, expected 3.5")


def test_file_listed_twice(stack):
    """Two layers naming the same file are reported."""
    edit_manifest(stack, lambda m: m["layers"][1].update(file=m["layers"][0]["file"],
                                                         sha256=m["layers"][0]["sha256"],
                                                         solid_pixels=m["layers"][0]["solid_pixels"]))
    found = problems(stack)
    assert "layer 1: layer_00000.tif is listed twice (also by layer 0)" in found
    assert "layer_00001.tif: layer file not listed in the manifest" in found


def masks_of(manifest: dict, index: int, *materials: str) -> None:
    """Give layer ``index`` of ``manifest`` one droplet mask entry per material (its own file, for structure;
    None: an entry without a material)."""
    entry = manifest["layers"][index]
    entry["channels"] = [{"file": entry["file"], "sha256": entry["sha256"]} | ({} if name is None else {"material": name})
                         for name in materials]


@pytest.mark.parametrize("change, expected", [
    (lambda m: m.update(complete=False), "not complete"),
    (lambda m: m.pop("complete"), "not complete"),
    (lambda m: m.update(format="other"), "format is 'other'"),
    (lambda m: m.update(version=2), "version 2 is not supported"),
    (lambda m: m.update(version=True), "is not supported"),
    (lambda m: m["image"].update(width=0), "width/height"),
    (lambda m: m["image"].update(width=40000, height=40000), "exceeds the limit"),
    (lambda m: m.update(dpi=[600]), "'dpi' must be two positive numbers"),
    (lambda m: m.update(layer_height_mm=-1), "'layer_height_mm'"),
    (lambda m: m.update(mask="alpha"), "mask 'alpha' needs image mode 'RGBA'"),
    (lambda m: m["layers"][2].update(index=3), "layer entry 2 has index 3"),
    (lambda m: m["layers"][2].update(sha256="abc"), "64 lower-case hex"),
    (lambda m: m["layers"][2].update(solid_pixels=-5), "solid_pixels"),
    (lambda m: m["layers"][2].update(channels=[{"file": 3}]), "channel 0"),
    (lambda m: m.update(layers={}), "'layers' must be a list"),
    (lambda m: m.update(grading="x"), "'grading' must be an object"),
    (lambda m: m.update(grading={"materials": "x"}), "'grading.materials' must be a list"),
    (lambda m: m.update(grading={"materials": [{"channel": 1}]}), "objects with a 'name'"),
    (lambda m: m.update(grading={"materials": [{"name": "a", "channel": 0}]}), "'a' has printer channel 0"),
    (lambda m: m.update(grading={"materials": [{"name": "a", "channel": True}]}), "'a' has printer channel True"),
    (lambda m: m.update(grading={"materials": [{"name": "a", "channel": 255}]}), "channel 255, not a whole number from 1"),
    (lambda m: (m.update(grading={"materials": [{"name": "a", "channel": 1}]}), masks_of(m, 2, None)),
     "layer 2: its droplet masks (None) are not one per material"),
    (lambda m: (m.update(grading={"materials": [{"name": "a", "channel": 1}]}), masks_of(m, 2, "b")),
     "layer 2: its droplet masks (b) are not one per material of grading.materials (a)"),
    (lambda m: (m.update(grading={"materials": [{"name": "a", "channel": 1}, {"name": "b", "channel": 2}]}),
                masks_of(m, 2, "a")), "layer 2: its droplet masks (a) are not one per material"),
])
def test_malformed_manifest(stack, change, expected):
    """Each structural manifest flaw is one problem line naming it."""
    edit_manifest(stack, change)
    found = problems(stack)
    assert len(found) == 1 and expected in found[0], found


def test_a_manifest_without_layers_is_problems_not_a_crash(stack):
    """A manifest whose layer list is empty is verify's problem lines (the layer count its z-range needs, the
    files it does not list), not an internal error."""
    edit_manifest(stack, lambda m: m.update(layers=[]))
    found = problems(stack)
    assert any("not listed in the manifest" in line for line in found), found


@pytest.mark.parametrize("text, expected", [
    (b"{not json", "not valid JSON"),
    (b"", "not valid JSON"),
    (b"\xff\xfe{}", "not UTF-8"),
    (b'{"a": NaN}', "not valid JSON"),
    (b'{"a": 1e999}', "not valid JSON"),
    (b"[" * 100000 + b"]" * 100000, "nested too deeply"),
    (b"[" + b"{}," * (MAX_MANIFEST_CONTAINERS + 1) + b"{}]", "objects and arrays"),
    (b"[]", "not a JSON object"),
])
def test_garbage_manifest(stack, text, expected):
    """Garbage, NaN, deep nesting and container bombs in manifest.json are one-line problems."""
    (stack / MANIFEST).write_bytes(text)
    found = problems(stack)
    assert len(found) == 1 and expected in found[0], found


def test_huge_manifest_refused_before_parsing(stack):
    """A manifest larger than MAX_MANIFEST_BYTES is refused without parsing (bounded memory)."""
    with open(stack / MANIFEST, "wb") as handle:
        handle.truncate(MAX_MANIFEST_BYTES + 1)
    tracemalloc.start()
    try:
        found = problems(stack)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert "larger than" in found[0] and peak < 1 << 20


def test_manifest_that_is_a_directory_or_missing(stack):
    """No manifest beside layer files is an incomplete stack (an interrupted slice: rerun it with --force); no
    manifest in a folder without layer files is not a stack; a manifest that is not a regular file is reported."""
    (stack / MANIFEST).unlink()
    assert "incomplete stack, no manifest.json" in problems(stack)[0]
    assert "run that slice again with --force" in problems(stack)[0]
    for layer in stack.glob("layer_*.tif"):
        layer.unlink()
    assert problems(stack)[0].endswith("no manifest.json (not a stack)")
    (stack / MANIFEST).mkdir()
    assert "is not a regular file" in problems(stack)[0]


# --- decompression bombs and hostile TIFF headers -----------------------------------------------


def hostile_layer(stack: Path, edit) -> str:
    """Rewrite layer 0's TIFF tags with ``edit(page tags, path)``, record its hash; return the verify problem."""
    path = stack / layer_file_name(0)
    with tifffile.TiffFile(path, mode="r+") as tiff:
        edit(tiff.pages.first.tags, path)
    data = path.read_bytes()
    replace_layer(stack, 0, data)
    tracemalloc.start()
    try:
        found = problems(stack)
        with pytest.raises(VerifyError):
            read_layer_mask(stack, read_manifest(stack), 0)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 4 << 20, peak
    assert len(found) == 1 and found[0].startswith("layer 0: "), found
    return found[0]


def test_tiff_claiming_a_huge_size_is_refused_before_decoding(stack):
    """A TIFF whose header claims 100000 x 100000 pixels is refused on the header, allocating nothing big."""
    def edit(tags, path):
        tags["ImageWidth"].overwrite(100000)
        tags["ImageLength"].overwrite(100000)
    assert "is 100000 x 100000 pixels" in hostile_layer(stack, edit)


def test_tiff_with_a_huge_compressed_strip_is_refused(stack):
    """A strip claiming 2 GiB of compressed data is refused before reading or decoding it."""
    def edit(tags, path):
        counts = list(tags["StripByteCounts"].value)
        counts[0] = 2**31
        tags["StripByteCounts"].overwrite(counts)
    assert "claims 2147483648 bytes" in hostile_layer(stack, edit)


def test_deflate_bomb_strip_stays_bounded(stack):
    """A strip within the size bound whose deflate stream expands 1000-fold decodes to at most one strip."""
    bomb = zlib.compress(b"\xff" * (1 << 20), 9)  # 1 MiB from about 1 KiB

    def edit(tags, path):
        offset = path.stat().st_size
        with open(path, "ab") as handle:
            handle.write(bomb)
        offsets = list(tags["StripOffsets"].value)
        counts = list(tags["StripByteCounts"].value)
        offsets[0], counts[0] = offset, len(bomb)
        tags["StripOffsets"].overwrite(offsets)
        tags["StripByteCounts"].overwrite(counts)

    message = hostile_layer(stack, edit)
    assert "cannot decode" in message or "solid pixels" in message, message


def test_read_layer_mask_checks_the_hash_again(stack):
    """A layer altered after verification is refused when read for printing."""
    manifest = load_verified(stack)
    path = stack / layer_file_name(1)
    data = bytearray(path.read_bytes())
    data[-1] ^= 1
    path.write_bytes(bytes(data))
    with pytest.raises(VerifyError, match="sha256 does not match"):
        read_layer_mask(stack, manifest, 1)


def test_decode_mask_of_a_channel_file(stack):
    """decode_mask without a mode reads any non-zero sample as solid (as the printer reads channels)."""
    manifest = read_manifest(stack)
    shape = (manifest["image"]["height"], manifest["image"]["width"])
    grey = np.zeros(shape, np.uint8)
    grey[2:5, 3:9] = 17
    path = stack / "layer_00000_m1.tif"
    path.write_bytes(encode_tiff(grey, (100, 100), "lzw"))
    np.testing.assert_array_equal(decode_mask(path, manifest), grey > 0)


def test_droplet_masks_must_partition_the_layer(tmp_path, run_cli):
    """A graded stack with droplet masks verifies clean; a mask replaced by another (hash updated) is
    reported as pixels jetted twice and as solid pixels in no mask, each naming its first pixel."""
    model = tmp_path / "vase.ply"
    procedural.vase(rings_outer=10, rings_inner=8, sections=24).export(model)
    directory = tmp_path / "graded"
    code, _, err = run_cli("slice", model, "-o", directory, "--layer", "5", "--dpi", "100",
                           "--grade", "linear", "--channels")
    assert code == 0, err
    assert verify_stack(directory).ok, verify_stack(directory).problems
    manifest = read_manifest(directory)
    first, second = manifest["layers"][4]["channels"][:2]
    (directory / second["file"]).write_bytes((directory / first["file"]).read_bytes())
    edit_manifest(directory, lambda m: m["layers"][4]["channels"][1].update(
        sha256=first["sha256"], solid_pixels=first["solid_pixels"]))
    found = problems(directory)
    assert any(line.startswith(f"layer 4: {first['solid_pixels']} pixel(s) in two or more droplet masks, first at "
                               "pixel x ") for line in found), found
    assert any(line.startswith(f"layer 4: {second['solid_pixels']} solid pixel(s) in no droplet mask, first at ")
               for line in found), found


@pytest.fixture(scope="module")
def graded_vase(tmp_path_factory) -> Path:
    """A small graded vase with two droplet masks a layer (M1, M2), 5 mm layers at 100 dpi."""
    from heoslice.cli import main

    folder = tmp_path_factory.mktemp("graded")
    model = folder / "vase.ply"
    procedural.vase(rings_outer=10, rings_inner=8, sections=24).export(model)
    try:
        main(["slice", str(model), "-o", str(folder / "stack"), "--layer", "5", "--dpi", "100", "--grade", "linear",
              "--channels"])
    except SystemExit as done:
        assert done.code in (0, None)
    return folder / "stack"


def one_material_layer(directory: Path, index: int, other: str) -> tuple[dict, dict]:
    """Make layer ``index``'s first droplet mask its layer's own file, byte for byte (as a part of one material
    writes it), hash and count updated; the other mask is left as it is (``other`` 'kept') or made blank
    ('blank'). Returns the layer entry and its masks' entries as they were."""
    manifest = read_manifest(directory)
    entry = manifest["layers"][index]
    first, second = entry["channels"][:2]
    (directory / first["file"]).write_bytes((directory / entry["file"]).read_bytes())
    blank = None
    if other == "blank":
        from heoslice.stack import encode_bilevel_tiff

        image = manifest["image"]
        rows = np.zeros((image["height"], -(-image["width"] // 8)), np.uint8)
        blank = encode_bilevel_tiff(rows, image["width"], tuple(manifest["dpi"]), "deflate")
        (directory / second["file"]).write_bytes(blank)

    def change(m: dict) -> None:
        masks = m["layers"][index]["channels"]
        masks[0].update(sha256=entry["sha256"], solid_pixels=entry["solid_pixels"])
        if blank is not None:
            masks[1].update(sha256=hashlib.sha256(blank).hexdigest(), solid_pixels=0)

    edit_manifest(directory, change)
    return entry, second


def test_a_mask_that_is_its_layers_file_is_checked_against_the_other_masks(graded_vase, tmp_path):
    """A layer whose first droplet mask is its own file byte for byte (read once, its bits shared) verifies
    clean when the other mask is blank, and when the other mask still holds pixels they are reported as jetted
    twice (not taken as a partition)."""
    blank, kept = tmp_path / "blank", tmp_path / "kept"
    for copy in (blank, kept):
        shutil.copytree(graded_vase, copy)
    one_material_layer(blank, 4, "blank")
    assert verify_stack(blank).ok, verify_stack(blank).problems
    _, second = one_material_layer(kept, 4, "kept")
    assert second["solid_pixels"] > 0, "the test needs a layer using both materials"
    found = problems(kept)
    assert any(line.startswith(f"layer 4: {second['solid_pixels']} pixel(s) in two or more droplet masks")
               for line in found), found


def test_verify_works_on_the_layers_also_names_from_their_checked_bits(graded_vase, tmp_path):
    """verify_stack's ``also`` is given the manifest, and its work runs on each layer it names that passes its
    check, with the bits layer_bits reads (the layer's, then its masks'); a layer with a problem gets no work."""
    from heoslice.stack.packed import layer_bits

    def also(manifest: dict):
        assert manifest["layers"][0]["index"] == 0
        return [1, 4], lambda index, bits: [bits[0].rows.copy(), *(b.rows.copy() for b in bits[1:])]

    report = verify_stack(graded_vase, also=also)
    assert report.ok and sorted(report.also) == [1, 4]
    manifest = read_manifest(graded_vase)
    for index, rows in report.also.items():
        solid, masks = layer_bits(graded_vase, manifest, index)
        assert all(np.array_equal(got, want.rows) for got, want in zip(rows, [solid, *masks], strict=True))
    broken = tmp_path / "broken"
    shutil.copytree(graded_vase, broken)
    edit_manifest(broken, lambda m: m["layers"][4].update(solid_pixels=m["layers"][4]["solid_pixels"] + 1))
    report = verify_stack(broken, also=also)
    assert not report.ok and sorted(report.also) == [1]


def test_read_small_regular_reads_a_small_file_and_refuses_a_fifo_without_waiting(tmp_path):
    """A regular file of at most ``most`` bytes is read whole, a larger one is left to the careful reader (None),
    and a FIFO planted in its place is refused at once (opened without blocking), naming the file."""
    from heoslice.stack.read import read_small_regular

    path = tmp_path / "layer_00000.tif"
    path.write_bytes(b"x" * 100)
    assert read_small_regular(path, "layer_00000.tif", 100) == b"x" * 100
    assert read_small_regular(str(path), "layer_00000.tif", 99) is None
    fifo = tmp_path / "layer_00001.tif"
    os.mkfifo(fifo)
    with pytest.raises(VerifyError, match="layer_00001.tif: is not a regular file"):
        read_small_regular(fifo, "layer_00001.tif", 100)
