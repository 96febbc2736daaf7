"""3MF reading: objects with names, base materials and colour groups, geometry placed as the build says."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest
import trimesh
from helpers import mesh_xml, write_3mf

from heoslice.errors import InputError
from heoslice.mesh.threemf import read_3mf

LIVER = trimesh.creation.icosphere(2, 20.0)
LESION = trimesh.creation.box(extents=(5.0, 5.0, 5.0))
MATERIALS = ('<basematerials id="1"><base name="liver tissue" displaycolor="#C04030"/>'
             '<base name="lesion" displaycolor="#30C040FF"/></basematerials>'
             '<m:colorgroup id="2"><m:color color="#0000FF"/><m:color color="#FFFF00"/></m:colorgroup>')


def test_objects_materials_and_colour_groups(tmp_path):
    """Two named objects: one with a base material for the whole object, one whose triangles alternate between
    the two colours of a colour group; names, materials, per-face colours and geometry (translated by the build
    transform) read back."""
    path = tmp_path / "organ.3mf"
    resources = (MATERIALS + mesh_xml(LIVER, 3, "Liver", ' pid="1" pindex="0"')
                 + mesh_xml(LESION, 4, "Lesion", triangle=lambda i: f' pid="2" p1="{i % 2}"'))
    write_3mf(path, resources, '<item objectid="3"/><item objectid="4" transform="1 0 0 0 1 0 0 0 1 7 0 -2"/>')
    model = read_3mf(path)
    assert [m.name for m in model.materials] == ["liver tissue", "lesion", "colorgroup 2 #0", "colorgroup 2 #1"]
    assert model.materials[0].color == (0xC0, 0x40, 0x30, 255)
    liver, lesion = model.objects
    assert (liver.name, lesion.name) == ("Liver", "Lesion")
    np.testing.assert_array_equal(liver.face_material, 0)
    np.testing.assert_array_equal(liver.mesh.face_colors, np.tile([0xC0, 0x40, 0x30], (len(LIVER.faces), 1)))
    np.testing.assert_array_equal(lesion.face_material, 2 + np.arange(len(LESION.faces)) % 2)
    assert liver.mesh.color_source == "face"
    np.testing.assert_allclose(liver.mesh.vertices, LIVER.vertices)
    np.testing.assert_allclose(lesion.mesh.vertices, LESION.vertices + [7.0, 0.0, -2.0])
    np.testing.assert_array_equal(lesion.mesh.faces, LESION.faces)


def test_geometry_matches_trimesh_placement(tmp_path):
    """Units, a rotating build transform and components of components are placed as an independent computation
    (trimesh's transform of the same mesh) says: volume and vertices in mm."""
    path = tmp_path / "placed.3mf"
    rotation = trimesh.transformations.rotation_matrix(0.3, [0, 0, 1])
    rotation[:3, 3] = [1.0, 2.0, 3.0]
    flat = " ".join(f"{v!r}" for v in rotation[:3, :3].T.ravel().tolist() + rotation[:3, 3].tolist())
    resources = (mesh_xml(LESION, 1, "cube") + '<object id="2" name="holder"><components>'
                 '<component objectid="1" transform="1 0 0 0 1 0 0 0 1 0 0 10"/></components></object>')
    write_3mf(path, resources, f'<item objectid="2" transform="{flat}"/>', unit="centimeter", rels=False)
    (placed,) = read_3mf(path).objects
    expected = LESION.copy().apply_translation([0, 0, 10]).apply_transform(rotation).apply_scale(10.0)
    np.testing.assert_allclose(placed.mesh.vertices, expected.vertices, atol=1e-9)
    assert trimesh.Trimesh(placed.mesh.vertices, placed.mesh.faces).volume == pytest.approx(125.0 * 1000)
    assert placed.mesh.face_colors is None and (placed.face_material == -1).all()


@pytest.mark.parametrize("change, expected", [
    (lambda x: b"not a zip", "not a zip archive"),
    (lambda x: x.replace(b'v3="2"', b'v3="999"', 1), "outside"),
    (lambda x: x.replace(b'pindex="0"', b'pindex="7"'), "property 1:7"),
    (lambda x: x.replace(b'<item objectid="3"/>', b'<item objectid="9"/>'), "object '9'"),
    (lambda x: x.replace(b'unit="millimeter"', b'unit="furlong"'), "unit"),
    (lambda x: x.replace(b"</model>", b""), "not well-formed"),
    (lambda x: x.replace(b'<vertex x="', b'<vertex x="zz', 1), "non-numeric"),
    (lambda x: x.replace(b"#C04030", b"red"), "colour"),
    (lambda x: x.replace(b"<?xml", b'<!DOCTYPE m [<!ENTITY a "b">]><?xml'), "DTD"),
])
def test_malformed_3mf_is_one_line_input_error(tmp_path, change, expected):
    """Each flaw of the archive, the XML or the references is one InputError line naming the file."""
    good = tmp_path / "good.3mf"
    write_3mf(good, MATERIALS + mesh_xml(LIVER, 3, "Liver", ' pid="1" pindex="0"'), '<item objectid="3"/>')
    with zipfile.ZipFile(good) as archive:
        model = archive.read("3D/3dmodel.model")
    bad = tmp_path / "bad.3mf"
    changed = change(model)
    if changed == b"not a zip":
        bad.write_bytes(changed)
    else:
        with zipfile.ZipFile(bad, "w") as archive:
            archive.writestr("3D/3dmodel.model", changed)
    with pytest.raises(InputError, match=expected) as caught:
        read_3mf(bad)
    assert "\n" not in str(caught.value) and str(bad) in str(caught.value)


def test_readme_format_table_says_what_takes_3mf_and_slice_does(tmp_path):
    """The README's format table says `slice` takes 3MF (it said it did not), and it does: a two-object 3MF
    slices into one complete stack."""
    from pathlib import Path

    from helpers import in_process

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")
    row = next(line for line in readme.splitlines() if line.startswith("| 3MF |"))
    assert "`slice`" in row and "not take" not in row and "library only" not in row
    path = tmp_path / "organ.3mf"
    write_3mf(path, MATERIALS + mesh_xml(LIVER, 3, "Liver", ' pid="1" pindex="0"')
              + mesh_xml(LESION, 4, "Lesion", ' pid="1" pindex="1"'), '<item objectid="3"/><item objectid="4"/>')
    assert in_process("slice", path, "--layer", "2", "--dpi", "50", "-o", tmp_path / "stack") == 0
    assert (tmp_path / "stack" / "manifest.json").is_file()
