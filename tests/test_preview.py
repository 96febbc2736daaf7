"""Tests of heoslice.preview and `heoslice preview`: one layer and contact sheets, read through the stack checks."""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile
from helpers import stack_without_material_colours
from PIL import Image

from heoslice import procedural
from heoslice.errors import InputError
from heoslice.preview import channels_rgb, layer_image, layer_rgb, parse_layers
from heoslice.preview.annotate import MIN_FOOTER_WIDTH
from heoslice.preview.sheet import layer_aspect, tile_box


@pytest.fixture(scope="module")
def stacks(tmp_path_factory):
    """A 1-bit and a graded RGBA stack of a 4 mm ball, 1 mm layers."""
    from heoslice.cli import main

    def run(args):
        try:
            main(args)
        except SystemExit as done:
            assert done.code in (0, None)

    folder = tmp_path_factory.mktemp("stacks")
    mesh = folder / "ball.ply"
    procedural.sphere(4.0, subdivisions=3).export(mesh)
    for name, extra in (("plain", []), ("graded", ["--grade", "linear", "--to", "0,255,0"])):
        run(["slice", str(mesh), "--layer", "1", "-o", str(folder / name), *extra])
        assert (folder / name / "manifest.json").is_file()
    return folder / "plain", folder / "graded"


@pytest.fixture(scope="module")
def channels_stack(tmp_path_factory):
    """A graded stack with droplet masks (--channels, white M1 to green M2) of a 4 mm ball, 1 mm layers."""
    from heoslice.cli import main

    folder = tmp_path_factory.mktemp("channels")
    mesh = folder / "ball.ply"
    procedural.sphere(4.0, subdivisions=3).export(mesh)
    try:
        main(["slice", str(mesh), "--layer", "1", "--grade", "linear", "--to", "0,255,0", "--channels",
              "-o", str(folder / "stack")])
    except SystemExit as done:
        assert done.code in (0, None)
    return folder / "stack"


def copy_stack(source, target):
    """A copy of a stack directory's files (to alter)."""
    target.mkdir()
    for item in source.iterdir():
        (target / item.name).write_bytes(item.read_bytes())
    return target


def test_parse_layers():
    """N, lists and START:STOP[:STEP] ranges (stop excluded, open ends) are understood; others refused."""
    assert parse_layers("3", 10) == [3]
    assert parse_layers("1,4,2", 10) == [1, 4, 2]
    assert parse_layers("0:10:3", 10) == [0, 3, 6, 9]
    assert parse_layers("5:", 8) == [5, 6, 7]
    assert parse_layers(":100:40", 90) == [0, 40, 80]
    for bad in ("x", "1:2:0", "12", "-1", "3:3"):
        with pytest.raises(InputError):
            parse_layers(bad, 10)


def test_layer_rgb_composites_rgba_over_dark_and_bits_on_white():
    """RGBA pixels are shown over dark grey (alpha 0 -> (32, 32, 32), white material stays visible);
    1-bit solid pixels dark grey on white."""
    rgba = np.array([[[0, 255, 0, 255], [0, 255, 0, 0], [255, 255, 255, 255]]], dtype=np.uint8)
    assert layer_rgb(rgba).tolist() == [[[0, 255, 0], [32, 32, 32], [255, 255, 255]]]
    bits = np.array([[True, False]])
    assert layer_rgb(bits).tolist() == [[[64, 64, 64], [255, 255, 255]]]


def test_preview_one_layer(run_cli, stacks, tmp_path):
    """`preview STACK --layer N -o F.png` writes the layer at full size: solid pixels coloured, the rest dark."""
    _, graded = stacks
    manifest = json.loads((graded / "manifest.json").read_text())
    target = tmp_path / "layer.png"
    code, stdout, stderr = run_cli("preview", graded, "--layer", "4", "-o", target)
    assert code == 0, stderr
    image = np.asarray(Image.open(target))
    height, width = manifest["image"]["height"], manifest["image"]["width"]
    assert image.shape[0] > height and image.shape[1] >= width  # the annotation footer below the layer
    image = image[:height, :width]
    assert (image == 32).all(axis=2).any()  # empty pixels
    assert (image[..., 1] > image[..., 0] + 50).any()  # green interior


def test_preview_size_and_sheet(run_cli, stacks, tmp_path):
    """--size bounds a single layer's longer side; --sheet lays out the chosen layers in a grid of tiles."""
    plain, _ = stacks
    small = tmp_path / "small.png"
    assert run_cli("preview", plain, "--layer", "3", "--size", "64", "-o", small)[0] == 0
    assert max(layer_image(plain, 3, 64).size) == 64
    assert Image.open(small).size[0] == max(64, MIN_FOOTER_WIDTH)  # the footer's width
    sheet = tmp_path / "sheet.png"
    code, _, stderr = run_cli("preview", plain, "--sheet", "--layers", "0:8:2", "--tile", "64", "--columns", "2",
                              "-o", sheet)
    assert code == 0, stderr
    box_width, box_height = tile_box(64, layer_aspect(json.loads((plain / "manifest.json").read_text())))
    assert max(box_width, box_height) == 64
    assert Image.open(sheet).size == (2 * (box_width + 4) + 4, 2 * (box_height + 14 + 4) + 4)


