"""Tests of the slice pipeline and `heoslice slice` / `heoslice info`: stacks against mesh geometry."""

from __future__ import annotations

import json
import platform
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import tifffile
from helpers import layer_loops
from PIL import Image

from heoslice import procedural
from heoslice.contours import build_contours
from heoslice.distribution import make_function
from heoslice.loading import load_mesh
from heoslice.materials import DEFAULT_MATERIALS, Material
from heoslice.pipeline import SliceSpec, slice_to_stack
from heoslice.rasterising import Grid, contour_pixels, solid_mask
from heoslice.regions import GradeSpec, RegionSpec
from heoslice.slicing import slice_mesh
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
            assert tiff.imagej_metadata["unit"] == "mm" and tiff.imagej_metadata["spacing"] == manifest["layer_height_mm"]
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


def test_coloured_mesh_gives_rgba_layers_with_contour_colours(tmp_path):
    """Vertex colours make RGBA layers; contour pixels carry colours interpolated from the vertices."""
    mesh = procedural.sphere(6.0, 3)
    red_top = np.where(mesh.vertices[:, 2:3] > 0, [255, 0, 0, 255], [0, 0, 255, 255]).astype(np.uint8)
    mesh.visual.vertex_colors = red_top
    model = write_mesh(mesh, tmp_path / "coloured.ply")
    manifest, _ = slice_to_stack(load_mesh(model), tmp_path / "stack", SliceSpec(layer_height_mm=1.0,
                                                                               dpi=(100.0, 100.0), jobs=1))
    assert manifest["mask"] == "alpha" and manifest["image"]["mode"] == "RGBA"
    top = tifffile.imread(tmp_path / "stack" / manifest["layers"][-2]["file"])
    bottom = tifffile.imread(tmp_path / "stack" / manifest["layers"][1]["file"])
    assert top.shape[2] == 4
    for image, colour in ((top, (255, 0, 0)), (bottom, (0, 0, 255))):
        rows, cols = contour_pixels(image[..., 3] > 0).T
        assert len(rows) > 0
        assert np.all(image[rows, cols, :3] == colour)
        interior = image[..., 3] > 0
        interior[rows, cols] = False
        assert np.all(image[interior][:, :3] == 255)  # base material (default white) inside
    assert verify_stack(tmp_path / "stack").ok


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
    from heoslice.loading import signed_volume_mm3, solid_volume_mm3

    mesh = procedural.nested_shells(outer=10.0, inner=4.0, offset=(3.0, 0.0, 0.0), subdivisions=4)
    model = write_mesh(mesh, tmp_path / "organ.ply")
    loaded = load_mesh(model)
    union, exact = solid_volume_mm3(loaded)
    assert exact and union < 0.99 * signed_volume_mm3(loaded.vertices, loaded.faces)
    manifest, _ = slice_to_stack(loaded, tmp_path / "stack", SliceSpec(layer_height_mm=0.25, dpi=(254.0, 254.0)))
    assert stack_volume_mm3(manifest) == pytest.approx(union, rel=5e-3)
    code, out, err = run_cli("verify", tmp_path / "stack", "--mesh", model)
    assert code == 0, out + err


def test_a_layer_takes_the_last_layers_tiff_only_for_the_same_solid_bits():
    """A 1-bit layer takes the last layer's encoded TIFF (the same bytes object) only when its solid bits are
    those bits: as many solid pixels elsewhere get a TIFF of their own, which decodes to them."""
    import io
    from types import SimpleNamespace

    from heoslice.pipeline import _solid_tiff

    job = SimpleNamespace(grid=SimpleNamespace(width=40), dpi=(600.0, 600.0), compression="deflate",
                          layer_height_mm=0.1)
    mask = np.zeros((30, 40), dtype=bool)
    mask[5:15, 8:20] = True
    moved = np.roll(mask, 7, axis=1)
    reuse: dict = {}
    first = _solid_tiff(np.packbits(mask, axis=1), int(mask.sum()), job, reuse)
    assert _solid_tiff(np.packbits(mask, axis=1), int(mask.sum()), job, reuse) is first
    other = _solid_tiff(np.packbits(moved, axis=1), int(moved.sum()), job, reuse)
    assert np.array_equal(tifffile.imread(io.BytesIO(other)).astype(bool), moved)
    assert np.array_equal(tifffile.imread(io.BytesIO(first)).astype(bool), mask)


