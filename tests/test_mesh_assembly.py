"""Assemblies: a 3MF's objects and several files as the parts of one job; the same masks either way; info,
verify --mesh and color on a 3MF; one-line errors for a multi-part job's bad inputs, nothing left looking complete."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from helpers import mesh_xml, write_3mf

from heoslice.mesh import load_assembly, load_mesh

MATERIALS_TOML = """
[materials.tissue]
color = "#c04030"
channel = 1
[materials.tumour]
color = "#30c040"
channel = 2
"""
COLOURS = {"organ": (0xC8, 0x40, 0x30), "lesion": (0x20, 0xC0, 0x50)}  # near tissue, near tumour


def exact(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The mesh with coordinates on a 1/256 mm grid (exact in float32 and in decimal text)."""
    mesh.vertices = np.round(mesh.vertices * 256.0) / 256.0
    return mesh


def two_objects() -> dict[str, trimesh.Trimesh]:
    organ = exact(trimesh.creation.icosphere(2, 8.0))
    lesion = exact(trimesh.creation.box(extents=(4.0, 4.0, 4.0)))
    lesion.apply_translation([2.0, 0.0, 1.0])
    return {"organ": organ, "lesion": lesion}


def write_organ_3mf(path, objects: dict[str, trimesh.Trimesh]) -> None:
    """The organ coloured by a base material (named 'liver', not a table material), the lesion by a colour group."""
    r, g, b = COLOURS["organ"]
    resources = (f'<basematerials id="1"><base name="liver" displaycolor="#{r:02X}{g:02X}{b:02X}"/></basematerials>'
                 '<m:colorgroup id="2"><m:color color="#{:02X}{:02X}{:02X}"/></m:colorgroup>'.format(*COLOURS["lesion"])
                 + mesh_xml(objects["organ"], 3, "organ", ' pid="1" pindex="0"')
                 + mesh_xml(objects["lesion"], 4, "lesion", triangle=lambda i: ' pid="2" p1="0"'))
    write_3mf(path, resources, '<item objectid="3"/><item objectid="4"/>')


def write_coloured_plys(tmp_path, objects: dict[str, trimesh.Trimesh]) -> list:
    paths = []
    for name, mesh in objects.items():
        coloured = mesh.copy()
        coloured.visual.vertex_colors = np.tile([*COLOURS[name], 255], (len(mesh.vertices), 1))
        coloured.export(tmp_path / f"{name}.ply")
        paths.append(tmp_path / f"{name}.ply")
    return paths


def layer_digests(manifest: dict) -> list:
    return [(entry["sha256"], [(c["material"], c["sha256"]) for c in entry["channels"]])
            for entry in manifest["layers"]]


def test_3mf_gives_the_same_masks_as_two_coloured_plys(tmp_path, run_cli):
    """A 3MF with two coloured objects and the same objects as two vertex-coloured PLYs slice to byte-identical
    solid and droplet masks: parts named alike, mapped to the table by their colours (nearest display colour)."""
    objects = two_objects()
    write_organ_3mf(tmp_path / "organ.3mf", objects)
    (tmp_path / "mats.toml").write_text(MATERIALS_TOML)
    common = ("--materials", tmp_path / "mats.toml", "--layer", "0.5", "--dpi", "200")
    code, out, err = run_cli("slice", tmp_path / "organ.3mf", "-o", tmp_path / "from_3mf", *common)
    assert code == 0, err
    code, out, err = run_cli("slice", *write_coloured_plys(tmp_path, objects), "--parts", "-o",
                             tmp_path / "from_ply", *common)
    assert code == 0, err
    first, second = (json.loads((tmp_path / name / "manifest.json").read_text()) for name in ("from_3mf", "from_ply"))
    assert [(p["name"], p["material"]) for p in first["parts"]] == [("organ", "tissue"), ("lesion", "tumour")]
    assert first["parts"][1]["rank"] == 0  # the smaller lesion wins where it is inside the organ
    assert layer_digests(first) == layer_digests(second)
    assert sum(c["solid_pixels"] for e in first["layers"] for c in e["channels"] if c["material"] == "tumour") > 0


