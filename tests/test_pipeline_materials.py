"""The material model (pipeline/materials.py): the design card's flow prints what ``color`` designed.

The expected material share is the paper's distribution function written out literally (eq. 3-5 with
the ``color`` defaults) of r = z / height (the reference plane z = 0); the masks are read back with
tifffile, and what the printer executed is checked against the CRC of those masks.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import tifffile
from helpers import executed_on_simulator

from heoslice import procedural
from heoslice.material import Material
from heoslice.mesh import load_mesh, without_materials
from heoslice.pipeline import SliceSpec, material_job, slice_to_stack
from heoslice.printing import stack_job
from heoslice.printing import protocol as P

#: The distribution functions as the paper writes them, with ``heoslice color``'s default coefficients.
LITERAL = {
    "linear": lambda r: r,
    "quadratic": lambda r: r * r,
    "sine": lambda r: 0.5 * math.sin(2 * math.pi * r) + 0.5,
}
LAYER_MM, DPI, WINDOW_MM = 1.0, 600.0, 2.0


@pytest.fixture(scope="module")
def vase_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("vase") / "vase.ply"
    path.write_bytes(procedural.vase().export(file_type="ply", encoding="binary"))
    return path


def window_shares(solid: np.ndarray, part: np.ndarray, size: int) -> np.ndarray:
    """The share of ``part`` among the solid pixels of every size x size window (stride size / 4) that is at
    least 90 % solid: (n,) float."""
    def box_sums(image):
        total = np.pad(image.astype(np.int64).cumsum(0).cumsum(1), ((1, 0), (1, 0)))
        return total[size:, size:] - total[:-size, size:] - total[size:, :-size] + total[:-size, :-size]

    stride = max(1, size // 4)
    solid_sum = box_sums(solid)[::stride, ::stride]
    part_sum = box_sums(part & solid)[::stride, ::stride]
    keep = solid_sum >= 0.9 * size * size
    return part_sum[keep] / solid_sum[keep]


@pytest.mark.parametrize("func", sorted(LITERAL))
def test_design_card_flow_prints_both_materials(run_cli, vase_file, tmp_path, func):
    """`color vase.ply --func F`, `slice` with no other option, `print` to the simulated controller: every
    layer has an M1 and an M2 mask partitioning its solid pixels; M2's share in every 2 mm x 2 mm window
    (at least 90 % solid) is the function of the layer's height within 2 %; the controller executes every
    layer once with the CRC of all three channels (solid, M1, M2) as read back from the TIFFs."""
    coloured = tmp_path / f"vase_{func}.ply"
    code, _, stderr = run_cli("color", str(vase_file), "--func", func, "-o", str(coloured))
    assert code == 0, stderr
    stack = tmp_path / "stack"
    code, stdout, stderr = run_cli("slice", str(coloured), "--layer", str(LAYER_MM), "--dpi", str(DPI),
                                   "-o", str(stack))
    assert code == 0, stderr
    assert "materials M1, M2: a solid mask and 2 droplet masks per layer" in stdout
    manifest = json.loads((stack / "manifest.json").read_text())
    assert manifest["image"]["mode"] == "1"
    height = manifest["z_range_mm"][1] - manifest["z_range_mm"][0]
    size = round(WINDOW_MM / 25.4 * DPI)
    packed_layers = []
    for entry in manifest["layers"]:
        assert [c["material"] for c in entry["channels"]] == ["M1", "M2"]
        solid = tifffile.imread(stack / entry["file"]).astype(bool)
        m1, m2 = (tifffile.imread(stack / c["file"]).astype(bool) for c in entry["channels"])
        assert not (m1 & m2).any() and np.array_equal(m1 | m2, solid)
        expected = LITERAL[func]((entry["z_mm"] - manifest["z_range_mm"][0]) / height)
        shares = window_shares(solid, m2, size)
        assert len(shares) > 0
        assert np.abs(shares - expected).max() <= 0.02, (entry["index"], expected, shares.min(), shares.max())
        packed_layers.append(b"".join(np.packbits(mask, axis=1).tobytes() for mask in (solid, m1, m2)))
    job, get_layer = stack_job(stack)
    assert job.channels == 3 and job.names == ("solid", "M1", "M2")
    executed = executed_on_simulator(job, get_layer)
    assert [e.layer for e in executed] == list(range(len(manifest["layers"])))
    assert [e.crc for e in executed] == [P.crc32(data) for data in packed_layers]


def test_rgba_preview_stack_is_coloured_by_the_materials(run_cli, vase_file, tmp_path):
    """`slice --rgba` of a coloured mesh writes an RGBA preview stack, no droplet masks, whose solid pixels are
    all (1 - f) M1 + f M2 in display colours (never white, never the mesh's own colours off the M1-M2 line)."""
    coloured = tmp_path / "vase_linear.ply"
    assert run_cli("color", str(vase_file), "--func", "linear", "-o", str(coloured))[0] == 0
    stack = tmp_path / "rgba"
    code, stdout, stderr = run_cli("slice", str(coloured), "--layer", "6", "--dpi", "100", "--rgba", "-o", str(stack))
    assert code == 0, stderr
    assert "RGBA preview" in stdout
    manifest = json.loads((stack / "manifest.json").read_text())
    assert manifest["image"]["mode"] == "RGBA" and "channels" not in manifest["layers"][0]
    m1, m2 = np.array([240, 240, 240]), np.array([0, 255, 0])
    for entry in manifest["layers"]:
        image = tifffile.imread(stack / entry["file"])
        rgb = image[image[..., 3] > 0][:, :3].astype(float)
        f = (240 - rgb[:, 0]) / 240
        assert np.abs(rgb - (m1 + f[:, None] * (m2 - m1))).max() <= 1.0


def test_material_job_rule(vase_file, tmp_path):
    """The rule: an uncoloured mesh is one material (no grading, a solid mask); a material fraction gives
    M1 and M2 masks; colours that all map to one material are one material, colours of two a mask each (and
    the table's unused second material none); an RGBA request keeps the grade without masks;
    without_materials drops what a mesh carries."""
    plain = load_mesh(vase_file)
    spec = SliceSpec(layer_height_mm=1.0)
    assert material_job(plain, spec).spec.grade is None and not material_job(plain, spec).spec.channels
    fraction = load_mesh(vase_file)
    fraction = type(fraction)(**{**fraction.__dict__, "material": fraction.vertices[:, 2] / 60.0})
    job = material_job(fraction, spec)
    assert job.spec.channels and [m.name for m in job.spec.grade.channel_materials()] == ["M1", "M2"]
    assert np.allclose(job.vertex_mix.sum(axis=1), 1.0)
    assert np.allclose(job.vertex_mix[:, 1], np.clip(fraction.vertices[:, 2] / 60.0, 0, 1))
    rgba = material_job(fraction, SliceSpec(layer_height_mm=1.0, channels=False))
    assert rgba.spec.grade is not None and rgba.spec.channels is False
    grey = np.full((len(plain.vertices), 3), 200, dtype=np.uint8)
    one_colour = type(plain)(**{**plain.__dict__, "colors": grey})
    assert material_job(one_colour, spec).spec.grade is None
    table = (Material("a", (200, 200, 200), 1), Material("b", (0, 0, 255), 2), Material("c", (255, 0, 0), 3))
    two = grey.copy()
    two[plain.vertices[:, 2] > 30] = (250, 10, 10)
    job = material_job(type(plain)(**{**plain.__dict__, "colors": two}), SliceSpec(layer_height_mm=1.0,
                                                                                    materials=table))
    assert [m.name for m in job.spec.grade.channel_materials()] == ["a", "c"]
    assert set(np.unique(job.vertex_mix.argmax(axis=1))) == {0, 1}
    assert without_materials(fraction).material is None and without_materials(one_colour).colors is None



def test_colours_of_some_of_a_larger_table_map_to_their_own_masks(vase_file):
    """A four-material table whose colours the mesh uses only two of (the first and the fourth): the masks are
    the first (M1 by the default roles: the base) and the used fourth, each vertex's mix is one at its own
    material's column (a table material the mesh does not use has no column to look up, nor a mask)."""
    plain = load_mesh(vase_file)
    table = (Material("a", (255, 0, 0), 1), Material("b", (0, 255, 0), 2), Material("c", (0, 0, 255), 3),
             Material("d", (255, 255, 0), 4))
    upper = plain.vertices[:, 2] > 30
    colors = np.where(upper[:, None], [250, 250, 5], [250, 5, 5]).astype(np.uint8)
    job = material_job(type(plain)(**{**plain.__dict__, "colors": colors}), SliceSpec(materials=table))
    assert [m.name for m in job.spec.grade.channel_materials()] == ["a", "d"]
    assert np.array_equal(job.vertex_mix.argmax(axis=1), np.where(upper, 1, 0))
    assert np.array_equal(job.vertex_mix.sum(axis=1), np.ones(len(plain.vertices)))

def test_a_library_table_without_channels_gets_them_as_a_materials_file_does(vase_file, tmp_path):
    """A SliceSpec table whose materials name no printer channel (a library caller's, not a file's): each
    gets its place in the table as its channel, as a materials file's would, so a mesh coloured with only
    the first and the third material sends the third's mask to channel 3, never to the unused second's
    cartridge (channel 2), in the job and in the manifest; a graded spec's own materials follow the table."""
    plain = load_mesh(vase_file)
    table = (Material("gel", (240, 240, 240)), Material("red", (255, 0, 0)), Material("blue", (0, 0, 255)))
    upper = plain.vertices[:, 2] > 30
    colors = np.where(upper[:, None], [0, 0, 250], [240, 240, 240]).astype(np.uint8)
    coloured = type(plain)(**{**plain.__dict__, "colors": colors})
    job = material_job(coloured, SliceSpec(materials=table))
    assert [(m.name, m.channel) for m in job.spec.grade.channel_materials()] == [("gel", 1), ("blue", 3)]
    manifest, _ = slice_to_stack(coloured, tmp_path / "stack", SliceSpec(layer_height_mm=5.0, dpi=(50.0, 50.0),
                                                                         materials=table))
    assert [(m["name"], m["channel"]) for m in manifest["grading"]["materials"]] == [("gel", 1), ("blue", 3)]
    from heoslice.grading import GradeSpec, RegionSpec

    graded = GradeSpec(regions=RegionSpec(), function=None, target=None, start=None, base=table[0], second=table[2])
    job = material_job(coloured, SliceSpec(materials=table, grade=graded, channels=True))
    assert {(m.name, m.channel) for m in job.spec.grade.channel_materials()} == {("gel", 1), ("blue", 3)}


def test_two_masks_on_one_printer_channel_are_refused_before_slicing(run_cli, vase_file, tmp_path):
    """A graded slice whose two materials name the same printer channel is refused in one line naming both
    (exit 2), with no stack written: print could not send both masks; with channels apart it slices."""
    table = tmp_path / "materials.toml"
    table.write_text('[materials.gel]\ncolor = "240,240,240"\nchannel = 1\n'
                     '[materials.cells]\ncolor = "0,255,0"\nchannel = 1\n')
    out = tmp_path / "stack"
    code, _, err = run_cli("slice", vase_file, "--layer", "5", "--dpi", "100", "--materials", table,
                           "--grade", "linear", "-o", out)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "'gel' and 'cells' both print on channel 1" in err and "Traceback" not in err
    assert not (out / "manifest.json").exists()
    table.write_text(table.read_text().replace("channel = 1\n[materials.cells]", "channel = 2\n[materials.cells]"))
    code, _, err = run_cli("slice", vase_file, "--layer", "5", "--dpi", "100", "--materials", table,
                           "--grade", "linear", "-o", out)
    assert code == 0, err


def coloured_vase(vase_file: Path, folder: Path, lower: tuple, upper: tuple) -> Path:
    """The vase with ``lower`` / ``upper`` (r, g, b) vertex colours below / above z = 30 mm, as a PLY file."""
    mesh = procedural.vase()
    colors = np.where((mesh.vertices[:, 2] > 30)[:, None], upper, lower).astype(np.uint8)
    mesh.visual.vertex_colors = np.column_stack([colors, np.full(len(colors), 255, np.uint8)])
    path = folder / "coloured.ply"
    path.write_bytes(mesh.export(file_type="ply", encoding="binary"))
    return path


@pytest.mark.parametrize("mode", ["default", "--channels", "[shells]"])
def test_a_table_material_the_colours_do_not_use_shares_a_channel_freely(run_cli, vase_file, tmp_path, mode):
    """A lab table with two alternatives on one cartridge (gel and gel_b on channel 1, cells on 2): a mesh
    coloured with gel and cells only slices (no mask, so no channel, for gel_b), asked for masks or not and
    with a [shells] table, and its stack verifies."""
    coloured = coloured_vase(vase_file, tmp_path, (240, 240, 240), (0, 255, 0))
    table = tmp_path / "materials.toml"
    shells = '[shells]\n0 = "gel"\n' if mode == "[shells]" else ""
    table.write_text('[materials.gel]\ncolor = "240,240,240"\nchannel = 1\n'
                     '[materials.gel_b]\ncolor = "200,200,255"\nchannel = 1\n'
                     '[materials.cells]\ncolor = "0,255,0"\nchannel = 2\n' + shells)
    out = tmp_path / "stack"
    options = ["--channels"] if mode == "--channels" else []
    code, _, err = run_cli("slice", coloured, "--layer", "5", "--dpi", "100", "--materials", table, "-o", out,
                           *options)
    assert code == 0, err
    manifest = json.loads((out / "manifest.json").read_text())
    assert [m["name"] for m in manifest["grading"]["materials"]] == ["gel", "cells"]
    code, out_text, err = run_cli("verify", out)
    assert code == 0, out_text + err


@pytest.mark.parametrize("channels, blue", [(("1", "2", None), 3), ((None, None, None), 3)])
def test_a_material_without_a_channel_keeps_its_tables_channel_whatever_the_mesh_uses(run_cli, vase_file, tmp_path,
                                                                                     channels, blue):
    """gel, red and blue, blue without a channel (and all three without one): a mesh coloured gel and blue
    sends blue to the channel the table leaves it (3), never to red's cartridge (2) because red is unused;
    the manifest records it, and the print job puts the mask there."""
    coloured = coloured_vase(vase_file, tmp_path, (240, 240, 240), (0, 0, 255))
    table = tmp_path / "materials.toml"
    lines = []
    for name, color, channel in zip(("gel", "red", "blue"), ("240,240,240", "255,0,0", "0,0,255"), channels):
        lines.append(f'[materials.{name}]\ncolor = "{color}"\n' + (f"channel = {channel}\n" if channel else ""))
    table.write_text("".join(lines))
    out = tmp_path / "stack"
    code, _, err = run_cli("slice", coloured, "--layer", "5", "--dpi", "100", "--materials", table, "-o", out)
    assert code == 0, err
    manifest = json.loads((out / "manifest.json").read_text())
    assert [(m["name"], m["channel"]) for m in manifest["grading"]["materials"]] == [("gel", 1), ("blue", blue)]
    job, _ = stack_job(out)
    assert job.names == ("solid", "gel", "unused", "blue")


def test_a_colour_outside_the_table_gets_a_channel_no_table_material_names(run_cli, tmp_path):
    """A [shells] colour that is no table material (0,0,255) gets the lowest channel that neither the table
    (gel 1, red 2, cells 4) nor another mask names (3), written in the manifest: a print sends it to no table
    material's cartridge."""
    two = procedural.box((10.0, 10.0, 6.0))
    other = procedural.box((4.0, 4.0, 6.0), origin=(20.0, 0.0, 0.0))
    mesh_path = tmp_path / "two.ply"
    (two + other).export(mesh_path)
    table = tmp_path / "materials.toml"
    table.write_text('[materials.gel]\ncolor = "240,240,240"\nchannel = 1\n'
                     '[materials.red]\ncolor = "255,0,0"\nchannel = 2\n'
                     '[materials.cells]\ncolor = "0,255,0"\nchannel = 4\n'
                     '[shells]\n1 = "0,0,255"\n')
    out = tmp_path / "stack"
    code, _, err = run_cli("slice", mesh_path, "--layer", "2", "--dpi", "100", "--materials", table, "-o", out)
    assert code == 0, err
    manifest = json.loads((out / "manifest.json").read_text())
    assert [(m["name"], m["channel"]) for m in manifest["grading"]["materials"]] == [("gel", 1), ("0,0,255", 3)]


def test_interior_takes_the_material_of_the_nearest_outer_ring_point(tmp_path):
    """Where a ring's materials differ (an L-shaped prism whose vertices are red where x > 4 mm, blue elsewhere),
    every solid pixel jets the material of the outer ring's point nearest its centre, computed independently
    with shapely as the nearer of the ring's red and blue parts; only pixels whose distances to the two parts
    differ by less than 0.75 mm may differ (the start mix is taken per 0.5 mm lattice cell, whose diagonal is
    0.71 mm, and the ring's material is interpolated between its last blue and first red vertex)."""
    import shapely
    import trimesh

    outline = shapely.Polygon([(0, 0), (12, 0), (12, 4), (5, 4), (5, 10), (0, 10)]).segmentize(0.25)
    prism = trimesh.creation.extrude_polygon(outline, 3.0)
    red = prism.vertices[:, 0] > 4.0
    prism.visual.vertex_colors = np.where(red[:, None], [255, 0, 0, 255], [0, 0, 255, 255]).astype(np.uint8)
    model = tmp_path / "prism.ply"
    model.write_bytes(prism.export(file_type="ply", encoding="binary"))
    table = (Material("red", (255, 0, 0), 1), Material("blue", (0, 0, 255), 2))
    stack = tmp_path / "stack"
    manifest, _ = slice_to_stack(load_mesh(model), stack, SliceSpec(layer_height_mm=1.0, dpi=(300.0, 300.0),
                                                                     jobs=1, materials=table))
    entry = manifest["layers"][1]
    solid = tifffile.imread(stack / entry["file"]).astype(bool)
    masks = {c["material"]: tifffile.imread(stack / c["file"]).astype(bool) for c in entry["channels"]}
    rows, cols = np.nonzero(solid)
    (x_left, y_top), (px, py) = manifest["image"]["origin_mm"], manifest["pixel_size_mm"]
    centres = shapely.points(x_left + (cols + 0.5) * px, y_top - (rows + 0.5) * py)
    ring = outline.exterior
    red_part = ring.intersection(shapely.box(4.25, -1, 13, 11))
    blue_part = ring.intersection(shapely.box(-1, -1, 4.0, 11))
    to_red, to_blue = shapely.distance(centres, red_part), shapely.distance(centres, blue_part)
    decided = np.abs(to_red - to_blue) > 0.75
    expected_red = to_red < to_blue
    got_red = masks["red"][rows, cols]
    assert decided.sum() > 0.6 * len(rows) and expected_red[decided].any() and not expected_red[decided].all()
    assert np.array_equal(got_red[decided], expected_red[decided])
    assert np.array_equal(masks["blue"][rows, cols][decided], ~expected_red[decided])


def test_a_scans_many_colours_collapsing_onto_two_materials_are_said(run_cli, vase_file, tmp_path):
    """A scan's many shades (a gradient of reds to greens up the vase) that map onto the table's two materials give one
    warning before the slice, naming the count and the materials; colours that are the materials' own display
    colours (two colours, two materials) and a mesh without colours give none."""
    from heoslice.material import DEFAULT_MATERIALS
    from heoslice.pipeline import slice_warnings

    plain = load_mesh(vase_file)
    shade = np.round(np.interp(plain.vertices[:, 2], [plain.bounds[0, 2], plain.bounds[1, 2]], [0, 255]))
    scan = np.stack([255 - shade, shade, np.full_like(shade, 40)], axis=1).astype(np.uint8)
    distinct = len(np.unique(scan, axis=0))
    assert distinct > 20
    spec = SliceSpec(layer_height_mm=1.0)
    warned = slice_warnings(type(plain)(**{**plain.__dict__, "colors": scan}), spec)
    assert len(warned) == 1 and f"its {distinct} distinct colours map onto 2 materials (M1, M2)" in warned[0]
    own = np.where((plain.vertices[:, 2] > 30)[:, None], DEFAULT_MATERIALS["M2"].color,
                   DEFAULT_MATERIALS["M1"].color).astype(np.uint8)
    assert slice_warnings(type(plain)(**{**plain.__dict__, "colors": own}), spec) == []
    assert slice_warnings(plain, spec) == []
    import trimesh

    model = tmp_path / "scan.ply"

    trimesh.Trimesh(plain.vertices, plain.faces, vertex_colors=scan, process=False).export(model)
    code, _, err = run_cli("slice", model, "--layer", "2", "--dpi", "50", "-o", tmp_path / "stack")
    assert code == 0, err
    assert err.count("warning:") == 1 and "distinct colours map onto 2 materials" in err


def test_slice_json_names_the_material_of_a_one_material_stack(run_cli, vase_file, tmp_path):
    """A one-material stack's `slice --json` names its material (it gave an empty list): the table's first for a
    mesh without colours, the one a scan's colours all map to otherwise; the text line names it too."""
    from heoslice.material import DEFAULT_MATERIALS

    code, out, err = run_cli("slice", vase_file, "--layer", "2", "--dpi", "50", "-o", tmp_path / "plain", "--json")
    assert code == 0, err
    assert json.loads(out)["materials"] == ["M1"] and json.loads(out)["droplet_masks"] is False
    import trimesh

    plain = load_mesh(vase_file)
    near_m2 = np.clip(np.array(DEFAULT_MATERIALS["M2"].color) + [3, -3, 2], 0, 255).astype(np.uint8)
    model = tmp_path / "greenish.ply"
    trimesh.Trimesh(plain.vertices, plain.faces, vertex_colors=np.tile(near_m2, (len(plain.vertices), 1)),
                    process=False).export(model)
    code, out, err = run_cli("slice", model, "--layer", "2", "--dpi", "50", "-o", tmp_path / "green", "--json")
    assert code == 0, err
    assert json.loads(out)["materials"] == ["M2"] and json.loads(out)["droplet_masks"] is False
    code, out, err = run_cli("slice", vase_file, "--layer", "2", "--dpi", "50", "-o", tmp_path / "text")
    assert code == 0 and "one material (M1): a solid mask per layer" in out


@pytest.mark.parametrize("channel, number, sent", [("channel = 3\n", 3, "4 channel(s) (solid, unused, unused, gel)"),
                                                  ("", 1, "2 channel(s) (solid, gel)")])
def test_one_material_of_a_materials_file_is_recorded(tmp_path, run_cli, channel, number, sent):
    """An uncoloured model printed in a materials file's one material: the stack holds its droplet mask on the
    material's printer channel (the one the file names, else its place in the table), so the manifest, verify and
    print name the material and its channel (it was a bare solid stack, sent as 'solid' only, exported as 'model')."""
    procedural.box((6.0, 6.0, 2.0)).export(tmp_path / "box.ply")
    (tmp_path / "m.toml").write_text(f'[materials.gel]\ncolor = "#30c0f0"\n{channel}')
    code, _, err = run_cli("slice", tmp_path / "box.ply", "--materials", tmp_path / "m.toml", "--layer", "1",
                           "--dpi", "50", "-o", tmp_path / "stack")
    assert code == 0, err
    manifest = json.loads((tmp_path / "stack" / "manifest.json").read_text())
    assert [(m["name"], m["channel"]) for m in manifest["grading"]["materials"]] == [("gel", number)]
    assert [c["material"] for c in manifest["layers"][0]["channels"]] == ["gel"]
    code, out, _ = run_cli("print", tmp_path / "stack", "--dry-run")
    assert code == 0 and sent in out
    code, out, _ = run_cli("verify", tmp_path / "stack")
    assert code == 0 and "gel: " in out
