"""`heoslice export --format voxel-print` and `--format png`, through the command line: a Voxel Print folder
with sequential slice names, 600 x 300 dpi, one exact colour per material and none blended; clear refusals."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest
from helpers import heoslice, in_process, stack_without_material_colours
from PIL import Image

from heoslice import procedural
from heoslice.stack import read_layer_channels, read_layer_mask, read_manifest


@pytest.fixture(scope="module")
def stacks(tmp_path_factory):
    """A graded ball with droplet masks (two materials) and the same ball graded without (RGBA)."""
    folder = tmp_path_factory.mktemp("export")
    procedural.sphere(4.0, subdivisions=3).export(folder / "ball.ply")
    for name, extra in (("masks", ["--channels"]), ("rgba", ["--rgba"])):
        assert in_process("slice", folder / "ball.ply", "--layer", "1", "--dpi", "200", "--grade", "linear",
                          "--to", "0,255,0", "-o", folder / name, *extra) == 0
    return folder


def test_voxel_print_folder_naming_resolution_palette_and_one_material_per_pixel(stacks, tmp_path):
    """Slices slice_00000.png.. bottom first, one per 0.027 mm of the part; each 600 x 300 dpi RGB of the
    part's extent; only the background and the materials' exact colours; every solid voxel (the stack's
    nearest layer and pixel) exactly its material's colour, every empty one the background."""
    out = tmp_path / "voxels"
    done = heoslice("export", stacks / "masks", "--format", "voxel-print", "-o", out, "--json")
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    manifest = read_manifest(stacks / "masks")
    z_min, z_max = manifest["z_range_mm"]
    count = int(np.ceil((z_max - z_min) / 0.027 - 1e-9))
    names = sorted(p.name for p in out.glob("*.png"))
    assert names == [f"slice_{k:05d}.png" for k in range(count)] and summary["slices"] == count
    width = round(manifest["image"]["width"] * manifest["pixel_size_mm"][0] / (25.4 / 600))
    height = round(manifest["image"]["height"] * manifest["pixel_size_mm"][1] / (25.4 / 300))
    colours = {m["name"]: tuple(m["color"]) for m in manifest["grading"]["materials"]}
    palette = [tuple(m["color"]) for m in json.loads((out / "voxelprint.json").read_text())["materials"]]
    assert palette == [colours[c["material"]] for c in manifest["layers"][0]["channels"]]
    assert len(set(palette) | {(0, 0, 0)}) == len(palette) + 1
    columns = np.minimum(((np.arange(width) + 0.5) * (25.4 / 600) / manifest["pixel_size_mm"][0]).astype(int),
                         manifest["image"]["width"] - 1)
    rows = np.minimum(((np.arange(height) + 0.5) * (25.4 / 300) / manifest["pixel_size_mm"][1]).astype(int),
                      manifest["image"]["height"] - 1)
    for k in (0, count // 3, count // 2, count - 1):
        image = Image.open(out / f"slice_{k:05d}.png")
        assert image.mode == "RGB" and image.size == (width, height)
        assert tuple(round(v) for v in image.info["dpi"]) == (600, 300)
        pixels = np.asarray(image)
        layer = min(int((k + 0.5) * 0.027 / manifest["layer_height_mm"]), len(manifest["layers"]) - 1)
        solid = read_layer_mask(stacks / "masks", manifest, layer)[np.ix_(rows, columns)]
        masks = read_layer_channels(stacks / "masks", manifest, layer)[:, rows][:, :, columns]
        assert solid.any()
        assert (pixels[~solid] == 0).all()
        matches = np.stack([(pixels == colour).all(axis=-1) for colour in palette])
        assert (matches.sum(axis=0)[solid] == 1).all()
        assert np.array_equal(matches, masks)


def test_voxel_print_refuses_what_it_cannot_honour(stacks, tmp_path):
    """Blended RGBA colours and a material coloured like the background: one line, exit 2, nothing written."""
    done = heoslice("export", stacks / "rgba", "--format", "voxel-print", "-o", tmp_path / "a")
    assert done.returncode == 2 and "--rgba" in done.stderr and done.stderr.count("\n") == 1
    colour = read_manifest(stacks / "masks")["grading"]["materials"][0]["color"]
    done = heoslice("export", stacks / "masks", "--format", "voxel-print", "-o", tmp_path / "b",
                    "--background", ",".join(map(str, colour)))
    assert done.returncode == 2 and "--background" in done.stderr
    done = heoslice("export", stacks / "masks", "--format", "voxel-print", "-o", tmp_path / "c", "--pitch", "0")
    assert done.returncode == 2 and "--pitch" in done.stderr
    assert not any(tmp_path.iterdir())


def test_voxel_print_of_masks_without_colours_names_the_manifest(stacks, tmp_path):
    """A droplet-mask stack whose manifest lists no material colours (edited by hand): one line naming its
    manifest file, exit 2, nothing written."""
    copy = stack_without_material_colours(stacks / "masks", tmp_path / "copy")
    done = heoslice("export", copy, "--format", "voxel-print", "-o", tmp_path / "out")
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert str(copy / "manifest.json") in done.stderr and "no [r, g, b] colour" in done.stderr
    assert not (tmp_path / "out").exists()


def test_voxel_print_refuses_a_layer_whose_masks_are_not_the_first_layers(stacks, tmp_path):
    """A hand-edited stack whose first layer lists no droplet masks and whose manifest names no materials (so
    verify has no order to hold the masks to, and passes) would colour the other layers' two masks from a palette
    of one material (before: a crash of the export's worker): one line naming the manifest and layer 1, exit 2,
    nothing written."""
    copy = tmp_path / "copy"
    copy.mkdir()
    for item in (stacks / "masks").iterdir():
        (copy / item.name).write_bytes(item.read_bytes())
    manifest = json.loads((copy / "manifest.json").read_text())
    for channel in manifest["layers"][0].pop("channels"):
        (copy / channel["file"]).unlink()
    manifest["grading"]["materials"] = None
    (copy / "manifest.json").write_text(json.dumps(manifest))
    assert heoslice("verify", copy).returncode == 0
    done = heoslice("export", copy, "--format", "voxel-print", "-o", tmp_path / "out")
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert str(copy / "manifest.json") in done.stderr and "layer 1 has droplet masks (M1, M2)" in done.stderr
    assert not (tmp_path / "out").exists()


def test_png_zip_holds_every_layer_and_the_manifest(stacks, tmp_path):
    """`--format png -o X.zip`: one PNG per layer image and droplet mask at the stack's size, solid black
    on white as in the TIFFs, with manifest.json beside them."""
    done = heoslice("export", stacks / "masks", "--format", "png", "-o", tmp_path / "layers.zip")
    assert done.returncode == 0, done.stderr
    manifest = read_manifest(stacks / "masks")
    with zipfile.ZipFile(tmp_path / "layers.zip") as archive:
        names = set(archive.namelist())
        assert json.loads(archive.read("manifest.json")) == manifest
        expected = {e["file"][:-4] + ".png" for e in manifest["layers"]}
        expected |= {c["file"][:-4] + ".png" for e in manifest["layers"] for c in e["channels"]}
        assert names == expected | {"manifest.json"}
        with archive.open("layer_00004.png") as handle:
            shown = np.asarray(Image.open(handle).convert("L"))
    solid = read_layer_mask(stacks / "masks", manifest, 4)
    assert shown.shape == solid.shape and (shown[solid] == 0).all() and (shown[~solid] == 255).all()


def test_sampled_labels_are_the_whole_layers_labels_sampled(stacks):
    """labels_of a layer's packed label planes (as the exports read them), unpacking only the sampled rows, gives
    at every sampled pixel the label of the whole decoded layer (tifffile's masks through read_layer_mask /
    read_layer_channels)."""
    from heoslice.export.voxel_print import label_planes, labels_of, sample_indices
    from heoslice.stack.packed import layer_bits

    def layer_labels(stack, manifest, index, rows=None, columns=None):
        planes = label_planes(*layer_bits(stack, manifest, index, solid=not manifest["layers"][index]["channels"]))
        return labels_of(planes, manifest["image"]["width"], rows, columns)

    stack = stacks / "masks"
    manifest = read_manifest(stack)
    image, (px, py) = manifest["image"], manifest["pixel_size_mm"]
    rows = sample_indices(image["height"], py, 25.4 / 300.0, round(image["height"] * py * 300.0 / 25.4))
    columns = sample_indices(image["width"], px, 25.4 / 600.0, round(image["width"] * px * 600.0 / 25.4))
    for index in range(len(manifest["layers"])):
        whole = read_layer_mask(stack, manifest, index).astype(np.uint8)
        for number, mask in enumerate(read_layer_channels(stack, manifest, index)):
            whole[mask] = number + 1
        assert np.array_equal(layer_labels(stack, manifest, index, rows, columns), whole[np.ix_(rows, columns)])
        assert np.array_equal(layer_labels(stack, manifest, index), whole)


@pytest.mark.parametrize("planes_count, samples", [(1, 3), (2, 3), (2, 4), (3, 3)])
def test_slice_scanlines_colour_each_sampled_pixel_by_its_label(planes_count, samples):
    """slice_scanlines (a table per packed byte for up to two planes, labels otherwise; background rows off the
    planes' span) gives, after a zero filter byte, colours[label] of each sampled pixel, the label the last
    plane holding it, on random planes of a width that is not a multiple of 8 with blank rows around them."""
    from heoslice.export.voxel_print import slice_scanlines
    from heoslice.stack.packed import Bits

    rng = np.random.default_rng(planes_count * 10 + samples)
    height, width = 40, 61
    masks = rng.random((planes_count, height, width)) < 0.4
    masks[:, :7] = masks[:, 31:] = False
    planes = [Bits(np.packbits(mask, axis=1), (7, 31)) for mask in masks]
    colours = rng.integers(0, 256, (planes_count + 1, samples), dtype=np.uint8)
    labels = np.zeros((height, width), dtype=np.uint8)
    for number, mask in enumerate(masks, 1):
        labels[mask] = number
    rows = np.array([0, 3, 7, 8, 8, 20, 30, 31, 39])
    for columns in (np.arange(width), np.array([0, 5, 5, 60])):
        out = slice_scanlines(planes, width, rows, columns, colours)
        assert (out[:, 0] == 0).all()
        assert np.array_equal(out[:, 1:].reshape(len(rows), len(columns), samples), colours[labels[np.ix_(rows, columns)]])


def image_data(png: bytes) -> bytes:
    """The zlib stream of a PNG's image data (its IDAT chunks joined)."""
    at, data = 8, b""
    while at < len(png):
        length = int.from_bytes(png[at:at + 4], "big")
        if png[at + 4:at + 8] == b"IDAT":
            data += png[at + 8:at + 8 + length]
        at += 12 + length
    return data


@pytest.mark.parametrize("columns_step", [1.0, 0.7, 2.5])
def test_a_slice_of_long_runs_is_written_from_runs_and_one_of_noise_from_its_rows(columns_step):
    """slice_png writes a slice of long runs (two parts, rows off them) from its runs (the zlib header 78 01 of
    run_stream) and one of random pixels (a dither) from its coloured rows by zlib-ng (not 78 01); either way
    the PNG is RGB and decodes to colours[label] of each sampled pixel, the label the last plane holding it."""
    from heoslice.export.voxel_print import slice_png
    from heoslice.stack.packed import Bits

    height, width = 300, 1001
    yy, xx = np.mgrid[:height, :width]
    parts = np.stack([(yy - 150) ** 2 + (xx - 500) ** 2 < 120 ** 2, (yy - 150) ** 2 + (xx - 530) ** 2 < 40 ** 2])
    noise = np.random.default_rng(1).random((2, height, width)) < 0.3
    colours = np.array([[0, 0, 0], [240, 240, 240], [0, 255, 0]], dtype=np.uint8)
    rows = np.arange(0, height, 2)
    columns = np.minimum((np.arange(int(width / columns_step)) * columns_step).astype(np.int64), width - 1)
    for masks, from_runs in ((parts, True), (noise, False)):
        planes = [Bits(np.packbits(mask, axis=1), (0, height)) for mask in masks]
        png = slice_png(planes, width, rows, columns, colours, (600.0, 300.0))
        assert (image_data(png)[:2] == b"\x78\x01") == from_runs
        labels = np.where(masks[1], 2, np.where(masks[0], 1, 0))[np.ix_(rows, columns)]
        image = Image.open(io.BytesIO(png))
        assert image.mode == "RGB" and np.array_equal(np.asarray(image), colours[labels])


def test_a_parts_stack_exports_every_slice_from_runs_exactly(tmp_path):
    """A two-part stack (a ball inside a ball, --parts, one material each) exports every slice from its runs,
    each pixel the colour of the material of the stack pixel and layer it samples, black where empty."""
    procedural.sphere(4.0, subdivisions=3).export(tmp_path / "outer.ply")
    procedural.sphere(1.5, subdivisions=3).export(tmp_path / "inner.ply")
    stack = tmp_path / "stack"
    assert in_process("slice", tmp_path / "outer.ply", tmp_path / "inner.ply", "--parts", "--part", "outer=M1",
                      "--part", "inner=M2", "--layer", "0.5", "--dpi", "150", "-o", stack) == 0
    out = tmp_path / "voxels"
    assert in_process("export", stack, "--format", "voxel-print", "-o", out) == 0
    from heoslice.export.voxel_print import printer_grid

    manifest = read_manifest(stack)
    width, height, slices, columns, rows, sources = printer_grid(manifest, (600.0, 300.0), 0.027)
    palette = np.array([(0, 0, 0)] + [m["color"] for m in json.loads((out / "voxelprint.json").read_text())
                                      ["materials"]], dtype=np.uint8)
    assert len(palette) == 3
    for number in range(slices):
        png = (out / f"slice_{number:05d}.png").read_bytes()
        assert image_data(png)[:2] == b"\x78\x01"
        masks = read_layer_channels(stack, manifest, int(sources[number]))[:, rows][:, :, columns]
        labels = np.where(masks[1], 2, np.where(masks[0], 1, 0))
        assert np.array_equal(np.asarray(Image.open(io.BytesIO(png))), palette[labels]), number


def test_export_refuses_a_stack_with_a_bad_layer_and_writes_nothing(tmp_path):
    """An export checks every layer as it reads it: a layer file altered after slicing (its sha256 no longer the
    manifest's), even one no slice samples (layers 0.3 mm, pitch 1 mm), stops voxel-print and png with exit 4
    and one line naming the file; no output appears and an earlier export given with --force is kept as it was."""
    procedural.sphere(3.0, subdivisions=2).export(tmp_path / "ball.ply")
    stack = tmp_path / "stack"
    assert in_process("slice", tmp_path / "ball.ply", "--layer", "0.3", "--dpi", "100", "-o", stack) == 0
    done = heoslice("export", stack, "--format", "voxel-print", "--pitch", "1", "-o", tmp_path / "old")
    assert done.returncode == 0, done.stderr
    before = sorted((p.name, p.read_bytes()) for p in (tmp_path / "old").iterdir())
    manifest = read_manifest(stack)
    from heoslice.export.voxel_print import printer_grid

    sources = printer_grid(manifest, (600.0, 300.0), 1.0)[-1]
    unsampled = sorted(set(range(len(manifest["layers"]))) - set(sources.tolist()))
    assert unsampled
    victim = stack / manifest["layers"][unsampled[len(unsampled) // 2]]["file"]
    data = bytearray(victim.read_bytes())
    data[-1] ^= 0xFF
    victim.write_bytes(bytes(data))
    for output, extra in ((tmp_path / "old", ["--format", "voxel-print", "--pitch", "1", "--force"]),
                          (tmp_path / "new", ["--format", "voxel-print", "--pitch", "1"]),
                          (tmp_path / "png.zip", ["--format", "png"])):
        done = heoslice("export", stack, *extra, "-o", output)
        assert done.returncode == 4 and done.stderr.count("\n") == 1 and victim.name in done.stderr, done.stderr
    assert sorted((p.name, p.read_bytes()) for p in (tmp_path / "old").iterdir()) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ball.ply", "old", "stack"]


@pytest.mark.parametrize("colours, advice", [
    ({"M1": [0, 0, 0], "M2": [0, 255, 0]}, "give it another colour in the materials file"),
    ({"M1": [0, 255, 0], "M2": [0, 255, 0]}, "give one of them another colour in the materials file"),
])
def test_materials_an_export_cannot_tell_apart_say_what_to_change(colours, advice):
    """A material coloured as the background (black, a .gcvf's fixed one) or two materials of one colour: one line
    naming the manifest and what to change (the materials' colours; --background only where the format takes
    one), not advice that the format refuses."""
    from heoslice.errors import InputError
    from heoslice.export.voxel_print import palette

    manifest = {"layers": [{"channels": [{"material": "M1"}, {"material": "M2"}]}],
                "grading": {"materials": [{"name": name, "color": colour} for name, colour in colours.items()]}}
    with pytest.raises(InputError, match=advice) as raised:
        palette(manifest, (0, 0, 0), "st/manifest.json")
    assert str(raised.value).startswith("st/manifest.json: material ") and "\n" not in str(raised.value)
