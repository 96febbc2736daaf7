"""Tests of pipeline/slice_job.py and `heoslice slice` / `heoslice info`: stacks against mesh geometry."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import tifffile
import trimesh
from helpers import layer_loops, modules_loaded_by_command
from PIL import Image

from heoslice import procedural
from heoslice.layers.contours import build_contours
from heoslice.layers.rasterising import Grid, solid_mask
from heoslice.layers.slicing import slice_mesh
from heoslice.material import Material
from heoslice.mesh import load_mesh
from heoslice.pipeline import SliceSpec, slice_to_stack
from heoslice.stack import read_layer_mask, stack_volume_mm3, verify_stack


def write_mesh(mesh, path: Path) -> Path:
    path.write_bytes(mesh.export(file_type="ply", encoding="binary"))
    return path


@pytest.mark.parametrize("name, mesh", [
    ("sphere", procedural.sphere(8.0, 4)),
    ("torus", procedural.torus(10.0, 3.0)),
    ("vase", procedural.vase()),
    ("island", procedural.shell_with_island(10.0, 6.0, 2.5)),
])
def test_stack_volume_matches_mesh_volume(tmp_path, name, mesh):
    """Solid pixels x pixel area x layer height is within 0.5 % of the mesh volume."""
    model = write_mesh(mesh, tmp_path / f"{name}.ply")
    manifest, _ = slice_to_stack(load_mesh(model), tmp_path / "stack", SliceSpec(layer_height_mm=0.2,
                                                                               dpi=(300.0, 300.0), jobs=1))
    assert stack_volume_mm3(manifest) == pytest.approx(mesh.volume, rel=5e-3)


def test_manifest_describes_the_images(tmp_path):
    """Manifest fields match the files: z at layer centres, dpi tags, origin, sizes, solid counts."""
    mesh = procedural.torus(10.0, 3.0)
    model = write_mesh(mesh, tmp_path / "torus.ply")
    loaded = load_mesh(model)
    manifest, _ = slice_to_stack(loaded, tmp_path / "stack", SliceSpec(layer_height_mm=0.5, dpi=(200.0, 100.0),
                                                                       jobs=2))
    assert manifest["format"] == "heoslice-stack" and manifest["version"] == 1 and manifest["complete"]
    assert manifest["source"] == {"file": "torus.ply", "sha256": loaded.sha256}
    z_min, z_max = loaded.bounds[:, 2]
    layers = manifest["layers"]
    assert len(layers) == int(np.ceil((z_max - z_min) / 0.5))
    np.testing.assert_allclose([e["z_mm"] for e in layers], z_min + (np.arange(len(layers)) + 0.5) * 0.5)
    assert manifest["pixel_size_mm"] == pytest.approx([25.4 / 200, 25.4 / 100])
    assert manifest["mask"] == "nonzero" and manifest["image"]["mode"] == "1"
    width, height = manifest["image"]["width"], manifest["image"]["height"]
    x_left, y_top = manifest["image"]["origin_mm"]
    grid = Grid(width, height, x_left, y_top, *manifest["pixel_size_mm"])
    contours = build_contours(slice_mesh(loaded.vertices, loaded.faces, np.array([e["z_mm"] for e in layers])))
    for entry in layers[::3]:
        path = tmp_path / "stack" / entry["file"]
        with tifffile.TiffFile(path) as tiff:
            page = tiff.pages[0]
            assert (page.imagewidth, page.imagelength) == (width, height)
            x_res, y_res = page.tags["XResolution"].value, page.tags["YResolution"].value
            assert np.isclose(x_res[0] / x_res[1] * 25.4, 200) and np.isclose(y_res[0] / y_res[1] * 25.4, 100)
            assert page.tags["ResolutionUnit"].value == 1  # pixels per mm, with the ImageJ unit=mm
            assert tiff.imagej_metadata["unit"] == "mm"
            assert tiff.imagej_metadata["spacing"] == manifest["layer_height_mm"]
        mask = read_layer_mask(tmp_path / "stack", manifest, entry["index"])
        assert mask.sum() == entry["solid_pixels"]
        np.testing.assert_array_equal(mask, solid_mask(*layer_loops(contours, entry["index"]), grid))
        assert np.array_equal(~np.array(Image.open(path)).astype(bool), mask)  # Pillow: solid dark (min-is-white)
    assert verify_stack(tmp_path / "stack").ok


@pytest.mark.parametrize("layer_mm, layers", [(0.5, 32), (9.0, 2), (16.0, 1)])
def test_parallel_and_serial_stacks_are_identical(tmp_path, layer_mm, layers):
    """Worker processes (the first layer rendered before they are forked) change nothing: the same layer
    files, byte for byte, also for parts of one or two layers."""
    model = write_mesh(procedural.shell_with_island(8.0, 5.0, 2.0, 3), tmp_path / "m.ply")
    mesh = load_mesh(model)
    spec = SliceSpec(layer_height_mm=layer_mm, dpi=(150.0, 150.0), jobs=1)
    one, _ = slice_to_stack(mesh, tmp_path / "a", spec)
    two, _ = slice_to_stack(mesh, tmp_path / "b", replace(spec, jobs=2))
    assert len(one["layers"]) == layers
    assert [e["sha256"] for e in one["layers"]] == [e["sha256"] for e in two["layers"]]


def test_coloured_mesh_gives_a_droplet_mask_per_material_of_its_colours(tmp_path):
    """Vertex colours map to the materials table by the nearest display colour: a sphere red on top and blue
    below, with red and blue materials, gives 1-bit layers with a red and a blue mask; a layer whose every
    contour point is red is all red inside (the contour's material fills the layer, not a one-pixel ring),
    and the masks partition the solid pixels. With the built-in table both colours are nearest M1: one
    material, a solid mask alone."""
    mesh = procedural.sphere(6.0, 3)
    red_top = np.where(mesh.vertices[:, 2:3] > 0, [255, 0, 0, 255], [0, 0, 255, 255]).astype(np.uint8)
    mesh.visual.vertex_colors = red_top
    model = write_mesh(mesh, tmp_path / "coloured.ply")
    table = (Material("red", (255, 0, 0), 1), Material("blue", (0, 0, 255), 2))
    spec = SliceSpec(layer_height_mm=1.0, dpi=(100.0, 100.0), jobs=1, materials=table)
    stack = tmp_path / "stack"
    manifest, _ = slice_to_stack(load_mesh(model), stack, spec)
    assert manifest["image"]["mode"] == "1"
    assert [m["name"] for m in manifest["grading"]["materials"]] == ["red", "blue"]
    for entry, expected in ((manifest["layers"][-2], "red"), (manifest["layers"][1], "blue")):
        solid = tifffile.imread(stack / entry["file"]).astype(bool)
        masks = {c["material"]: tifffile.imread(stack / c["file"]).astype(bool) for c in entry["channels"]}
        assert solid.any()
        assert np.array_equal(masks[expected], solid)
        assert not any(mask.any() for name, mask in masks.items() if name != expected)
    for entry in manifest["layers"]:
        solid = tifffile.imread(stack / entry["file"]).astype(bool)
        red, blue = (tifffile.imread(stack / c["file"]).astype(bool) for c in entry["channels"])
        assert not (red & blue).any() and np.array_equal(red | blue, solid)
    assert verify_stack(stack).ok
    plain, _ = slice_to_stack(load_mesh(model), tmp_path / "plain", replace(spec, materials=()))
    assert plain.get("grading") is None and "channels" not in plain["layers"][0]


def test_slice_command_writes_the_default_directory(tmp_path, monkeypatch, run_cli):
    """`heoslice slice MODEL` writes ./MODEL_stack in the current directory, verified."""
    model = write_mesh(procedural.sphere(5.0, 3), tmp_path / "ball.ply")
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    code, out, err = run_cli("slice", str(model), "--layer", "1", "--dpi", "100")
    assert code == 0, err
    assert (work / "ball_stack" / "manifest.json").is_file()
    assert verify_stack(work / "ball_stack").ok
    assert "ball_stack" in out


def test_slice_command_refuses_a_non_empty_directory_without_force(tmp_path, run_cli):
    """A second run into the same directory exits 3 with one line, and --force rewrites it."""
    model = write_mesh(procedural.sphere(5.0, 3), tmp_path / "ball.ply")
    out_dir = tmp_path / "out"
    assert run_cli("slice", model, "-o", out_dir, "--layer", "1", "--dpi", "100")[0] == 0
    code, _, err = run_cli("slice", model, "-o", out_dir, "--layer", "1", "--dpi", "100")
    assert code == 3 and err.count("\n") == 1 and "--force" in err
    code, _, err = run_cli("slice", model, "-o", out_dir, "--layer", "2", "--dpi", "100", "--force")
    assert code == 0, err
    assert len(json.loads((out_dir / "manifest.json").read_text())["layers"]) == 5
    assert verify_stack(out_dir).ok


def test_slice_command_json_summary(tmp_path, run_cli):
    """--json prints one object with the stack path, layer count and volume."""
    mesh = procedural.box((4.0, 4.0, 2.0))
    model = write_mesh(mesh, tmp_path / "box.ply")
    code, out, err = run_cli("slice", model, "-o", tmp_path / "s", "--layer", "0.5", "--dpi", "254", "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["layers"] == 4
    assert summary["volume_mm3"] == pytest.approx(32.0, rel=1e-9)


@pytest.mark.parametrize("args, message", [
    (["--dpi", "abc"], "--dpi"),
    (["--layer", "0"], "--layer"),
    (["--canvas", "5x5"], "canvas"),
])
def test_slice_command_rejects_bad_options(tmp_path, run_cli, args, message):
    """Bad option values exit 2 with one line naming the option, and write no stack."""
    model = write_mesh(procedural.sphere(5.0, 2), tmp_path / "ball.ply")
    code, _, err = run_cli("slice", model, "-o", tmp_path / "s", *args)
    assert code == 2 and message in err and err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "s" / "manifest.json").exists()


def test_missing_model_is_one_line_exit_2(tmp_path, run_cli):
    """A missing file names the file, exits 2, no traceback."""
    code, _, err = run_cli("slice", tmp_path / "nope.ply")
    assert code == 2 and "nope.ply" in err and err.count("\n") == 1


def test_info_reports_geometry(tmp_path, run_cli):
    """`heoslice info --json` reports counts, watertightness, shells and the exact volume."""
    mesh = procedural.shell_with_island(10.0, 6.0, 2.5, 3)
    model = write_mesh(mesh, tmp_path / "island.ply")
    code, out, err = run_cli("info", model, "--json")
    assert code == 0, err
    info = json.loads(out)
    assert info["triangles"] == len(mesh.faces) and info["vertices"] == len(mesh.vertices)
    assert info["watertight"] and info["winding_consistent"] and info["shells"] == 3
    assert info["volume_mm3"] == pytest.approx(mesh.volume, rel=1e-6)  # PLY stores float32
    code, out, _ = run_cli("info", model)
    assert code == 0 and "shells:" in out and "watertight:         yes" in out


def test_slicing_in_runs_of_planes_gives_the_same_stack(tmp_path):
    """A tiny segment budget (many runs of planes) writes the same layers as slicing all at once."""
    model = write_mesh(procedural.torus(10.0, 3.0), tmp_path / "t.ply")
    mesh = load_mesh(model)
    whole, _ = slice_to_stack(mesh, tmp_path / "a", SliceSpec(layer_height_mm=0.5, dpi=(150.0, 150.0), jobs=2))
    runs, _ = slice_to_stack(mesh, tmp_path / "b", SliceSpec(layer_height_mm=0.5, dpi=(150.0, 150.0), jobs=2,
                                                             max_segments=300))
    assert [e["sha256"] for e in whole["layers"]] == [e["sha256"] for e in runs["layers"]]


def test_nested_shells_fill_once_and_verify_against_the_union(tmp_path, run_cli):
    """A lesion shell inside an organ is filled once: the stack volume is the union's (manifold3d), not
    the signed sum, and `verify --mesh` accepts it."""
    from heoslice.mesh import signed_volume_mm3, solid_volume_mm3

    mesh = procedural.nested_shells(outer=10.0, inner=4.0, offset=(3.0, 0.0, 0.0), subdivisions=4)
    model = write_mesh(mesh, tmp_path / "organ.ply")
    loaded = load_mesh(model)
    union, exact = solid_volume_mm3(loaded)
    assert exact and union < 0.99 * signed_volume_mm3(loaded.vertices, loaded.faces)
    manifest, _ = slice_to_stack(loaded, tmp_path / "stack", SliceSpec(layer_height_mm=0.25, dpi=(254.0, 254.0)))
    assert stack_volume_mm3(manifest) == pytest.approx(union, rel=5e-3)
    code, out, err = run_cli("verify", tmp_path / "stack", "--mesh", model)
    assert code == 0, out + err


def _holder(directory: Path) -> subprocess.Popen:
    """A separate process holding ``directory`` as a print does (locks.hold_stack) until it is killed."""
    code = ("import sys, time\nfrom heoslice.locks import hold_stack\n"
            "with hold_stack(sys.argv[1], 'printing it'):\n    print('held', flush=True)\n    time.sleep(60)\n")
    holder = subprocess.Popen([sys.executable, "-c", code, str(directory)], stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "held"
    return holder


def test_slice_force_into_a_held_stack_is_refused_and_leaves_it_unchanged(tmp_path, run_cli):
    """slice --force into a stack another process holds (a print) exits 18 with one line, and no file of the
    stack is removed or rewritten; once the holder has gone, the same command succeeds."""
    from heoslice.errors import EXIT_STACK_BUSY

    model = write_mesh(trimesh.creation.box(extents=(4.0, 4.0, 2.0)), tmp_path / "cube.ply")
    stack = tmp_path / "stack"
    code, _, err = run_cli("slice", model, "-o", stack, "--dpi", "100", "--layer", "0.5", "-j", "1")
    assert code == 0, err
    before = {path.name: path.read_bytes() for path in stack.iterdir()}
    holder = _holder(stack)
    try:
        code, _, err = run_cli("slice", model, "-o", stack, "--force", "--dpi", "200", "--layer", "0.5", "-j", "1")
    finally:
        holder.kill()
        holder.wait()
    assert code == EXIT_STACK_BUSY and len(err.strip().splitlines()) == 1 and str(stack) in err, err
    assert {path.name: path.read_bytes() for path in stack.iterdir()} == before
    code, _, err = run_cli("slice", model, "-o", stack, "--force", "--dpi", "200", "--layer", "0.5", "-j", "1")
    assert code == 0, err


def test_two_slices_into_one_directory_cannot_both_succeed(tmp_path):
    """Two slice --force runs started together into one new directory: exactly one writes the stack, the
    other exits 18 (or, if it started after the first ended, also succeeds); the stack verifies either way."""
    from heoslice.errors import EXIT_STACK_BUSY

    model = write_mesh(trimesh.creation.icosphere(subdivisions=4, radius=10.0), tmp_path / "ball.ply")
    stack = tmp_path / "stack"
    runs = [subprocess.Popen([sys.executable, "-m", "heoslice", "slice", str(model), "-o", str(stack), "--force",
                              "--dpi", dpi, "--layer", "0.2", "-j", "1"], stderr=subprocess.PIPE, text=True)
            for dpi in ("300", "150")]
    codes = [run.wait(timeout=120) for run in runs]
    assert sorted(codes) in ([0, EXIT_STACK_BUSY], [0, 0]), [run.stderr.read() for run in runs]
    assert verify_stack(stack).ok


def test_one_material_slice_loads_no_heavy_library(tmp_path):
    """A one-material `heoslice slice` (a fresh process) loads neither numba nor scipy's sparse graphs or
    spatial trees, nor the colouring's modules or tqdm (no terminal): importing them costs every such slice
    more than slicing a small part (benchmarks/README.md)."""
    model = write_mesh(procedural.sphere(5.0, 3), tmp_path / "ball.ply")
    args = ["slice", str(model), "-o", str(tmp_path / "out")]
    heavy = ("numba", "scipy.sparse", "scipy.spatial", "heoslice.material.coloring", "heoslice.material.surface",
             "tqdm")
    assert modules_loaded_by_command(args, heavy) == []