def test_3mf_object_maps_by_name_then_base_material(tmp_path):
    """A 3MF object's base material named as a table material is that material, unless [parts] names another."""
    from heoslice.material import PartSetting, read_materials_file
    from heoslice.pipeline import plan_parts

    objects = two_objects()
    write_organ_3mf(tmp_path / "organ.3mf", objects)
    (tmp_path / "mats.toml").write_text(MATERIALS_TOML + '[materials.liver]\ncolor = "blue"\nchannel = 3\n')
    mesh = load_mesh(tmp_path / "organ.3mf")
    assert [part.material_name for part in mesh.parts] == ["liver", "colorgroup 2 #0"]
    table = read_materials_file(tmp_path / "mats.toml").materials
    assert [m.name for m in plan_parts(mesh.parts, table, {}).materials] == ["tumour", "liver"]
    named = plan_parts(mesh.parts, table, {"organ": PartSetting("tissue")})
    assert [named.materials[i].name for i in named.part_material] == ["tissue", "tumour"]


def test_info_verify_and_color_take_a_3mf(tmp_path, run_cli):
    """info reports the 3MF's objects as one mesh, verify --mesh accepts the 3MF its stack was sliced from, and
    color writes a coloured PLY of it."""
    objects = two_objects()
    write_organ_3mf(tmp_path / "organ.3mf", objects)
    code, out, err = run_cli("info", tmp_path / "organ.3mf", "--json")
    assert code == 0, err
    assert json.loads(out)["triangles"] == sum(len(m.faces) for m in objects.values())
    code, out, err = run_cli("slice", tmp_path / "organ.3mf", "-o", tmp_path / "stack", "--layer", "0.5",
                             "--dpi", "200")
    assert code == 0, err
    code, out, err = run_cli("verify", tmp_path / "stack", "--mesh", tmp_path / "organ.3mf")
    assert code == 0, out + err
    code, out, err = run_cli("color", tmp_path / "organ.3mf", "--func", "linear", "-o", tmp_path / "organ.ply")
    assert code == 0, err
    assert len(load_mesh(tmp_path / "organ.ply").faces) >= sum(len(m.faces) for m in objects.values())


def test_a_plain_one_object_3mf_slices_like_its_mesh(tmp_path, run_cli):
    """An uncoloured one-object 3MF is a one-part job of the table's first material: its stack is the 1-bit
    solid mask only, with the same layers as the same object given as an STL."""
    box = exact(trimesh.creation.box(extents=(6.0, 5.0, 4.0)))
    write_3mf(tmp_path / "box.3mf", mesh_xml(box, 1, "box"), '<item objectid="1"/>')
    box.export(tmp_path / "box.stl")
    for name in ("box.3mf", "box.stl"):
        code, out, err = run_cli("slice", tmp_path / name, "-o", tmp_path / f"{name}_stack", "--layer", "0.5",
                                 "--dpi", "100")
        assert code == 0, err
    first, second = (json.loads((tmp_path / f"{name}_stack" / "manifest.json").read_text())
                     for name in ("box.3mf", "box.stl"))
    assert first["parts"][0]["material"] == "M1" and "grading" not in first
    assert [e["sha256"] for e in first["layers"]] == [e["sha256"] for e in second["layers"]]


def test_assembly_labels_faces_with_their_part(tmp_path):
    """Several files: faces keep their part label in file order (a 3MF's objects each a part), each part's
    volume its own mesh's."""
    objects = two_objects()
    paths = write_coloured_plys(tmp_path, objects)
    mesh = load_assembly(paths)
    np.testing.assert_array_equal(np.bincount(mesh.part), [len(m.faces) for m in objects.values()])
    assert [p.volume_mm3 for p in mesh.parts] == pytest.approx([m.volume for m in objects.values()])
    assert mesh.source.name == "organ.ply+lesion.ply"
    write_organ_3mf(tmp_path / "organ.3mf", objects)
    mixed = load_assembly([paths[1], tmp_path / "organ.3mf"])
    assert [p.name for p in mixed.parts] == ["lesion", "organ", "lesion"]
    np.testing.assert_array_equal(np.bincount(mixed.part), [len(objects[name].faces) for name in
                                                              ("lesion", "organ", "lesion")])


