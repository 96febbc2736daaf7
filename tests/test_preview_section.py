"""`heoslice preview --section x=MM / y=MM`, through the command line: a vertical cut in material colours at
true aspect ratio, bottom layer at the bottom; positions outside the stack refused in one line."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from helpers import heoslice, in_process
from PIL import Image

from heoslice import procedural
from heoslice.stack.tiff import encode_bilevel_tiff


def test_section_of_a_z_graded_box_shows_the_gradient_at_true_aspect(tmp_path):
    """A 10 x 10 x 20 mm box coloured by `color --func linear` along z, cut at x=5 and y=5: an image of
    the part's width by twice that height (20 mm of layers against 10 mm across), its contour colour
    changing from the bottom row to the top row; --json reports the size; x=50 is outside: exit 2 naming --section."""
    procedural.box(extents=(10.0, 10.0, 20.0)).export(tmp_path / "box.ply")
    assert in_process("color", tmp_path / "box.ply", "--func", "linear", "-o", tmp_path / "coloured.ply") == 0
    model = tmp_path / "coloured.ply"
    assert in_process("slice", model, "--layer", "0.5", "--dpi", "50", "--margin", "0", "-o", tmp_path / "s") == 0
    manifest = json.loads((tmp_path / "s" / "manifest.json").read_text())
    for axis in ("x", "y"):
        done = heoslice("preview", tmp_path / "s", "--section", f"{axis}=5", "-o", tmp_path / f"{axis}.png", "--json")
        assert done.returncode == 0, done.stderr
        reported = json.loads(done.stdout)
        image = np.asarray(Image.open(tmp_path / f"{axis}.png"))
        across = manifest["image"]["height" if axis == "x" else "width"]
        pixel = manifest["pixel_size_mm"][1 if axis == "x" else 0]
        assert (reported["width"], reported["height"]) == (image.shape[1], image.shape[0])
        tall = round(len(manifest["layers"]) * 0.5 / pixel)
        assert image.shape[0] > tall and image.shape[1] >= across  # the annotation footer below the section
        image = image[:tall, :across]
        solid = (image != [32, 32, 32]).any(axis=-1)
        assert solid[0].any() and solid[-1].any()
        edge_top, edge_bottom = image[0][np.argmax(solid[0])], image[-1][np.argmax(solid[-1])]
        assert not np.array_equal(edge_top, edge_bottom)
    done = heoslice("preview", tmp_path / "s", "--section", "x=50", "-o", tmp_path / "out.png")
    assert done.returncode == 2 and "--section" in done.stderr and "outside" in done.stderr
    assert not (tmp_path / "out.png").exists()


def test_error_names_the_stack_once(tmp_path):
    """A directory without a manifest: export, print and preview name it once ('full: no manifest.json')."""
    (tmp_path / "full").mkdir()
    for args in (("export", "full", "--format", "png", "-o", "x"), ("preview", "full")):
        done = subprocess.run([sys.executable, "-m", "heoslice", *args], capture_output=True, text=True,
                              cwd=tmp_path)
        assert done.returncode != 0 and "full: full:" not in done.stderr and "full: no manifest.json" in done.stderr


@pytest.mark.parametrize("fault", ["two", "none"])
def test_a_section_through_a_pixel_in_two_droplet_masks_or_none_is_refused(tmp_path, fault):
    """A graded stack whose layer 4 has its second droplet mask replaced by its first ("two": its pixels in two
    masks) or by an empty mask ("none": solid pixels in no mask), hashes updated so only the pixels object: a
    section through the part draws nothing and says so in one line (exit 4); a section of the clean stack is
    drawn."""
    import hashlib

    procedural.vase(rings_outer=10, rings_inner=8, sections=24).export(tmp_path / "vase.ply")
    stack = tmp_path / "graded"
    assert in_process("slice", tmp_path / "vase.ply", "-o", stack, "--layer", "5", "--dpi", "100", "--grade",
                      "linear", "--channels") == 0
    manifest = json.loads((stack / "manifest.json").read_text())
    x_middle = manifest["image"]["origin_mm"][0] + manifest["image"]["width"] * manifest["pixel_size_mm"][0] / 2
    done = heoslice("preview", stack, "--section", f"x={x_middle:.4f}", "-o", tmp_path / "clean.png")
    assert done.returncode == 0, done.stderr
    first, second = manifest["layers"][4]["channels"][:2]
    if fault == "two":
        data, count = (stack / first["file"]).read_bytes(), first["solid_pixels"]
    else:
        height, width = manifest["image"]["height"], manifest["image"]["width"]
        data, count = encode_bilevel_tiff(np.zeros((height, -(-width // 8)), np.uint8), width,
                                          (100.0, 100.0), "deflate"), 0
    (stack / second["file"]).write_bytes(data)
    second.update(sha256=hashlib.sha256(data).hexdigest(), solid_pixels=count)
    (stack / "manifest.json").write_text(json.dumps(manifest))
    done = heoslice("preview", stack, "--section", f"x={x_middle:.4f}", "-o", tmp_path / "faulty.png")
    said = {"two": "in two droplet masks", "none": "in no droplet mask"}[fault]
    assert done.returncode == 4 and f"layer 4: a pixel of the section is {said}" in done.stderr, done.stderr
    assert done.stderr.count("\n") == 1 and not (tmp_path / "faulty.png").exists()


def test_a_cut_at_the_far_edge_says_the_edge_is_not_included():
    """A cut at the image's far edge (outside: the last pixel ends there) says the range excludes that edge, so
    the message does not read as if its own bound were refused."""
    from heoslice.errors import InputError
    from heoslice.preview.section import section_line

    manifest = {"image": {"origin_mm": [-2.0, 2.0], "width": 40, "height": 40}, "pixel_size_mm": [0.1, 0.1]}
    assert section_line(manifest, "x", 1.95) == 39
    with pytest.raises(InputError, match=r"x from -2 mm up to, not including, 2 mm"):
        section_line(manifest, "x", 2.0)
