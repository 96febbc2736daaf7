"""Tests of pipeline/spec.py and the slice's own limits: every numeric slice option is range-checked before
any arithmetic, as one line naming its option (exit 2), and the layer count agrees with the manifest limit."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import trimesh

from heoslice import procedural
from heoslice.errors import InputError
from heoslice.mesh import load_mesh
from heoslice.pipeline import SliceSpec, check_scale, layer_limit, slice_to_stack
from heoslice.stack import (
    MAX_IMAGE_PIXELS,
    MAX_MANIFEST_BYTES,
    layer_file_name,
    read_manifest,
)


@pytest.fixture(scope="module")
def cube(tmp_path_factory):
    """A 1 x 1 x 10 mm pillar as a binary PLY."""
    path = tmp_path_factory.mktemp("cube") / "pillar.ply"
    procedural.box((1.0, 1.0, 10.0)).export(path)
    return path


@pytest.mark.parametrize("args, flag", [
    (["--canvas", "1e308x1e308"], "--canvas"),
    (["--margin", "1e308"], "--margin"),
    (["--scale", "1e308"], "--scale"),
    (["--scale", "1e-300"], "--scale"),
    (["--scale", "900000"], "--scale"),  # within the factor's range, but the part would reach 9e6 mm
    (["--dpi", "1e9"], "--dpi"),
    (["--dpi", "600x1e9"], "--dpi"),
    (["--layer", "1e308"], "--layer"),
    (["--layer", "1e-300"], "--layer"),
    (["--layer", "nan"], "--layer"),
    (["--jobs", "100000000"], "--jobs"),
    (["--canvas", "10x10", "--dpi", "100000"], "pixels"),  # 3.9e4 x 3.9e4: more pixels than a layer may have
    (["--scale", "1000"], "--layer"),  # a 10 m pillar: 100,000 layers of 0.1 mm
    (["--layer", "0.001", "--scale", "10"], "--layer"),  # 100,000 layers: more than a manifest holds
])
def test_absurd_slice_options_are_one_line_errors_before_any_arithmetic(tmp_path, run_cli, cube, args, flag):
    """Each is refused with exit 2 and one line naming the option, nothing written, no RuntimeWarning (made an
    error here, it would end the command with an internal error)."""
    out = tmp_path / "stack"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        code, _, err = run_cli("slice", cube, "-o", out, *args)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("heoslice: error:") and flag in lines[0], err
    assert "internal error" not in err and not (out / "manifest.json").exists()


def test_library_errors_name_the_parameter():
    """SliceSpec and check_scale name their parameters, not the command's options."""
    for make, name in ((lambda: SliceSpec(layer_height_mm=0.0), "layer_height_mm"),
                       (lambda: SliceSpec(dpi=(600.0, 1e9)), "dpi"),
                       (lambda: SliceSpec(margin_mm=float("inf")), "margin_mm"),
                       (lambda: SliceSpec(canvas_mm=(1e308, 10.0)), "canvas_mm"),
                       (lambda: check_scale(1e308, np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])), "scale")):
        with pytest.raises(InputError, match=f"^{name}: "):
            make()


def test_a_part_one_layer_high_in_single_precision_is_one_layer(tmp_path, run_cli):
    """A 0.1 mm thin plate whose coordinates are float32 (z_max = 0.10000000149) gets one 0.1 mm layer, and
    the stack verifies."""
    plate = procedural.box((5.0, 5.0, 0.1))
    path = tmp_path / "plate.ply"
    trimesh.Trimesh(plate.vertices.astype(np.float32), plate.faces, process=False).export(path)
    code, out, err = run_cli("slice", path, "-o", tmp_path / "stack", "--layer", "0.1", "--dpi", "200", "--json")
    assert code == 0, err
    assert json.loads(out)["layers"] == 1
    assert run_cli("verify", tmp_path / "stack")[0] == 0


def test_a_layer_taller_than_the_part_warns(tmp_path, run_cli, cube):
    """--layer 1000 on a 10 mm pillar slices (one layer) and says so in one warning naming --layer; the layer,
    cut above the part, is empty, so a second warning says the stack cannot print."""
    code, _, err = run_cli("slice", cube, "-o", tmp_path / "stack", "--layer", "1000", "--dpi", "50")
    warned = [line for line in err.splitlines() if line.startswith("warning:")]
    assert code == 0 and len(warned) == 2 and "--layer" in warned[0] and "one layer" in warned[0], err
    assert "cannot print: every layer is empty" in warned[1]


@pytest.mark.parametrize("channels", [False, True])
def test_the_largest_layer_count_makes_a_manifest_the_readers_accept(tmp_path, cube, channels):
    """A manifest of layer_limit layers at their longest (largest index, solid counts and z, with droplet masks
    of the default materials) is within MAX_MANIFEST_BYTES and read back; it is the limit (a few more layers
    would not fit: it uses at least 90 % of the bytes allowed, or it is the absolute limit)."""
    from heoslice.grading import GradeSpec, RegionSpec
    from heoslice.material import DEFAULT_MATERIALS, Material, make_function
    from heoslice.pipeline import channel_name
    from heoslice.stack import MAX_LAYERS

    grade = GradeSpec(RegionSpec(nozzle_mm=0.5), make_function("linear"), Material("green", (0, 255, 0)), None,
                      DEFAULT_MATERIALS["M1"], DEFAULT_MATERIALS["M2"]) if channels else None
    spec = SliceSpec(layer_height_mm=5.0, dpi=(50.0, 50.0), grade=grade, channels=channels)
    limit = layer_limit(spec)
    written, _ = slice_to_stack(load_mesh(cube), tmp_path, spec)
    materials = grade.channel_materials() if channels else ()
    def entry(index: int) -> dict:
        longest = {"index": index, "z_mm": -1.2345678901234567e-300, "file": layer_file_name(index),
                   "sha256": "f" * 64, "solid_pixels": MAX_IMAGE_PIXELS, "open_contours": False}
        if channels:
            longest["channels"] = [{"material": m.name, "file": layer_file_name(index, channel_name(m)),
                                    "sha256": "f" * 64, "solid_pixels": MAX_IMAGE_PIXELS} for m in materials]
        return longest

    image = {**written["image"], "width": 1 << 15, "height": 1 << 15}
    text = json.dumps({**written, "image": image, "layers": [entry(i) for i in range(limit)]}, indent=1)
    assert len(text) <= MAX_MANIFEST_BYTES
    assert limit == MAX_LAYERS or len(text) > 0.9 * MAX_MANIFEST_BYTES
    (tmp_path / "manifest.json").write_text(text)
    assert len(read_manifest(tmp_path)["layers"]) == limit
