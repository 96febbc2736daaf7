"""Tests of `heoslice slice` with graded interiors (--grade, --to, --channels, ...): the command as
documented, the stack it writes, and its refusals of bad options."""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile

from heoslice import procedural
from heoslice.stack import verify_stack


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    """A closed sphere of radius 4 mm as a PLY file."""
    path = tmp_path_factory.mktemp("mesh") / "ball.ply"
    procedural.sphere(4.0, subdivisions=3).export(path)
    return path


@pytest.fixture(scope="module")
def organ(tmp_path_factory):
    """Two shells: a 6 mm ball and a 2 mm lesion inside it, with a materials file naming the lesion's material."""
    folder = tmp_path_factory.mktemp("organ")
    path = folder / "organ.ply"
    procedural.nested_shells(outer=6.0, inner=2.0, offset=(2.0, 0.0, 0.0), subdivisions=3).export(path)
    materials = folder / "materials.toml"
    materials.write_text('[materials.gel]\ncolor = "240,240,240"\nchannel = 1\n'
                         '[materials.cells]\ncolor = "0,255,0"\nchannel = 2\n'
                         '[materials.tumour]\ncolor = "200,0,0"\nchannel = 3\n'
                         '[shells]\n1 = "tumour"\n')
    return path, materials


def test_grade_command_as_documented(run_cli, ball, tmp_path):
    """`heoslice slice model.ply --grade linear --to 0,255,0 --nozzle 0.2 --rgba` writes a verified RGBA
    preview stack whose interior goes from the base material at the contour to green at the centre."""
    out = tmp_path / "stack"
    code, stdout, stderr = run_cli("slice", ball, "--grade", "linear", "--to", "0,255,0", "--nozzle", "0.2",
                                   "--layer", "0.5", "--rgba", "-o", out)
    assert code == 0, stderr
    report = verify_stack(out)
    assert report.ok, report.problems
    manifest = report.manifest
    assert manifest["image"]["mode"] == "RGBA" and manifest["mask"] == "alpha"
    assert manifest["grading"]["function"].startswith("linear")
    assert manifest["grading"]["target"]["color"] == [0, 255, 0]
    middle = len(manifest["layers"]) // 2
    image = tifffile.imread(out / manifest["layers"][middle]["file"])
    solid = image[..., 3] > 0
    rows, cols = np.nonzero(solid)
    centre = image[int(rows.mean()), int(cols.mean())].astype(int)
    assert tuple(centre[:3]) == pytest.approx((0, 255, 0), abs=40)
    edge = image[rows.min() + 2, int(cols.mean())].astype(int)
    assert edge[0] > 150  # near the contour: still mostly the light base material


