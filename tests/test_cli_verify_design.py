"""`verify` of a field-interior stack against the design its manifest records (stack/recorded_design.py, shown by
cli/material_report.py): no --design needed; the designed f per pixel is the analytic one, every band of r and the
worst 2 mm window are delivered within 2 points, and a stack whose masks were swapped is caught."""

from __future__ import annotations

import hashlib
import json
import shutil

import numpy as np
import pytest

from heoslice import procedural
from heoslice.material.field import R_STEPS
from heoslice.stack import read_manifest
from heoslice.stack.read import read_layer_channels, read_layer_mask
from heoslice.stack.recorded_design import field_comparison
from heoslice.stack.report import pixel_position

RADIUS = 6.0
#: The most f = 0.5 sin(6 pi r) + 0.5 moves over half a step of r (the field's steps, 1 / R_STEPS).
HALF_STEP = 0.5 * 6 * np.pi / (2 * R_STEPS)


@pytest.fixture(scope="module")
def sine_ball(tmp_path_factory):
    """A 6 mm sphere coloured by a point-referenced sine of 3 periods, sliced in the field interior at 600 dpi
    with 1 mm layers (12 layers): the folder and the stack."""
    from helpers import in_process

    folder = tmp_path_factory.mktemp("design")
    procedural.sphere(radius=RADIUS, subdivisions=4).export(folder / "ball.ply")
    assert in_process("color", folder / "ball.ply", "--ref", "point", "--at", "0,0,0", "--func", "sine",
                      "--periods", "3", "-o", folder / "ball_c.ply") == 0
    assert in_process("slice", folder / "ball_c.ply", "--layer", "1", "--dpi", "600", "-j", "1",
                      "-o", folder / "stack") == 0
    return folder, folder / "stack"


def test_the_recorded_design_is_the_analytic_sine_at_every_solid_pixel(sine_ball):
    """The designed target share the manifest's design gives each solid pixel is 0.5 sin(6 pi r) + 0.5 with r the
    pixel centre's distance to the centre over the largest vertex distance (written out here), to within what r
    rounded to its step (1 / R_STEPS, as the slice rounds it) changes f, plus 1e-5."""
    _, stack = sine_ball
    manifest = read_manifest(stack)
    recorded = field_comparison(stack, manifest)
    r_max = float(manifest["grading"]["design"]["range"]["mm"][1])
    assert r_max == pytest.approx(RADIUS, rel=1e-3)
    for index in (0, 5, 11):
        solid = read_layer_mask(stack, manifest, index)
        rows, cols = np.nonzero(solid)
        x, y = pixel_position(manifest, (rows, cols))
        r = np.sqrt(x ** 2 + y ** 2 + manifest["layers"][index]["z_mm"] ** 2) / r_max
        expected = np.clip(0.5 * np.sin(6 * np.pi * r) + 0.5, 0, 1)
        mix, bands = recorded.design(index)
        assert np.abs(mix[recorded.target][rows, cols] - expected).max() <= HALF_STEP + 1e-5
        assert np.allclose(mix.sum(axis=0)[rows, cols], 1.0)
        assert (bands[rows, cols] == np.minimum((r * 10).astype(int), 9)).mean() > 0.999


def test_verify_compares_a_field_stack_with_its_recorded_design(sine_ball, run_cli):
    """verify without --design: every band of r (10) and the worst 2 mm window within 2 points, no warning; the
    text names the bands of r."""
    _, stack = sine_ball
    code, out, err = run_cli("verify", stack, "--json")
    assert code == 0, out + err
    summary = json.loads(out)
    assert summary["warnings"] == []
    delivered = summary["delivered"]
    assert delivered["design"] == {"from": "manifest", "bands_of": "r", "target": "M2"}
    assert len(delivered["bands"]) == 10
    assert all(abs(band["difference"]) <= 0.02 for band in delivered["bands"]), delivered["bands"]
    assert sum(band["voxels"] for band in delivered["bands"]) == delivered["solid"]["voxels"]
    assert abs(delivered["worst_window"]["difference"]) <= 0.02, delivered["worst_window"]
    assert delivered["worst_window"]["solid_pixels"] >= 1100
    assert delivered["worst_window"]["material"] == "M2"  # the target, as the bands give it
    code, out, err = run_cli("verify", stack)
    assert code == 0 and err == ""
    assert "  r 0.9-1.0: " in out and "  worst 2 mm window: layer " in out


