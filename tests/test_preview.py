"""Tests of heoslice.preview and `heoslice preview`: one layer and contact sheets, read through the stack checks."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from heoslice import procedural
from heoslice.errors import InputError
from heoslice.preview import layer_rgb, parse_layers


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
    assert image.shape == (manifest["image"]["height"], manifest["image"]["width"], 3)
    assert (image == 32).all(axis=2).any()  # empty pixels
    assert (image[..., 1] > image[..., 0] + 50).any()  # green interior


def test_preview_size_and_sheet(run_cli, stacks, tmp_path):
    """--size bounds a single layer's longer side; --sheet lays out the chosen layers in a grid of tiles."""
    plain, _ = stacks
    small = tmp_path / "small.png"
    assert run_cli("preview", plain, "--layer", "3", "--size", "64", "-o", small)[0] == 0
    assert max(Image.open(small).size) == 64
    sheet = tmp_path / "sheet.png"
    code, _, stderr = run_cli("preview", plain, "--sheet", "--layers", "0:8:2", "--tile", "64", "--columns", "2",
                              "-o", sheet)
    assert code == 0, stderr
    assert Image.open(sheet).size == (2 * (64 + 4) + 4, 2 * (64 + 14 + 4) + 4)


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
