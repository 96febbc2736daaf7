"""Tests of cli/verify.py: `verify --mesh` against the meshes a stack was sliced from, one per part file of a
multi-part stack, in the manifest's part order."""

from __future__ import annotations

import json

import pytest

from heoslice import procedural
from heoslice.errors import EXIT_INPUT, EXIT_VERIFY


@pytest.fixture
def two_part_stack(tmp_path, run_cli):
    """A stack sliced from two boxes side by side as the parts of one job (`slice a.ply b.ply --part a=M1
    --part b=M2`), and the folder holding the meshes (a 10 x 10 x 5 mm box, b 5 x 5 x 3 mm, b_tall 5 x 5 x 8 mm)."""
    procedural.box((10.0, 10.0, 5.0)).export(tmp_path / "a.ply")
    procedural.box((5.0, 5.0, 3.0), origin=(15.0, 0.0, 0.0)).export(tmp_path / "b.ply")
    procedural.box((5.0, 5.0, 8.0), origin=(15.0, 0.0, 0.0)).export(tmp_path / "b_tall.ply")
    code, _, err = run_cli("slice", tmp_path / "a.ply", tmp_path / "b.ply", "--part", "a=M1", "--part", "b=M2",
                           "--layer", "0.5", "--dpi", "100", "-j", "1", "-o", tmp_path / "stack")
    assert code == 0, err
    manifest = json.loads((tmp_path / "stack" / "manifest.json").read_text())
    assert [part["file"] for part in manifest["parts"]] == ["a.ply", "b.ply"]
    return tmp_path


def test_a_two_part_stack_verifies_against_its_two_meshes(two_part_stack, run_cli):
    """One --mesh per part, in order: OK (exit 0, no warning), and --json compares the parts' volume together."""
    folder = two_part_stack
    code, out, err = run_cli("verify", folder / "stack", "--mesh", folder / "a.ply", "--mesh", folder / "b.ply")
    assert code == 0, out + err
    assert out.startswith(f"{folder / 'stack'}: OK, 10 layers") and err == ""
    code, out, err = run_cli("verify", folder / "stack", "--mesh", folder / "a.ply", "--mesh", folder / "b.ply",
                             "--json")
    summary = json.loads(out)
    assert code == 0 and summary["ok"] and summary["mesh"]["volume_mm3"] == pytest.approx(500.0 + 75.0)


def test_a_wrong_part_mesh_fails(two_part_stack, run_cli):
    """A taller second part: the volume and layer-height problems, one line each, and one error line, exit 4."""
    folder = two_part_stack
    code, out, err = run_cli("verify", folder / "stack", "--mesh", folder / "a.ply", "--mesh", folder / "b_tall.ply")
    assert code == EXIT_VERIFY
    assert any("differs from the mesh volume" in line for line in out.splitlines())
    assert any("z-range" in line for line in out.splitlines())
    errors = [line for line in err.splitlines() if line.startswith("heoslice: error: ")]
    assert errors == [f"heoslice: error: {folder / 'stack'}: 2 problem(s); do not print this stack"]
    assert "b_tall.ply: not the file of the stack's parts from b.ply" in err


def test_part_meshes_in_another_order_are_matched_by_content(two_part_stack, run_cli):
    """The --mesh files of a multi-part stack given in another order are matched to its parts by their sha256: the
    same report (each part's designed against delivered share) as in order, no warning, exit 0."""
    folder = two_part_stack
    reports = []
    for order in (("a.ply", "b.ply"), ("b.ply", "a.ply")):
        options = [item for name in order for item in ("--mesh", folder / name)]
        code, out, err = run_cli("verify", folder / "stack", *options, "--json")
        assert code == 0 and err == "", err
        reports.append(json.loads(out)["delivered"]["parts"])
    assert reports[1] == reports[0]
    assert [part["material"] for part in reports[0]] == ["M1", "M2"]
    assert all(abs(part["difference"]) <= 0.02 for part in reports[0])



@pytest.mark.parametrize("meshes, needs", [(("a.ply",), "the 2 part files a.ply, b.ply"),
                                           (("a.ply", "b.ply", "a.ply"), "the 2 part files a.ply, b.ply")])
def test_one_mesh_per_part_file(two_part_stack, run_cli, meshes, needs):
    """Fewer or more --mesh than the stack's part files: one line naming the files it needs, exit 2."""
    folder = two_part_stack
    options = [item for name in meshes for item in ("--mesh", folder / name)]
    code, out, err = run_cli("verify", folder / "stack", *options)
    assert code == EXIT_INPUT and out == ""
    assert err.count("\n") == 1 and err.startswith("heoslice: error: --mesh: ") and needs in err


def test_several_meshes_for_a_one_mesh_stack_are_refused(tmp_path, run_cli):
    """A stack of one mesh takes one --mesh: two are one line, exit 2."""
    procedural.box((10.0, 10.0, 5.0)).export(tmp_path / "a.ply")
    assert run_cli("slice", tmp_path / "a.ply", "--layer", "1", "--dpi", "100", "-o", tmp_path / "stack")[0] == 0
    code, _, err = run_cli("verify", tmp_path / "stack", "--mesh", tmp_path / "a.ply", "--mesh", tmp_path / "a.ply")
    assert code == EXIT_INPUT and err.count("\n") == 1 and "one mesh file: give one --mesh (got 2)" in err