def test_a_stack_with_swapped_masks_fails_the_comparison(sine_ball, tmp_path, run_cli):
    """Swapping the M1 and M2 masks of one layer (their files, hashes and counts, so the stack still verifies)
    is caught: the worst window is far off, and verify fails (exit 4) saying the delivered material differs from
    the design."""
    _, stack = sine_ball
    broken = tmp_path / "broken"
    shutil.copytree(stack, broken)
    manifest = json.loads((broken / "manifest.json").read_text())
    first, second = manifest["layers"][6]["channels"]
    a, b = (broken / first["file"]).read_bytes(), (broken / second["file"]).read_bytes()
    (broken / first["file"]).write_bytes(b)
    (broken / second["file"]).write_bytes(a)
    for channel, data in ((first, b), (second, a)):
        channel["sha256"] = hashlib.sha256(data).hexdigest()
    first["solid_pixels"], second["solid_pixels"] = second["solid_pixels"], first["solid_pixels"]
    (broken / "manifest.json").write_text(json.dumps(manifest))
    code, out, err = run_cli("verify", broken, "--json")
    summary = json.loads(out)
    assert code == 4 and not summary["ok"], summary
    assert abs(summary["delivered"]["worst_window"]["difference"]) > 0.1
    assert summary["delivered"]["worst_window"]["layer"] == 6
    assert [line for line in summary["problems"] if "differs from the design by more than 2 points" in line] == \
        summary["problems"] and len(summary["problems"]) == 1, summary
    code, out, err = run_cli("verify", broken)
    assert code == 4 and "differs from the design by more than 2 points" in out and "do not print" in err