def test_channels_partition_the_solid_pixels(run_cli, ball, tmp_path):
    """--channels writes one 1-bit mask per material per layer, listed with sha256 and solid pixels in the
    manifest; the layer image is then the 1-bit solid mask, and the masks are disjoint and together
    are exactly its solid pixels."""
    out = tmp_path / "stack"
    code, _, stderr = run_cli("slice", ball, "--grade", "linear", "--to", "M2", "--layer", "1", "--channels",
                              "-o", out)
    assert code == 0, stderr
    report = verify_stack(out)
    assert report.ok, report.problems
    assert report.manifest["image"]["mode"] == "1" and report.manifest["mask"] == "nonzero"
    for entry in report.manifest["layers"]:
        channels = entry["channels"]
        assert [c["material"] for c in channels] == ["M1", "M2"]
        masks = [tifffile.imread(out / c["file"]).astype(bool) for c in channels]
        for c, mask in zip(channels, masks):
            assert c["solid_pixels"] == int(mask.sum())
        solid = tifffile.imread(out / entry["file"]) != 0
        assert entry["solid_pixels"] == int(solid.sum())
        assert np.array_equal(masks[0].astype(int) + masks[1].astype(int), solid.astype(int))
    middle = report.manifest["layers"][len(report.manifest["layers"]) // 2]["channels"]
    assert middle[1]["solid_pixels"] > 0.3 * (middle[0]["solid_pixels"] + middle[1]["solid_pixels"])


def test_altered_channel_file_fails_verification(run_cli, ball, tmp_path):
    """A droplet mask changed after slicing no longer matches its sha256: verify reports it."""
    out = tmp_path / "stack"
    assert run_cli("slice", ball, "--grade", "linear", "--layer", "2", "--channels", "-o", out)[0] == 0
    manifest = json.loads((out / "manifest.json").read_text())
    victim = out / manifest["layers"][1]["channels"][0]["file"]
    victim.write_bytes(victim.read_bytes()[:-1] + b"\0")
    report = verify_stack(out)
    assert any(victim.name in problem for problem in report.problems)


def test_nested_shell_keeps_its_material_through_the_cli(run_cli, organ, tmp_path):
    """A lesion shell given its own material in the materials file keeps it in every layer it crosses:
    its droplet channel holds exactly the pixels the RGBA rendering (the same slice with
    --rgba) paints in the tumour's colour, while the organ around it is graded."""
    mesh, materials = organ
    out, rgba = tmp_path / "stack", tmp_path / "rgba"
    common = ("--grade", "linear", "--to", "cells", "--materials", materials, "--layer", "0.5")
    code, _, stderr = run_cli("slice", mesh, *common, "--channels", "-o", out)
    assert code == 0, stderr
    assert run_cli("slice", mesh, *common, "--rgba", "-o", rgba)[0] == 0
    manifest = json.loads((out / "manifest.json").read_text())
    names = [c["material"] for c in manifest["layers"][0]["channels"]]
    assert names == ["gel", "cells", "tumour"]
    crossing = [e for e in manifest["layers"] if abs(e["z_mm"]) < 1.5]
    assert crossing
    for entry in crossing:
        image = tifffile.imread(rgba / entry["file"])
        tumour = tifffile.imread(out / entry["channels"][2]["file"]).astype(bool)
        assert entry["channels"][2]["solid_pixels"] > 0
        assert np.array_equal(tumour, np.all(image[..., :3] == (200, 0, 0), axis=-1) & (image[..., 3] > 0))
        cells = tifffile.imread(out / entry["channels"][1]["file"]).astype(bool)
        assert cells.sum() > 0 and not (cells & tumour).any()


def test_default_slice_is_unchanged(run_cli, ball, tmp_path):
    """Without grading options the stack stays 1-bit, without a grading entry or channels."""
    out = tmp_path / "stack"
    assert run_cli("slice", ball, "--layer", "1", "-o", out)[0] == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["image"]["mode"] == "1"
    assert "grading" not in manifest
    assert all("channels" not in entry for entry in manifest["layers"])


@pytest.mark.parametrize("args, option", [
    (["--grade", "wavy"], "--grade"),
    (["--grade", "linear", "--nozzle", "0"], "--nozzle"),
    (["--grade", "linear", "--depth", "-2"], "--depth"),
    (["--grade", "linear", "--to", "not-a-colour"], "--to"),
    (["--grade", "linear", "--from", "#12"], "--from"),
    (["--alpha", "2"], "--alpha"),
    (["--grade", "linear", "--offsets", "0"], "--offsets"),
    (["--grade", "expression", "--expression", "__import__('os')"], "--expr"),
])
def test_bad_grading_options_fail_cleanly(run_cli, ball, tmp_path, args, option):
    """A bad grading option is one line naming it, exit status 2, and no stack left behind."""
    out = tmp_path / "stack"
    code, _, stderr = run_cli("slice", ball, *args, "-o", out)
    assert code == 2
    assert option in stderr and "Traceback" not in stderr
    assert len(stderr.strip().splitlines()) == 1
    assert not (out / "manifest.json").exists()


def test_missing_materials_file(run_cli, ball, tmp_path):
    """A materials file that does not exist is named in a one-line error (exit 2)."""
    code, _, stderr = run_cli("slice", ball, "--grade", "linear", "--materials", tmp_path / "nope.toml",
                              "-o", tmp_path / "stack")
    assert code == 2 and "nope.toml" in stderr


def counted_plate(tmp_path, monkeypatch):
    """The benchmark's plate with holes, pins and a cavity, small; a graded slice spec with droplet masks
    (300 dpi, 0.2 mm layers, in this process); and a list that grows by one per family measured afresh."""
    from heoslice import grading, pipeline
    from heoslice.material import DEFAULT_MATERIALS, Material, make_function
    from heoslice.mesh import load_mesh

    path = tmp_path / "plate.ply"
    procedural.holes_and_islands((20.0, 12.5, 4.0), 48).export(path)
    grade = grading.GradeSpec(grading.RegionSpec(nozzle_mm=0.3), make_function("linear"),
                              Material("green", (0, 255, 0)), None, DEFAULT_MATERIALS["M1"], DEFAULT_MATERIALS["M2"])
    measured = []
    family_field = grading.labels.family_field
    monkeypatch.setattr(grading.labels, "family_field", lambda *args, **kwargs: measured.append(1) or family_field(
        *args, **kwargs))
    spec = pipeline.SliceSpec(layer_height_mm=0.2, dpi=(300.0, 300.0), grade=grade, channels=True, jobs=1)
    return load_mesh(path), spec, measured


def test_extruded_layers_reuse_their_sub_regions_and_write_the_same_stack(tmp_path, monkeypatch):
    """A plate with holes, pins and a cavity (the benchmark's part, small): its layers away from the cavity
    are alike, and slicing with droplet masks measures far fewer families than layers times families while
    writing every layer and channel file byte for byte as layers graded one by one, each afresh."""
    from heoslice import pipeline

    mesh, spec, measured = counted_plate(tmp_path, monkeypatch)
    reused, _ = pipeline.slice_to_stack(mesh, tmp_path / "reused", spec)
    with_reuse = len(measured)
    from heoslice.pipeline import runs

    render_and_write = runs.render_and_write
    monkeypatch.setattr(runs, "render_and_write", lambda job, cache=None: render_and_write(job))
    fresh, _ = pipeline.slice_to_stack(mesh, tmp_path / "fresh", spec)
    assert with_reuse < 0.4 * (len(measured) - with_reuse)
    assert [(e["sha256"], e["channels"]) for e in reused["layers"]] == [(e["sha256"], e["channels"])
                                                                       for e in fresh["layers"]]
    assert verify_stack(tmp_path / "reused").ok


def test_sub_regions_carry_over_from_one_run_of_layers_to_the_next(tmp_path, monkeypatch):
    """Sliced in runs of a layer or two (a small segment budget), the plate with holes and pins measures no
    more families than in one long run, in this process, the last layer of a run serving the next run's
    first; forked workers, each keeping its own last layer, write the same stack byte for byte."""
    from dataclasses import replace

    from heoslice import pipeline
    from heoslice.layers import face_z_range, plane_heights

    mesh, long_runs, measured = counted_plate(tmp_path, monkeypatch)
    short_runs = replace(long_runs, max_segments=1500)
    one, _ = pipeline.slice_to_stack(mesh, tmp_path / "one", long_runs)
    in_one_run = len(measured)
    z = plane_heights(mesh.bounds[0, 2], mesh.bounds[1, 2], short_runs.layer_height_mm)
    context = pipeline.RunContext(mesh=mesh, z=z, face_range=face_z_range(mesh.vertices, mesh.faces), grid=None,
                                  spec=short_runs, directory=tmp_path)
    assert len(pipeline.plane_runs(context)) >= 8
    many, _ = pipeline.slice_to_stack(mesh, tmp_path / "many", short_runs)
    assert len(measured) - in_one_run == in_one_run
    forked, _ = pipeline.slice_to_stack(mesh, tmp_path / "forked", replace(short_runs, jobs=2))
    files = [[(e["sha256"], e["channels"]) for e in stack["layers"]] for stack in (one, many, forked)]
    assert files[0] == files[1] == files[2]