def test_preview_sheet_says_when_layers_are_clipped(run_cli, stacks, tmp_path):
    """A --layers range past the stack's last layer is clipped with one warning naming the layers shown; a range
    inside the stack gives none."""
    plain, _ = stacks
    count = len(json.loads((plain / "manifest.json").read_text())["layers"])
    code, _, stderr = run_cli("preview", plain, "--sheet", "--layers", "0:1000", "--tile", "32",
                              "-o", tmp_path / "all.png")
    assert code == 0, stderr
    assert stderr.count("warning:") == 1
    assert f"clipped to layers 0..{count - 1}" in stderr and "0:1000" in stderr
    code, _, stderr = run_cli("preview", plain, "--sheet", "--layers", f"0:{count}", "--tile", "32",
                              "-o", tmp_path / "exact.png")
    assert code == 0 and stderr == ""


def test_preview_refuses_altered_and_missing(run_cli, stacks, tmp_path):
    """An altered layer file fails its sha256 check (exit 4, one line); a missing layer number is exit 2;
    a directory that is not a stack is refused."""
    plain, _ = stacks
    copy = tmp_path / "copy"
    copy.mkdir()
    for item in plain.iterdir():
        (copy / item.name).write_bytes(item.read_bytes())
    manifest = json.loads((copy / "manifest.json").read_text())
    victim = copy / manifest["layers"][2]["file"]
    data = bytearray(victim.read_bytes())
    data[-1] ^= 0xFF
    victim.write_bytes(bytes(data))
    code, _, stderr = run_cli("preview", copy, "--layer", "2", "-o", tmp_path / "x.png")
    assert code == 4 and "sha256" in stderr and len(stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x.png").exists()
    assert run_cli("preview", plain, "--layer", "999", "-o", tmp_path / "y.png")[0] == 2
    assert run_cli("preview", tmp_path, "--layer", "0", "-o", tmp_path / "z.png")[0] == 4
    assert run_cli("preview", plain, "--layer", "1", "-o", tmp_path / "z.jpg")[0] == 2


def test_preview_of_masks_without_colours_names_the_manifest(run_cli, channels_stack, tmp_path):
    """Droplet masks whose materials have no colour in the manifest: one line naming the manifest file and
    the layer, exit 4, no image written (a layer, a sheet and a section alike)."""
    copy = stack_without_material_colours(channels_stack, tmp_path / "copy")
    for extra in (["--layer", "1"], ["--sheet"], ["--section", "y=0"]):
        code, _, stderr = run_cli("preview", copy, *extra, "-o", tmp_path / "x.png")
        assert code == 4 and len(stderr.strip().splitlines()) == 1, stderr
        assert str(copy / "manifest.json") in stderr and "no [r, g, b] colour" in stderr
        assert not (tmp_path / "x.png").exists()


def test_channels_rgb_paints_each_mask_in_its_colour():
    """Each set pixel of mask m takes colour m; pixels in no mask are the dark RGBA background."""
    masks = np.array([[[True, False, False]], [[False, True, False]]])
    colors = np.array([[240, 240, 240], [0, 255, 0]], dtype=np.uint8)
    assert channels_rgb(masks, colors).tolist() == [[[240, 240, 240], [0, 255, 0], [32, 32, 32]]]


def test_preview_channels_in_material_colours(run_cli, channels_stack, tmp_path):
    """A layer with droplet masks previews at full size with every set pixel of material m's mask (read
    independently with tifffile) in grading.materials[m].color and every other pixel dark; both
    materials occur in the layer, so the check covers both colours."""
    manifest = json.loads((channels_stack / "manifest.json").read_text())
    assert manifest["image"]["mode"] == "1"
    index = len(manifest["layers"]) // 2
    target = tmp_path / "layer.png"
    code, _, stderr = run_cli("preview", channels_stack, "--layer", index, "-o", target)
    assert code == 0, stderr
    image = np.asarray(Image.open(target).convert("RGB"))[:manifest["image"]["height"], :manifest["image"]["width"]]
    colors = {m["name"]: m["color"] for m in manifest["grading"]["materials"]}
    covered = np.zeros(image.shape[:2], dtype=bool)
    for channel in manifest["layers"][index]["channels"]:
        mask = tifffile.imread(channels_stack / channel["file"]).astype(bool)
        assert mask.any()
        assert (image[mask] == colors[channel["material"]]).all()
        covered |= mask
    assert (image[~covered] == 32).all()


def test_preview_channels_reduced_and_sheet(run_cli, channels_stack, tmp_path):
    """Reduced previews box-filter the composed colours (a dithered white/green mix stays greenish-light,
    never the grey of a plain 1-bit layer); a contact sheet of a --channels stack is written."""
    small = tmp_path / "small.png"
    assert run_cli("preview", channels_stack, "--layer", "4", "--size", "32", "-o", small)[0] == 0
    drawn_width, drawn_height = layer_image(channels_stack, 4, 32).size
    assert max(drawn_width, drawn_height) == 32
    pixels = np.asarray(Image.open(small).convert("RGB")).astype(int)[:drawn_height, :drawn_width]
    assert (pixels[..., 1] > pixels[..., 0] + 30).any()
    sheet = tmp_path / "sheet.png"
    code, _, stderr = run_cli("preview", channels_stack, "--sheet", "--layers", "2:6", "--tile", "64",
                              "--columns", "2", "-o", sheet)
    assert code == 0, stderr
    image = np.asarray(Image.open(sheet).convert("RGB")).astype(int)
    box_width, box_height = tile_box(64, layer_aspect(json.loads((channels_stack / "manifest.json").read_text())))
    assert image.shape == (2 * (box_height + 14 + 4) + 4, 2 * (box_width + 4) + 4, 3)
    assert (image[..., 1] > image[..., 0] + 30).sum() > 100


def test_preview_refuses_altered_channels(run_cli, channels_stack, tmp_path):
    """An altered droplet mask fails its sha256 check, for one layer, a sheet and any other layer (exit 4, one
    line, no PNG: preview shares verify's check); masks that do not cover the layer's solid pixels once each, or a material without a
    colour in grading.materials, are refused the same way."""
    copy = copy_stack(channels_stack, tmp_path / "copy")
    manifest = json.loads((copy / "manifest.json").read_text())
    victim = copy / manifest["layers"][2]["channels"][1]["file"]
    data = bytearray(victim.read_bytes())
    data[-1] ^= 0xFF
    victim.write_bytes(bytes(data))
    for args in (("--layer", "2"), ("--sheet", "--layers", "0:4")):
        code, _, stderr = run_cli("preview", copy, *args, "-o", tmp_path / "x.png")
        assert code == 4 and "sha256" in stderr and victim.name in stderr, stderr
        assert len(stderr.strip().splitlines()) == 1
        assert not (tmp_path / "x.png").exists()
    code, _, stderr = run_cli("preview", copy, "--layer", "3", "-o", tmp_path / "other.png")
    assert code == 4 and victim.name in stderr, stderr  # verify's check: another layer's damage refuses too

    swapped = copy_stack(channels_stack, tmp_path / "swapped")
    manifest = json.loads((swapped / "manifest.json").read_text())
    manifest["layers"][3]["channels"][1] = manifest["layers"][1]["channels"][1]
    (swapped / "manifest.json").write_text(json.dumps(manifest))
    code, _, stderr = run_cli("preview", swapped, "--layer", "3", "-o", tmp_path / "y.png")
    assert code == 4 and "listed twice" in stderr and len(stderr.strip().splitlines()) == 1

    uncoloured = copy_stack(channels_stack, tmp_path / "uncoloured")
    manifest = json.loads((uncoloured / "manifest.json").read_text())
    manifest["grading"]["materials"][0]["color"] = "white"
    (uncoloured / "manifest.json").write_text(json.dumps(manifest))
    code, _, stderr = run_cli("preview", uncoloured, "--layer", "3", "-o", tmp_path / "z.png")
    assert code == 4 and "grading.materials" in stderr and len(stderr.strip().splitlines()) == 1


def test_more_columns_than_tiles_lay_them_on_one_row():
    """--columns beyond the number of layers lays them all on one row (no empty columns), instead of refusing a
    sheet too wide."""
    from heoslice.preview.sheet import sheet_size

    columns, width, height = sheet_size(11, 1024, 400)
    assert columns == 11 and (width, height) == sheet_size(11, 1024, 11)[1:]


@pytest.mark.parametrize("options, problem", [(("--sheet", "--size", "100"), "--size: a sheet's tiles are sized by --tile"),
                                              (("--layer", "1", "--tile", "100"), "--tile: only used with --sheet"),
                                              (("--layer", "1", "--columns", "3"), "--columns: only used with --sheet")])
def test_preview_options_the_drawing_does_not_use_are_refused(tmp_path, run_cli, options, problem):
    """--size with --sheet, --tile or --columns without it: one line naming the option and why, exit 2, not ignored."""
    from heoslice import procedural

    procedural.box((6.0, 6.0, 2.0)).export(tmp_path / "box.ply")
    assert run_cli("slice", tmp_path / "box.ply", "--layer", "1", "--dpi", "50", "-o", tmp_path / "stack")[0] == 0
    code, out, err = run_cli("preview", tmp_path / "stack", *options, "-o", tmp_path / "p.png")
    assert code == 2 and err.count("\n") == 1 and problem in err, err
    assert not (tmp_path / "p.png").exists()