@pytest.mark.parametrize("change", ["missing", "changed"])
def test_a_missing_or_changed_reference_surface_is_one_warning(sine_ball, tmp_path, run_cli, change):
    """A recorded surface reference that is missing, or whose bytes changed: one warning line naming it, the
    design not compared (no bands, no window), the stack still verified."""
    folder, stack = sine_ball
    copy = tmp_path / "stack"
    shutil.copytree(stack, copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    path = tmp_path / "gone.ply" if change == "missing" else folder / "ball.ply"
    manifest["grading"]["design"]["reference"] = {"kind": "surface", "path": str(path), "sha256": "0" * 64}
    (copy / "manifest.json").write_text(json.dumps(manifest))
    code, out, err = run_cli("verify", copy, "--json")
    summary = json.loads(out)
    assert code == 0 and len(summary["warnings"]) == 1, summary
    assert str(path) in summary["warnings"][0] and "not compared with the design" in summary["warnings"][0]
    assert ("missing" if change == "missing" else "changed") in summary["warnings"][0]
    assert summary["delivered"]["design"] is None and summary["delivered"]["bands"] == []
    assert summary["delivered"]["worst_window"] is None


def test_a_surface_found_beside_the_moved_model_is_the_one_verify_compares_with(tmp_path, run_cli):
    """A model moved with its reference surface slices against the surface beside it, and the stack's record names
    that file: verify compares the stack with the design (bands of r) instead of warning that the surface is
    missing."""
    organ, lesion = procedural.sphere(10.0, 3), procedural.sphere(3.0, 3)
    lesion.apply_translation((2.0, 0.0, 0.0))
    first, moved = tmp_path / "first", tmp_path / "moved"
    first.mkdir()
    organ.export(first / "organ.ply")
    lesion.export(first / "lesion.ply")
    assert run_cli("color", first / "organ.ply", "--ref", "surface", "--surface", first / "lesion.ply", "--func",
                   "linear", "-o", first / "organ_c.ply")[0] == 0
    first.rename(moved)
    stack = tmp_path / "stacks" / "organ"
    code, _, err = run_cli("slice", moved / "organ_c.ply", "--layer", "1", "--dpi", "100", "-o", stack)
    assert code == 0, err
    reference = json.loads((stack / "manifest.json").read_text())["grading"]["design"]["reference"]
    assert reference["path"] == str((moved / "lesion.ply").resolve())
    code, out, _ = run_cli("verify", stack, "--json")
    summary = json.loads(out)
    assert summary["warnings"] == [] and summary["delivered"]["bands"], summary


def sliding_sums(values: np.ndarray, size: int) -> np.ndarray:
    """Reference: the sum over the size x size window at every top-left pixel, window by window."""
    return np.lib.stride_tricks.sliding_window_view(values, (size, size)).sum(axis=(-2, -1))


def test_a_deviation_between_the_tiles_is_found(sine_ball, tmp_path, run_cli):
    """One layer of the sine ball delivering M2 where it should be mixed over an 8 x 8 pixel patch centred on the
    corner of four 47-pixel tiles (so the stack still verifies: hashes and counts rewritten): every tile from the
    image's top-left is within 2 points, and a window over the patch is not. verify finds that window (exit 4),
    its shares are those a brute-force sliding 47-pixel window gives at its pixel, it is within half a point of
    the worst sliding window at any pixel, and the report states the 0.47 mm step between windows."""
    from heoslice.stack.tiff import encode_bilevel_tiff

    _, stack = sine_ball
    broken = tmp_path / "broken"
    shutil.copytree(stack, broken)
    manifest = json.loads((broken / "manifest.json").read_text())
    layer, size, corner, half = 6, 47, 3 * 47, 4
    solid = read_layer_mask(broken, manifest, layer)
    masks = read_layer_channels(broken, manifest, layer)
    recorded = field_comparison(broken, manifest)
    mix, _ = recorded.design(layer)
    patch = (slice(corner - half, corner + half),) * 2
    assert solid[patch].all() and mix[recorded.target][patch].mean() < 0.8
    masks[:, patch[0], patch[1]] = False
    masks[recorded.target][patch] = True
    for channel, mask in zip(manifest["layers"][layer]["channels"], masks):
        data = encode_bilevel_tiff(np.packbits(mask, axis=-1), mask.shape[1], tuple(manifest["dpi"]),
                                   manifest["image"]["compression"], manifest["layer_height_mm"])
        (broken / channel["file"]).write_bytes(data)
        channel["sha256"], channel["solid_pixels"] = hashlib.sha256(data).hexdigest(), int(mask.sum())
    (broken / "manifest.json").write_text(json.dumps(manifest))

    count = sliding_sums(solid.astype(np.int64), size)
    compared = count >= 0.5 * size * size
    off = np.stack([np.abs(sliding_sums((mask & solid).astype(np.float64), size)
                           - sliding_sums(np.where(solid, share, 0.0), size)) / np.maximum(count, 1)
                    for mask, share in zip(masks, mix)]) * compared
    assert off[:, ::size, ::size].max() <= 0.02 < off.max()
    code, out, err = run_cli("verify", broken, "--json")
    summary = json.loads(out)
    worst = summary["delivered"]["worst_window"]
    assert code == 4 and worst["layer"] == layer, worst
    column, row = worst["pixel"]
    material = [m["name"] for m in summary["delivered"]["materials"]].index(worst["material"])
    assert abs(worst["difference"]) == pytest.approx(off[material, row, column], abs=1e-6)
    assert off.max() - 0.005 <= abs(worst["difference"]) <= off.max() + 1e-9
    assert worst["step_mm"] == pytest.approx([11 * 25.4 / 600] * 2)
    assert "the worst 2 mm window (layer 6)" in summary["problems"][0]
    code, out, err = run_cli("verify", broken)
    assert code == 4 and "windows every 0.466 mm" in out


def test_windows_of_a_coarse_stack_hold_as_many_pixels_as_at_600_dpi(tmp_path, run_cli):
    """At 150 dpi a 2 mm window is 12 x 12 pixels, less than one ordered-dither tile: verify's windows there are 47
    pixels a side (7.96 mm), as at 600 dpi, so the linear vase (every band within 2 points) verifies clean, and
    the report names the window's true size."""
    from helpers import in_process

    from heoslice.stack.report import WINDOW_LEAST_PIXELS

    procedural.vase().export(tmp_path / "vase.ply")
    assert in_process("color", tmp_path / "vase.ply", "--func", "linear", "-o", tmp_path / "vase_c.ply") == 0
    assert in_process("slice", tmp_path / "vase_c.ply", "--layer", "0.5", "--dpi", "150", "-o",
                      tmp_path / "stack") == 0
    code, out, err = run_cli("verify", tmp_path / "stack", "--json")
    worst = json.loads(out)["delivered"]["worst_window"]
    assert code == 0, (out, err)
    assert worst["size_mm"] == pytest.approx([WINDOW_LEAST_PIXELS * 25.4 / 150] * 2)
    assert abs(worst["difference"]) <= 0.02
    code, out, _ = run_cli("verify", tmp_path / "stack")
    assert code == 0 and "worst 7.96 mm window" in out


def test_a_design_with_no_window_half_solid_says_so(tmp_path, run_cli):
    """A designed stack too thin for any window to be half solid (a 3 mm plate coloured across, at 150 dpi: its
    windows are 7.96 mm) says its design is compared per band only, rather than leaving the window line out."""
    from helpers import in_process

    procedural.box((40.0, 3.0, 3.0)).export(tmp_path / "plate.ply")
    assert in_process("color", tmp_path / "plate.ply", "--ref", "plane", "--func", "linear", "-o",
                      tmp_path / "plate_c.ply") == 0
    assert in_process("slice", tmp_path / "plate_c.ply", "--layer", "0.5", "--dpi", "150", "-o",
                      tmp_path / "stack") == 0
    code, out, err = run_cli("verify", tmp_path / "stack")
    assert code == 0, out + err
    assert "no 7.96 mm window is half solid: the design is compared per band only" in out


@pytest.mark.parametrize("function", [("--expr", "0.5-0.5*cos(2*pi*r)"), ("--func", "constant", "--lambda", "0.3")])
def test_an_expression_or_constant_design_is_compared(tmp_path, run_cli, function):
    """A design whose f table is float64 (an expression, a constant) is compared as the slice dithered it (in
    float32): verify of its field stack reports ten bands of r within 2 points and exits 0 (the compiled tally
    was handed the float64 table and crashed)."""
    from helpers import in_process

    procedural.sphere(radius=4.0, subdivisions=3).export(tmp_path / "ball.ply")
    assert in_process("color", tmp_path / "ball.ply", "--ref", "point", "--at", "0,0,0", *function, "-o",
                      tmp_path / "ball_c.ply") == 0
    assert in_process("slice", tmp_path / "ball_c.ply", "--layer", "1", "--dpi", "300", "-j", "1", "-o",
                      tmp_path / "stack") == 0
    code, out, err = run_cli("verify", tmp_path / "stack", "--json")
    assert code == 0, out + err
    delivered = json.loads(out)["delivered"]
    assert delivered["design"]["bands_of"] == "r" and delivered["bands"]
    assert all(abs(band["difference"]) <= 0.02 for band in delivered["bands"]), delivered["bands"]


def test_a_layer_listing_no_droplet_masks_is_counted_without_its_design(sine_ball, tmp_path, run_cli):
    """A field stack one of whose layers lists no droplet masks (its masks' files removed from the manifest and
    the folder: the manifest allows it) still verifies and reports; that layer's solid counts without a design
    (it crashed the compiled tally)."""
    _, stack = sine_ball
    edited = tmp_path / "edited"
    shutil.copytree(stack, edited)
    manifest = json.loads((edited / "manifest.json").read_text())
    layer = manifest["layers"][0]
    for channel in layer.pop("channels"):
        (edited / channel["file"]).unlink()
    (edited / "manifest.json").write_text(json.dumps(manifest))
    code, out, err = run_cli("verify", edited, "--json")
    assert "internal error" not in err, err
    summary = json.loads(out)
    assert summary["delivered"]["bands"], summary


@pytest.mark.parametrize("edit", [
    lambda g: g["design"]["reference"].update(kind="banana"),
    lambda g: g["design"]["reference"].pop("point"),
    lambda g: g["design"]["function"].update(kind="wobble"),
    lambda g: g["design"]["function"].update(kind="expression", expression='__import__("os").getcwd()'),
    lambda g: g["design"]["range"].update(mm=[5, 5]),
    lambda g: g["design"]["target"].update(name=7) if isinstance(g["design"]["target"], dict) else g["design"].pop(
        "target"),
    lambda g: g.pop("design"),
    lambda g: g.update(design=None),
], ids=["kind", "no-point", "function", "expression", "range", "target", "no-design", "null-design"])
def test_a_field_stack_whose_design_record_cannot_be_read_fails(sine_ball, tmp_path, run_cli, edit):
    """A field-interior stack whose manifest's design record was edited into one heoslice cannot read (an unknown
    reference or function kind, a point or the record missing, an empty range, an expression of an unknown
    function) fails verify with one problem line naming the stack, exit 4, never an internal error nor a pass
    without the comparison (a crash with KeyError or TypeError, or a warning and exit 0, before)."""
    _, stack = sine_ball
    edited = tmp_path / "edited"
    shutil.copytree(stack, edited)
    manifest = json.loads((edited / "manifest.json").read_text())
    edit(manifest["grading"])
    (edited / "manifest.json").write_text(json.dumps(manifest))
    code, out, err = run_cli("verify", edited, "--json")
    assert code == 4, (code, out, err)
    assert "internal error" not in err and "Traceback" not in err
    problems = json.loads(out)["problems"]
    assert len(problems) == 1 and problems[0].startswith(f"{edited}: ") and "design record" in problems[0], problems


def test_a_band_of_fewer_voxels_than_a_window_is_shown_not_judged(tmp_path, run_cli):
    """A plate one pixel thin (0.05 mm at 150 dpi) coloured by a plane-referenced sine: its bands hold a few dozen
    voxels, over which no halftone holds a share within 2 points, so they are reported, marked not judged, and the
    stack verifies (exit 0; it failed by 28.5 points before); a band's `judged` in --json says which."""
    from helpers import in_process

    from heoslice.stack.report import WINDOW_LEAST_PIXELS, WINDOW_MIN_SOLID

    procedural.box((0.05, 10.0, 5.0)).export(tmp_path / "plate.ply")
    assert in_process("color", tmp_path / "plate.ply", "--ref", "plane", "--func", "sine", "-o",
                      tmp_path / "plate_c.ply") == 0
    assert in_process("slice", tmp_path / "plate_c.ply", "--layer", "1", "--dpi", "150", "-o",
                      tmp_path / "stack") == 0
    code, out, err = run_cli("verify", tmp_path / "stack", "--json")
    assert code == 0, out + err
    bands = json.loads(out)["delivered"]["bands"]
    least = np.ceil(WINDOW_MIN_SOLID * WINDOW_LEAST_PIXELS ** 2)
    assert bands and all(band["judged"] == (band["voxels"] >= least) for band in bands)
    assert not any(band["judged"] for band in bands)
    code, out, _ = run_cli("verify", tmp_path / "stack")
    assert code == 0 and "not judged" in out
