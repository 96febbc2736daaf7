"""A coloured model's design decides its materials end to end (issue 44): the material fraction is the share of
the design's named target, whatever the order of --from/--to against the materials table; custom colours keep
their display colour; a design that disagrees with --materials is one line naming both."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from heoslice import procedural
from heoslice.stack.read import read_layer_channels, read_layer_mask, read_layer_pixels
from helpers import lesion_distance

MATERIALS = """\
[materials.gel]
color = "#f0f0f0"
channel = 1
[materials.cells]
color = "0,255,0"
channel = 2
[materials.tumour]
color = "200,0,0"
channel = 3
"""
#: The window the delivered share is held to its design over: 2 mm x 2 mm, every 1 mm.
WINDOW_MM, STEP_MM = 2.0, 1.0
#: Windows at least this solid are compared (a window mostly outside the part holds few pixels to share).
SOLID_SHARE = 0.75
TOLERANCE = 0.02


def pixel_centres(manifest: dict) -> tuple[np.ndarray, np.ndarray]:
    """x (w,), y (h,) mm of the stack's pixel centres."""
    image, (px, py) = manifest["image"], manifest["pixel_size_mm"]
    x0, y0 = image["origin_mm"]
    return x0 + (np.arange(image["width"]) + 0.5) * px, y0 - (np.arange(image["height"]) + 0.5) * py


def worst_window(stack: Path, material: str, designed, layers) -> tuple[float, int]:
    """The largest |delivered - designed| share of ``material`` over the 2 mm windows of ``layers`` (solid at
    least SOLID_SHARE), ``designed(x, y, z)`` giving the designed share at pixel centres; and the windows seen."""
    manifest = json.loads((stack / "manifest.json").read_text())
    names = [channel["material"] for channel in manifest["layers"][0]["channels"]]
    x, y = pixel_centres(manifest)
    size = int(round(WINDOW_MM / manifest["pixel_size_mm"][0]))
    step = int(round(STEP_MM / manifest["pixel_size_mm"][0]))
    worst, seen = 0.0, 0
    for index in layers:
        solid = read_layer_mask(stack, manifest, index)
        masks = read_layer_channels(stack, manifest, index)
        assert (masks.sum(axis=0) == solid).all(), "every solid pixel jets exactly one material"
        mine = masks[names.index(material)]
        z = manifest["layers"][index]["z_mm"]
        share = np.zeros(solid.shape)
        rows, cols = np.nonzero(solid)
        share[rows, cols] = designed(x[cols], y[rows], z)
        for r in range(0, solid.shape[0] - size + 1, step):
            for c in range(0, solid.shape[1] - size + 1, step):
                window = solid[r:r + size, c:c + size]
                if window.mean() < SOLID_SHARE:
                    continue
                want = share[r:r + size, c:c + size][window].mean()
                got = mine[r:r + size, c:c + size][window].mean()
                worst, seen = max(worst, abs(got - want)), seen + 1
    return worst, seen