def test_two_materials_on_one_printer_channel_fail_verify(two_part_stack, run_cli):
    """A stack whose grading.materials put two masks on one printer channel (a manifest edited by hand, or
    written by another tool) fails verify with one line naming both materials, as print refuses it."""
    path = two_part_stack / "stack" / "manifest.json"
    manifest = json.loads(path.read_text())
    for material in manifest["grading"]["materials"]:
        material["channel"] = 3
    path.write_text(json.dumps(manifest))
    code, out, err = run_cli("verify", two_part_stack / "stack")
    assert code == EXIT_VERIFY, (out, err)
    assert "manifest.json: materials M1, M2 all name printer channel 3" in out + err


def test_a_wrong_mesh_count_is_refused_before_any_mesh_is_read(two_part_stack, run_cli):
    """The --mesh count is checked from the manifest before a mesh is loaded or a layer hashed: one mesh for a
    two-part stack, even a file that does not exist, is the count's one line (exit 2)."""
    code, out, err = run_cli("verify", two_part_stack / "stack", "--mesh", two_part_stack / "missing.ply")
    assert code == EXIT_INPUT, (out, err)
    assert "was sliced from the 2 part files a.ply, b.ply" in err and "missing.ply" not in err


@pytest.fixture
def metre_box_stack(tmp_path, run_cli):
    """A 0.02 x 0.01 x 0.005 m box sliced with --scale 1000 (a 20 x 10 x 5 mm part) into tmp_path/stack."""
    procedural.box((0.02, 0.01, 0.005)).export(tmp_path / "box_m.ply")
    code, _, err = run_cli("slice", tmp_path / "box_m.ply", "--scale", "1000", "--layer", "0.5", "--dpi", "254",
                           "-j", "1", "-o", tmp_path / "stack")
    assert code == 0, err
    return tmp_path


def test_the_manifest_remembers_the_scale_and_verify_applies_it(metre_box_stack, run_cli):
    """slice --scale 1000 records scale 1000 in the manifest; verify --mesh then passes without --scale (the
    mesh volume 1000 mm^3, summary scale 1000) and with the same --scale; a --scale that disagrees is one
    line naming both scales, exit 2, before any mesh is read."""
    folder = metre_box_stack
    manifest = json.loads((folder / "stack" / "manifest.json").read_text())
    assert manifest["scale"] == 1000.0
    code, out, err = run_cli("verify", folder / "stack", "--mesh", folder / "box_m.ply", "--json")
    summary = json.loads(out)
    assert code == 0 and summary["ok"], out + err
    assert summary["mesh"]["scale"] == 1000.0 and summary["mesh"]["volume_mm3"] == pytest.approx(1000.0)
    assert run_cli("verify", folder / "stack", "--mesh", folder / "box_m.ply", "--scale", "1000")[0] == 0
    code, out, err = run_cli("verify", folder / "stack", "--mesh", folder / "missing.ply", "--scale", "10")
    assert code == EXIT_INPUT and out == "" and err.count("\n") == 1
    assert err.startswith("heoslice: error: --scale: 10 disagrees with the scale 1000 ") and "missing" not in err


def test_a_stack_without_a_recorded_scale_takes_verify_scale(metre_box_stack, run_cli):
    """A manifest written before the scale was recorded (no 'scale') is still read: verify --mesh takes
    --scale as given (1000 passes) and scale 1 without it (the metre box fails on volume, exit 4)."""
    folder = metre_box_stack
    path = folder / "stack" / "manifest.json"
    manifest = json.loads(path.read_text())
    del manifest["scale"]
    path.write_text(json.dumps(manifest))
    assert run_cli("verify", folder / "stack")[0] == 0
    assert run_cli("verify", folder / "stack", "--mesh", folder / "box_m.ply", "--scale", "1000")[0] == 0
    code, out, _ = run_cli("verify", folder / "stack", "--mesh", folder / "box_m.ply")
    assert code == EXIT_VERIFY and "differs from the mesh volume" in out


@pytest.mark.parametrize("value", [0, -1000, "1000", None, True])
def test_a_malformed_scale_fails_verify(metre_box_stack, run_cli, value):
    """A manifest 'scale' that is not a positive number is a manifest problem naming 'scale' (exit 4)."""
    path = metre_box_stack / "stack" / "manifest.json"
    manifest = json.loads(path.read_text())
    manifest["scale"] = value
    path.write_text(json.dumps(manifest))
    code, out, _ = run_cli("verify", metre_box_stack / "stack")
    assert code == EXIT_VERIFY and "'scale' must be a positive number" in out