_REUSE_PROBE = """
import resource, sys
import numpy as np
from heoslice import pipeline
if sys.argv[1] == "worker":
    pipeline._adopt(None, {})
faults = []
for _ in range(2):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    block = np.ones(24 << 20, dtype=np.uint8)
    del block
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
print(*faults)
"""


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt's thresholds are glibc's")
def test_workers_keep_freed_memory_for_the_next_layer():
    """A worker (set up by the pool's initializer) serves a 24 MB block freed by the last layer again
    without new page faults; a plain process keeps glibc's defaults, which fault it in afresh at least
    once (the probe sees the faults when there are some)."""
    def probe(role):
        out = subprocess.run([sys.executable, "-c", _REUSE_PROBE, role], capture_output=True, text=True, check=True)
        return [int(word) for word in out.stdout.split()]

    first, second = probe("worker")
    assert first > 100 and second < 20
    assert max(probe("plain")) > 100


def _graded_spec(**changes) -> SliceSpec:
    """A small graded slice with droplet masks (linear grading, nozzle 0.5 mm, 0.5 mm layers at 150 dpi)."""
    grade = GradeSpec(RegionSpec(nozzle_mm=0.5), make_function("linear"), Material("green", (0, 255, 0)), None,
                      DEFAULT_MATERIALS["M1"], DEFAULT_MATERIALS["M2"])
    return SliceSpec(layer_height_mm=0.5, dpi=(150.0, 150.0), grade=grade, channels=True, **changes)


def _broken_helper(*args):
    raise RuntimeError("helper broke")


class _Asked:
    """A helper's end of the pipe, as a parent that asks only once the helper has gone through every run."""

    def __init__(self):
        self.sent = []

    def poll(self):
        return False

    def recv(self):
        return None

    def send(self, value):
        self.sent.append(value)


def _run_context(tmp_path, mesh, spec):
    from heoslice.pipeline import RunContext
    from heoslice.rasterising import grid_for
    from heoslice.slicing import face_z_range, plane_heights

    loaded = load_mesh(write_mesh(mesh, tmp_path / "part.ply"))
    return RunContext(mesh=loaded, z=plane_heights(loaded.bounds[0, 2], loaded.bounds[1, 2], spec.layer_height_mm),
                      face_range=face_z_range(loaded.vertices, loaded.faces),
                      grid=grid_for(loaded.bounds[:, :2], spec.dpi, spec.margin_mm, spec.canvas_mm), spec=spec,
                      directory=tmp_path)


@pytest.mark.parametrize("graded", [False, True])
def test_runs_sliced_ahead_into_shared_memory_are_the_runs_sliced_in_place(tmp_path, graded):
    """What the helper copies into the shared buffer reads back (read-only) as the very contours and
    hierarchy that run_contours makes in place, run by run, and as the layers' solid bits that packed_mask
    makes of them; a buffer too small for the next run stops it after the runs that fit, none cut short;
    run_contours takes a run the context holds instead of slicing it."""
    import mmap

    from heoslice.pipeline import _shared_array, _slice_ahead, layer_jobs, plane_runs, run_contours
    from heoslice.rasterising import packed_mask

    spec = _graded_spec(max_segments=400) if graded else SliceSpec(layer_height_mm=0.5, dpi=(150.0, 150.0),
                                                                   max_segments=400)
    context = _run_context(tmp_path, procedural.shell_with_island(8.0, 5.0, 2.0, 3), spec)
    runs = plane_runs(context)
    assert len(runs) > 3
    buffer = mmap.mmap(-1, 16 << 20)
    asked = _Asked()
    _slice_ahead(context, runs, buffer, asked)
    ((placed, masks),) = asked.sent
    assert [run for run, _, _ in placed] == [run for run, _ in masks] == runs
    for (run, layout, _), (_, where_bits) in zip(placed, masks):
        expected, _, _ = run_contours(context, *run)
        for name, where in layout:
            got = _shared_array(buffer, where)
            if getattr(expected, name) is None:
                assert got is None and not graded
            else:
                assert not got.flags.writeable and np.array_equal(got, getattr(expected, name))
        jobs = layer_jobs(expected, context.mesh, context.grid, spec, tmp_path, first_layer=run[0])
        bits = _shared_array(buffer, where_bits)
        assert not bits.flags.writeable
        assert np.array_equal(bits, [packed_mask(job.points, job.offsets, context.grid) for job in jobs])
    # room for the first two runs and 64 bytes more: the third does not fit
    two_runs = max(offset + np.dtype(dtype).itemsize * int(np.prod(shape))
                   for _, where in placed[1][1] if where for dtype, shape, offset in [where])
    small = mmap.mmap(-1, two_runs + 64)
    asked = _Asked()
    _slice_ahead(context, runs, small, asked)
    assert [run for run, _, _ in asked.sent[0][0]] == runs[:2] and asked.sent[0][1] == []
    held = run_contours(context, *runs[0])
    ahead = replace(context, ahead={runs[0]: (held[0], 0.0, 0.0)})
    assert run_contours(ahead, *runs[0])[0] is held[0]