@pytest.fixture(scope="module")
def vase_file(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("vase")
    path = folder / "vase.ply"
    procedural.vase().export(path)
    (folder / "mats.toml").write_text(MATERIALS)
    return path


# (from, to, materials file?, the target's name in the stack, the start's name): every order against the table's
# (gel, cells, tumour), named, by a table colour, and a colour outside any table
VASE_CASES = [
    ("gel", "cells", True, "cells", "gel"),
    ("cells", "gel", True, "gel", "cells"),
    ("tumour", "gel", True, "gel", "tumour"),
    ("cells", "200,0,0", True, "tumour", "cells"),  # a table colour is that material
    ("M2", "M1", False, "M1", "M2"),
    ("M1", "255,0,0", False, "255,0,0", "M1"),  # a custom colour: its own material
]


@pytest.mark.parametrize("interior", ["field", "contour"])
@pytest.mark.parametrize("start, target, with_file, target_name, start_name", VASE_CASES)
def test_vase_delivers_each_named_material_as_designed(run_cli, vase_file, tmp_path, interior, start, target,
                                                       with_file, target_name, start_name):
    """Coloured bottom-to-top from --from to --to, the vase's every 2 mm window jets the named target in the
    share f = z / H its design gives (within 2 %), in either interior and whatever the table's order."""
    mats = ["--materials", vase_file.parent / "mats.toml"] if with_file else []
    coloured = tmp_path / "v.ply"
    assert run_cli("color", vase_file, "--from", start, "--to", target, "-o", coloured, *mats)[0] == 0
    stack = tmp_path / "stack"
    code, _, err = run_cli("slice", coloured, "--layer", "1", "--dpi", "300", "-o", stack, "--interior", interior,
                           *mats)
    assert code == 0, err
    manifest = json.loads((stack / "manifest.json").read_text())
    assert manifest["grading"]["interior"] == interior
    assert manifest["grading"]["design"]["target"]["name"] == target_name
    height = manifest["z_range_mm"][1] - manifest["z_range_mm"][0]
    layers = range(0, len(manifest["layers"]), 7)
    worst, seen = worst_window(stack, target_name, lambda x, y, z: np.full(len(x), z / height), layers)
    assert seen > 50 and worst <= TOLERANCE, (worst, seen)
    worst, _ = worst_window(stack, start_name, lambda x, y, z: np.full(len(x), 1 - z / height), layers)
    assert worst <= TOLERANCE


def test_custom_colour_keeps_its_display_colour(run_cli, vase_file, tmp_path):
    """`color --to 255,0,0` is a material of that colour in the stack's record and in its RGBA preview layers
    (not 'M2' green)."""
    coloured = tmp_path / "v.ply"
    assert run_cli("color", vase_file, "--to", "255,0,0", "-o", coloured)[0] == 0
    stack = tmp_path / "stack"
    assert run_cli("slice", coloured, "--layer", "2", "--dpi", "100", "-o", stack)[0] == 0
    grading = json.loads((stack / "manifest.json").read_text())["grading"]
    assert {(m["name"], tuple(m["color"])) for m in grading["materials"]} == {("M1", (240, 240, 240)),
                                                                              ("255,0,0", (255, 0, 0))}
    preview = tmp_path / "preview"
    assert run_cli("slice", coloured, "--layer", "2", "--dpi", "100", "-o", preview, "--rgba")[0] == 0
    manifest = json.loads((preview / "manifest.json").read_text())
    top = read_layer_pixels(preview, manifest, len(manifest["layers"]) - 1)
    solid = top[..., 3] > 0
    assert np.abs(top[solid][:, :3].astype(int) - (255, 0, 0)).max(axis=1).mean() < 15


@pytest.mark.parametrize("change, message", [
    ("[materials.gel]\ncolor = \"#f0f0f0\"\n[materials.other]\ncolor = \"blue\"\n", "is not in"),
    (MATERIALS.replace("0,255,0", "0,0,255"), "but"),
    (MATERIALS.replace("channel = 2", "channel = 7"), "but"),
])
def test_a_design_that_disagrees_with_the_materials_file_is_one_line(run_cli, vase_file, tmp_path, change,
                                                                     message):
    """A recorded material missing from --materials, or with another colour or channel there, stops the slice
    with one line naming the model's material and the file; nothing is written."""
    coloured = tmp_path / "v.ply"
    mats = vase_file.parent / "mats.toml"
    assert run_cli("color", vase_file, "--from", "gel", "--to", "cells", "-o", coloured, "--materials", mats)[0] == 0
    other = tmp_path / "other.toml"
    other.write_text(change)
    code, _, err = run_cli("slice", coloured, "-o", tmp_path / "stack", "--materials", other)
    assert code != 0
    line = err.strip()
    assert "\n" not in line and "'cells'" in line and str(other) in line and message in line, line
    assert not (tmp_path / "stack" / "manifest.json").exists()


@pytest.fixture(scope="module")
def organ_files(tmp_path_factory) -> tuple[Path, Path, trimesh.Trimesh]:
    folder = tmp_path_factory.mktemp("organ")
    organ, lesion = procedural.liver_phantom(scale=0.15, subdivisions=3)
    organ.export(folder / "organ.ply")
    lesion.export(folder / "lesion.ply")
    (folder / "mats.toml").write_text(MATERIALS)
    return folder / "organ.ply", folder / "lesion.ply", lesion


@pytest.mark.parametrize("start, target", [("tumour", "gel"), ("gel", "tumour")])
def test_organ_graded_from_its_lesion_delivers_the_design(run_cli, organ_files, tmp_path, start, target):
    """The lab's case: an organ coloured by distance to its lesion (range 0..4 mm, tumour -> organ material and
    back): the field interior jets each named material in its designed share over every 2 mm window of the
    layers through the lesion, the design's f taken from a brute-force distance."""
    organ, lesion_path, lesion = organ_files
    mats = organ.parent / "mats.toml"
    coloured = tmp_path / "o.ply"
    assert run_cli("color", organ, "--ref", "surface", "--surface", lesion_path, "--from", start, "--to", target,
                   "--range", "0", "4", "--materials", mats, "-o", coloured)[0] == 0
    stack = tmp_path / "stack"
    code, _, err = run_cli("slice", coloured, "--layer", "0.5", "--dpi", "600", "-o", stack, "--materials", mats)
    assert code == 0, err
    manifest = json.loads((stack / "manifest.json").read_text())
    centre = lesion.vertices.mean(axis=0)
    through = [entry["index"] for entry in manifest["layers"] if abs(entry["z_mm"] - centre[2]) < 2.0][::4]
    assert through

    def designed(x, y, z):
        return np.clip(lesion_distance(lesion, np.column_stack([x, y, np.full(len(x), z)]), 4.0) / 4.0, 0.0, 1.0)

    worst, seen = worst_window(stack, target, designed, through)
    assert seen > 20 and worst <= TOLERANCE, (worst, seen)


def test_the_labs_reversed_liver_prints_liver_where_designed(run_cli, shared_data, tmp_path):
    """The lab's case on the shared liver scan (scaled to 160 mm) with a 10 mm lesion inside: coloured from
    tumour at the lesion to liver 10 mm away (the table lists tumour after liver), each layer through the lesion
    jets liver in the share its design gives (the mean of f over the layer's voxels, from a brute-force
    distance), within 2 %, and tumour only near the lesion."""
    organ = trimesh.load(shared_data / "anatomy" / "sofa_liver_smooth.ply", force="mesh", process=False)
    organ.apply_scale(160.0 / float(organ.extents.max()))
    organ.apply_translation(-organ.bounds[0])
    organ.export(tmp_path / "liver_mm.ply")
    lesion = trimesh.creation.icosphere(subdivisions=2, radius=10.0)
    lesion.apply_translation(organ.center_mass)
    lesion.export(tmp_path / "lesion.ply")
    (tmp_path / "mats.toml").write_text('[materials.liver]\ncolor = "#c08060"\nchannel = 1\n'
                                        '[materials.tumour]\ncolor = "200,0,0"\nchannel = 2\n')
    mats = tmp_path / "mats.toml"
    coloured = tmp_path / "liver_rev.ply"
    assert run_cli("color", tmp_path / "liver_mm.ply", "--ref", "surface", "--surface", tmp_path / "lesion.ply",
                   "--from", "tumour", "--to", "liver", "--materials", mats, "--range", "0", "10",
                   "-o", coloured)[0] == 0
    stack = tmp_path / "stack"
    code, _, err = run_cli("slice", coloured, "--layer", "1", "--dpi", "150", "--materials", mats, "-o", stack)
    assert code == 0, err
    manifest = json.loads((stack / "manifest.json").read_text())
    names = [c["material"] for c in manifest["layers"][0]["channels"]]
    x, y = pixel_centres(manifest)
    centre = lesion.vertices.mean(axis=0)
    through = [e["index"] for e in manifest["layers"] if abs(e["z_mm"] - centre[2]) < 8.0][::5]
    assert through
    for index in through:
        solid = read_layer_mask(stack, manifest, index)
        masks = read_layer_channels(stack, manifest, index)
        rows, cols = np.nonzero(solid)
        z = manifest["layers"][index]["z_mm"]
        f = np.clip(lesion_distance(lesion, np.column_stack([x[cols], y[rows], np.full(len(rows), z)]), 10.0)
                    / 10.0, 0.0, 1.0)
        delivered = masks[names.index("liver")][rows, cols]
        assert abs(delivered.mean() - f.mean()) <= TOLERANCE
        assert f.mean() < 0.999 and delivered[f == 1.0].all()  # the lesion is in this layer; liver beyond 10 mm


def test_interior_choices_are_checked(run_cli, vase_file, tmp_path):
    """--interior field needs a recorded design, and a design with shells coloured whole is sliced 'contour' by
    default; --interior with --grade is refused (one line, exit 2)."""
    code, _, err = run_cli("slice", vase_file, "--interior", "field", "-o", tmp_path / "a")
    assert code == 2 and "field" in err and "design" in err
    code, _, err = run_cli("slice", vase_file, "--interior", "contour", "--grade", "linear", "-o", tmp_path / "b")
    assert code == 2 and "--interior" in err
    shelled = tmp_path / "shell.ply"
    assert run_cli("color", vase_file, "--shell-colors", "0=255,0,0", "-o", shelled)[0] == 0
    assert run_cli("slice", shelled, "--layer", "5", "--dpi", "50", "-o", tmp_path / "c")[0] == 0
    assert json.loads((tmp_path / "c" / "manifest.json").read_text())["grading"]["interior"] == "contour"
    code, _, err = run_cli("slice", shelled, "--interior", "field", "-o", tmp_path / "d")
    assert code == 2 and "shell" in err


@pytest.mark.parametrize("start, target", [("M2", "M1"), ("M1", "255,0,0")])
def test_a_grade_without_to_grades_towards_the_designs_target(run_cli, vase_file, tmp_path, start, target):
    """`slice --grade FUNC` without --to, on a model coloured from ``start`` to ``target``, grades towards the
    design's target (not the table's second material, which may be the design's start or no material of it)."""
    coloured = tmp_path / "v.ply"
    assert run_cli("color", vase_file, "--from", start, "--to", target, "-o", coloured)[0] == 0
    stack = tmp_path / "stack"
    code, _, err = run_cli("slice", coloured, "--grade", "linear", "--layer", "2", "--dpi", "100", "-o", stack)
    assert code == 0, err
    grading = json.loads((stack / "manifest.json").read_text())["grading"]
    assert grading["target"]["name"] == target
    assert {m["name"] for m in grading["materials"]} == {start, target}


def test_color_scale_reaches_the_reference_surface(run_cli, tmp_path):
    """`color --scale 1000` of an organ and its lesion given in metres records the lesion's scale with it, so
    the slice (and verify) measure r from the lesion at the size it was coloured at: the stack is the one the same
    organ and lesion in mm give, mask for mask."""
    stacks = {}
    for unit, factor in (("mm", 1.0), ("m", 0.001)):
        organ, lesion = procedural.sphere(10.0, 3), procedural.sphere(3.0, 3)
        lesion.apply_translation((2.0, 0.0, 0.0))
        organ_path, lesion_path = tmp_path / f"organ_{unit}.ply", tmp_path / f"lesion_{unit}.ply"
        trimesh.Trimesh(organ.vertices * factor, organ.faces).export(organ_path)
        trimesh.Trimesh(lesion.vertices * factor, lesion.faces).export(lesion_path)
        coloured = tmp_path / f"coloured_{unit}.ply"
        scale = ["--scale", "1000"] if factor != 1.0 else []
        code, _, err = run_cli("color", organ_path, *scale, "--ref", "surface", "--surface", lesion_path,
                               "--func", "linear", "-o", coloured)
        assert code == 0, err
        stacks[unit] = tmp_path / f"stack_{unit}"
        code, _, err = run_cli("slice", coloured, "--layer", "1", "--dpi", "100", "-o", stacks[unit])
        assert code == 0, err
    counts = {unit: [[c["solid_pixels"] for c in layer["channels"]]
                     for layer in json.loads((stack / "manifest.json").read_text())["layers"]]
              for unit, stack in stacks.items()}
    assert counts["m"] == counts["mm"]
    code, out, _ = run_cli("verify", stacks["m"], "--json")
    bands = json.loads(out)["delivered"]["bands"]
    assert bands and max(abs(b["difference"]) for b in bands if b["voxels"] > 500) < 0.02


@pytest.mark.parametrize("role", ["--from", "--to"])
def test_color_refuses_a_colour_its_materials_file_lacks(run_cli, vase_file, tmp_path, role):
    """With --materials, `color` settles its materials against the file as `slice` will: a colour that is no
    material of the file is one line naming the option and the file (it was written, then refused by slice)."""
    other = {"--from": "--to", "--to": "--from"}[role]
    code, _, err = run_cli("color", vase_file, role, "255,255,0", other, "gel", "--materials",
                           vase_file.parent / "mats.toml", "-o", tmp_path / "v.ply")
    assert code == 2 and err.count("\n") == 1 and err.startswith(f"heoslice: error: {role}: ") and "mats.toml" in err
    assert not (tmp_path / "v.ply").exists()
    code, _, err = run_cli("color", vase_file, role, "200,0,0", other, "gel", "--materials",
                           vase_file.parent / "mats.toml", "-o", tmp_path / "v.ply")
    assert code == 0, err  # a table colour is that material


def test_a_grade_from_the_designs_target_goes_towards_its_start(run_cli, vase_file, tmp_path):
    """`slice --grade FUNC --from M2` on a model coloured M1 -> M2, without --to: the grade goes from M2 towards the
    design's other material, M1 (not from M2 to itself, a one-material print)."""
    coloured = tmp_path / "v.ply"
    assert run_cli("color", vase_file, "-o", coloured)[0] == 0
    stack = tmp_path / "stack"
    code, _, err = run_cli("slice", coloured, "--grade", "linear", "--from", "M2", "--layer", "2", "--dpi", "100",
                           "-o", stack)
    assert code == 0, err
    grading = json.loads((stack / "manifest.json").read_text())["grading"]
    assert (grading["from"]["name"], grading["target"]["name"]) == ("M2", "M1")


@pytest.mark.parametrize("args, flag", [(("--to", "gel"), "--from, --to: both are 'gel'"),
                                        (("--shell-colors", "0=1,2,3"), "--shell-colors: the design")])
def test_color_refuses_what_slice_would_refuse(run_cli, vase_file, tmp_path, args, flag):
    """`color` with a one-material table and --to naming it (a grade from it to itself), or a --shell-colors colour
    its materials file lacks: one line naming the option, nothing written (slice would refuse the file)."""
    one = tmp_path / "one.toml"
    one.write_text('[materials.gel]\ncolor = "#f0f0f0"\nchannel = 1\n')
    table = one if args[0] == "--to" else vase_file.parent / "mats.toml"
    code, _, err = run_cli("color", vase_file, *args, "--materials", table, "-o", tmp_path / "v.ply")
    assert code == 2 and err.count("\n") == 1 and flag in err
    assert not (tmp_path / "v.ply").exists()


def test_scales_that_cancel_keep_the_surface_at_the_size_it_was_coloured(run_cli, tmp_path):
    """`color --scale 10` then `slice --scale 0.1`: the surface is read at 1x by the slice, and the stack records
    that (scale 1), so verify measures r from the same surface and finds the design delivered."""
    organ, lesion = procedural.sphere(10.0, 3), procedural.sphere(3.0, 3)
    lesion.apply_translation((2.0, 0.0, 0.0))
    organ.export(tmp_path / "organ.ply")
    lesion.export(tmp_path / "lesion.ply")
    coloured = tmp_path / "c.ply"
    assert run_cli("color", tmp_path / "organ.ply", "--scale", "10", "--ref", "surface", "--surface",
                   tmp_path / "lesion.ply", "--func", "linear", "-o", coloured)[0] == 0
    stack = tmp_path / "stack"
    assert run_cli("slice", coloured, "--scale", "0.1", "--layer", "1", "--dpi", "100", "-o", stack)[0] == 0
    reference = json.loads((stack / "manifest.json").read_text())["grading"]["design"]["reference"]
    assert reference["scale"] == 1.0
    code, out, _ = run_cli("verify", stack, "--json")
    bands = json.loads(out)["delivered"]["bands"]
    assert bands and max(abs(b["difference"]) for b in bands if b["voxels"] > 500) < 0.02