def test_the_shared_bunny_in_metres_verifies_without_scale(shared_data, tmp_path, run_cli):
    """The issue's case: scans/bunny_watertight_7k.ply (metres) sliced with --scale 1000 verifies against its
    file without --scale (volume within 1 %)."""
    bunny = shared_data / "scans" / "bunny_watertight_7k.ply"
    code, _, err = run_cli("slice", bunny, "--scale", "1000", "--layer", "1", "--dpi", "100", "-j", "1",
                           "-o", tmp_path / "bunny")
    assert code == 0, err
    code, out, err = run_cli("verify", tmp_path / "bunny", "--mesh", bunny)
    assert code == 0 and out.startswith(f"{tmp_path / 'bunny'}: OK"), out + err
def test_an_8_bit_droplet_mask_is_refused(two_part_stack, run_cli):
    """A droplet mask stored as 8-bit grey (the format says 1-bit) fails verify (exit 4, naming the file), and
    preview, export and print --dry-run refuse the same stack with the same check, writing nothing."""
    import hashlib

    import tifffile

    stack = two_part_stack / "stack"
    manifest = json.loads((stack / "manifest.json").read_text())
    channel = manifest["layers"][1]["channels"][0]
    mask_file = stack / channel["file"]
    bits = tifffile.imread(mask_file).astype(bool)
    tifffile.imwrite(mask_file, bits.astype("uint8") * 255, resolution=tuple(manifest["dpi"]),
                     resolutionunit="INCH", photometric="minisblack")
    channel["sha256"] = hashlib.sha256(mask_file.read_bytes()).hexdigest()
    (stack / "manifest.json").write_text(json.dumps(manifest))
    code, out, err = run_cli("verify", stack)
    assert code == EXIT_VERIFY and f"{mask_file.name}: pixels are 8-bit x 1, manifest says mode '1'" in out + err
    before = sorted(p.name for p in two_part_stack.iterdir())
    for command in (("preview", stack, "--layer", "0", "-o", two_part_stack / "p.png"),
                    ("export", stack, "--format", "png", "-o", two_part_stack / "e"), ("print", stack, "--dry-run")):
        code, out, err = run_cli(*command)
        assert code == EXIT_VERIFY and err.count("\n") == 1 and mask_file.name in err, (command, err)
    assert sorted(p.name for p in two_part_stack.iterdir()) == before


def test_verify_starts_without_the_slicing_stages():
    """Loading the verify command (and the stack reader it runs) does not load the mesh or layers stages, whose
    imports (kernels, trimesh) would double a plain verify's start-up."""
    import subprocess
    import sys

    code = ("import sys, heoslice.cli.verify, heoslice.stack.verify; "
            "print(sorted(m for m in sys.modules if m.startswith(('heoslice.mesh', 'heoslice.layers'))))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]", done.stdout


def test_verifying_a_stack_loads_no_slicing_stage(two_part_stack):
    """Running verify over a stack (its manifest's layer count included) loads only the layers stage's plane
    heights and packed-bit kernel, not its slicing, chaining or rasterising modules nor the mesh stage."""
    import subprocess
    import sys

    code = ("import sys\nfrom heoslice.stack import verify_stack\n"
            f"assert verify_stack({str(two_part_stack / 'stack')!r}).ok\n"
            "print(sorted(m for m in sys.modules if m.startswith(('heoslice.mesh', 'heoslice.layers'))))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == str(["heoslice.layers", "heoslice.layers.packed_kernels", "heoslice.layers.planes"])


def test_a_listed_name_with_a_backslash_is_outside_the_stack(two_part_stack):
    """A regular file whose name holds a backslash, listed by the manifest, is refused as every reader refuses
    it ("lies outside the stack"), although the folder's listing holds it (verify's one-listing path)."""
    from heoslice.stack import verify_stack

    stack = two_part_stack / "stack"
    manifest = json.loads((stack / "manifest.json").read_text())
    channel = manifest["layers"][1]["channels"][0]
    renamed = "sub\\" + channel["file"]
    (stack / channel["file"]).rename(stack / renamed)
    channel["file"] = renamed
    (stack / "manifest.json").write_text(json.dumps(manifest))
    problems = verify_stack(stack).problems
    assert any("lies outside the stack" in line and "sub\\\\" in line for line in problems), problems


def test_verify_against_a_ct_of_a_stack_without_labels_says_so(run_cli, tmp_path):
    """`verify --mesh CT.nii.gz` on a stack sliced from no label map: one line saying the stack lists no printed
    labels (not the CT's refusal as a label map, which advises an option verify does not have)."""
    import nibabel as nib
    import numpy as np

    procedural.box((10.0, 10.0, 5.0)).export(tmp_path / "box.ply")
    assert run_cli("slice", tmp_path / "box.ply", "--layer", "1", "--dpi", "50", "-o", tmp_path / "stack")[0] == 0
    ct = np.full((8, 8, 8), -1000, dtype=np.int16)
    nib.save(nib.Nifti1Image(ct, np.eye(4)), tmp_path / "ct.nii.gz")
    code, _, err = run_cli("verify", tmp_path / "stack", "--mesh", tmp_path / "ct.nii.gz")
    assert code == EXIT_INPUT and err.count("\n") == 1 and "lists no printed labels" in err