BAD_INPUTS = [
    ("unknown part in the TOML", '[parts]\nspleen = "tissue"\n', (), "[parts] spleen: no part"),
    ("unknown material in the TOML", '[parts]\norgan = "bone"\n', (), "unknown material 'bone'"),
    ("unknown part on the command line", "", ("--part", "spleen=tissue"), "--part spleen=...: no part"),
    ("unknown material on the command line", "", ("--part", "organ=bone"), "unknown material 'bone'"),
    ("malformed --part", "", ("--part", "organ"), "expected NAME=MATERIAL"),
    ("more materials than channels", '[materials.blood]\ncolor = "blue"\nchannel = 2\n[parts]\norgan = "tissue"\n'
     'lesion = "tumour"\nvessel = "blood"\n', (), "both print on channel 2"),
    ("a part with no material", '[parts]\norgan = "tissue"\n', ("--parts",), "part 'lesion' has no material"),
    ("grading refused", '[parts]\norgan = "tissue"\n', ("--grade", "linear"), "not graded"),
    ("a preview refused", '[parts]\norgan = "tissue"\n', ("--rgba",), "--rgba: a multi-part job is a print job"),
    ("an interior refused", '[parts]\norgan = "tissue"\n', ("--interior", "contour"), "--interior: each part"),
    ("a part file that fails to load", '[parts]\norgan = "tissue"\n', ("broken",), "broken.stl"),
]


def test_a_defaults_files_mesh_settings_leave_a_multi_part_job_alone(tmp_path, run_cli):
    """A defaults file's [slice] interior and channels = false (for the lab's coloured meshes) do not stop a
    multi-part job: they are refused only when typed for it."""
    for name, mesh in {"organ": trimesh.creation.icosphere(1, 8.0), "lesion": trimesh.creation.box()}.items():
        mesh.export(tmp_path / f"{name}.stl")
    (tmp_path / "heoslice.toml").write_text('[slice]\ninterior = "contour"\nchannels = false\n')
    (tmp_path / "mats.toml").write_text(MATERIALS_TOML + '[parts]\norgan = "tissue"\nlesion = "tumour"\n')
    code, _, err = run_cli("--config", tmp_path / "heoslice.toml", "slice", tmp_path / "organ.stl",
                           tmp_path / "lesion.stl", "--materials", tmp_path / "mats.toml", "-o", tmp_path / "stack",
                           "--layer", "1", "--dpi", "50")
    assert code == 0, err


@pytest.mark.parametrize("case, toml, extra, expected", BAD_INPUTS, ids=[case[0] for case in BAD_INPUTS])
def test_bad_multi_part_inputs_are_one_line_errors(tmp_path, run_cli, case, toml, extra, expected):
    """Each bad input of a multi-part job exits 2 with one line naming what is wrong, and leaves no stack."""
    for name, mesh in {"organ": trimesh.creation.icosphere(1, 8.0), "lesion": trimesh.creation.box(),
                       "vessel": trimesh.creation.cylinder(1.0, 20.0)}.items():
        mesh.export(tmp_path / f"{name}.stl")
    (tmp_path / "broken.stl").write_bytes(b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0\n")
    (tmp_path / "mats.toml").write_text(MATERIALS_TOML + toml)
    files = [tmp_path / f"{name}.stl" for name in ("organ", "lesion", "vessel")]
    if "broken" in extra:
        files, extra = [files[0], tmp_path / "broken.stl"], ("--parts",)
    code, out, err = run_cli("slice", *files, "--materials", tmp_path / "mats.toml", "-o", tmp_path / "stack",
                             "--layer", "1", "--dpi", "50", *extra)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and expected in lines[0], err
    assert not (tmp_path / "stack" / "manifest.json").exists()