def test_graded_stacks_are_the_same_with_runs_sliced_ahead_or_not(tmp_path, monkeypatch):
    """Graded droplet-mask stacks with workers (and a helper slicing ahead) are byte for byte the serial
    stack, also when every run is sliced ahead (many runs) and when the helper fails."""
    from heoslice import pipeline

    mesh = load_mesh(write_mesh(procedural.shell_with_island(8.0, 5.0, 2.0, 3), tmp_path / "m.ply"))

    def layers(name, **changes):
        manifest, _ = slice_to_stack(mesh, tmp_path / name, _graded_spec(**changes))
        return [(e["sha256"], e["channels"]) for e in manifest["layers"]]

    serial = layers("serial", jobs=1)
    assert layers("workers", jobs=2) == serial
    assert layers("many-runs", jobs=2, max_segments=400) == serial

    monkeypatch.setattr(pipeline, "_slice_ahead", _broken_helper)
    assert layers("broken-helper", jobs=2) == serial


def test_a_helper_that_fails_or_is_left_makes_nothing_and_leaves_quietly(tmp_path, monkeypatch, capfd):
    """A helper that raises leaves the context as it was; a parent interrupted before it asks ends its helper,
    which leaves without a traceback."""
    from heoslice import pipeline

    spec = SliceSpec(layer_height_mm=0.5, dpi=(150.0, 150.0), max_segments=400)
    context = _run_context(tmp_path, procedural.shell_with_island(8.0, 5.0, 2.0, 3), spec)
    with pytest.raises(KeyboardInterrupt):
        with pipeline._sliced_ahead(context, pipeline.plane_runs(context)):
            raise KeyboardInterrupt
    assert "Traceback" not in capfd.readouterr().err

    monkeypatch.setattr(pipeline, "_slice_ahead", _broken_helper)
    with pipeline._sliced_ahead(context, pipeline.plane_runs(context)) as collect:
        assert collect() is context


def test_parallel_slicing_leaves_the_garbage_collector_as_it_found_it(tmp_path):
    """What is frozen for the forks is unfrozen after (nothing left frozen), and a caller that froze its own
    objects finds them frozen still, and no more."""
    import gc

    mesh = load_mesh(write_mesh(procedural.shell_with_island(8.0, 5.0, 2.0, 3), tmp_path / "m.ply"))
    spec = _graded_spec(jobs=2)
    assert gc.get_freeze_count() == 0
    slice_to_stack(mesh, tmp_path / "a", spec)
    assert gc.get_freeze_count() == 0
    gc.freeze()
    try:
        frozen = gc.get_freeze_count()
        slice_to_stack(mesh, tmp_path / "b", spec)
        assert gc.get_freeze_count() == frozen
    finally:
        gc.unfreeze()


def test_a_helper_makes_masks_only_up_to_their_share_of_the_buffer(tmp_path, monkeypatch):
    """Past AHEAD_MASK_BYTES of solid masks the helper stops making them: every run's contours, the masks of
    the runs that fit in that share."""
    import mmap

    from heoslice import pipeline

    context = _run_context(tmp_path, procedural.shell_with_island(8.0, 5.0, 2.0, 3), _graded_spec(max_segments=400))
    runs = pipeline.plane_runs(context)
    layers = [stop - start for start, stop in runs[:2]]
    row_bytes = context.grid.height * -(-context.grid.width // 8)
    monkeypatch.setattr(pipeline, "AHEAD_MASK_BYTES", sum(layers) * row_bytes)
    asked = _Asked()
    pipeline._slice_ahead(context, runs, mmap.mmap(-1, 16 << 20), asked)
    placed, masks = asked.sent[0]
    assert [run for run, _, _ in placed] == runs and [run for run, _ in masks] == runs[:2]


def _silent_helper(*args):
    import signal
    import time

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    time.sleep(120)


def test_a_helper_that_does_not_answer_is_left_aside_and_ended(tmp_path, monkeypatch):
    """A helper that neither answers nor ends is waited for at most _AHEAD_WAIT_S (0.3 s here; well within
    30 s, where the helper would still be asleep), its work left to the workers, and it is killed: no
    process is left behind."""
    import multiprocessing
    import time

    from heoslice import pipeline

    monkeypatch.setattr(pipeline, "_slice_ahead", _silent_helper)
    monkeypatch.setattr(pipeline, "_AHEAD_WAIT_S", 0.3)
    spec = SliceSpec(layer_height_mm=0.5, dpi=(150.0, 150.0), max_segments=400)
    context = _run_context(tmp_path, procedural.shell_with_island(8.0, 5.0, 2.0, 3), spec)
    started = time.monotonic()
    with pipeline._sliced_ahead(context, pipeline.plane_runs(context)) as collect:
        assert collect() is context
    assert time.monotonic() - started < 30
    assert multiprocessing.active_children() == []
