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


# --- bounded: hostile archives and models, through the command line under a time and memory limit ----------

def _model(resources: str, build: str) -> bytes:
    from heoslice.mesh.threemf import CORE

    return (f'<?xml version="1.0" encoding="UTF-8"?><model unit="millimeter" xmlns="{CORE.strip("{}")}">'
            f"<resources>{resources}</resources><build>{build}</build></model>").encode()


def _archive(path, members: dict[str, bytes], method=zipfile.ZIP_DEFLATED):
    with zipfile.ZipFile(path, "w", method) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return path


TETRA = ('<object id="1" type="model"><mesh><vertices><vertex x="0" y="0" z="0"/><vertex x="1" y="0" z="0"/>'
         '<vertex x="0" y="1" z="0"/><vertex x="0" y="0" z="1"/></vertices><triangles><triangle v1="0" v2="2" v3="1"/>'
         '<triangle v1="0" v2="1" v3="3"/><triangle v1="0" v2="3" v3="2"/><triangle v1="1" v2="2" v3="3"/>'
         '</triangles></mesh></object>')


def _patched(path, offset_of, value: bytes):
    """Overwrite bytes of the archive at ``offset_of(data)`` (local header and central directory fields)."""
    data = bytearray(path.read_bytes())
    for offset in offset_of(bytes(data)):
        data[offset:offset + len(value)] = value
    path.write_bytes(bytes(data))
    return path


def _header_offsets(field: int):
    """Offsets of a field in every local file header (PK\\3\\4, field offset) and central entry (PK\\1\\2, +2)."""
    def find(data: bytes):
        out, start = [], 0
        while (start := data.find(b"PK\x03\x04", start)) >= 0:
            out.append(start + field)
            start += 4
        start = 0
        while (start := data.find(b"PK\x01\x02", start)) >= 0:
            out.append(start + field + 2)
            start += 4
        return out
    return find


def nested_components(levels: int, fan: int) -> bytes:
    """Object 1 a tetrahedron; object k+1 holds ``fan`` components of object k: fan^(levels-1) placements."""
    objects = [TETRA] + [f'<object id="{k + 1}" type="model"><components>'
                         + f'<component objectid="{k}"/>' * fan + "</components></object>" for k in range(1, levels)]
    return _model("".join(objects), f'<item objectid="{levels}"/>')


def vertex_flood(count: int) -> bytes:
    """One object of ``count`` vertices (all referenced by a fan of triangles): tens of MB of XML, a small zip."""
    vertices = "".join(f'<vertex x="{k}" y="{k % 7}" z="{k % 11}"/>' for k in range(count))
    triangles = "".join(f'<triangle v1="0" v2="{k}" v3="{k + 1}"/>' for k in range(1, min(count - 1, 1000)))
    return _model(f'<object id="1" type="model"><mesh><vertices>{vertices}</vertices><triangles>{triangles}'
                  "</triangles></mesh></object>", '<item objectid="1"/>')


@pytest.fixture
def hostile(tmp_path):
    """name -> (3MF path, expected fragment of the one-line refusal)."""
    rels_bomb = _archive(tmp_path / "rels_bomb.3mf", {"_rels/.rels": b" " * (64 << 20),
                                                      "3D/3dmodel.model": _model(TETRA, '<item objectid="1"/>')})
    encrypted = _patched(_archive(tmp_path / "encrypted.3mf", {"3D/3dmodel.model": _model(TETRA, '<item objectid="1"/>')}),
                         _header_offsets(6), b"\x01\x00")
    bad_crc = _patched(_archive(tmp_path / "bad_crc.3mf", {"3D/3dmodel.model": _model(TETRA, '<item objectid="1"/>')}),
                       _header_offsets(14), b"\x00\x00\x00\x00")
    return {
        "nested": (_archive(tmp_path / "nested.3mf", {"3D/3dmodel.model": nested_components(16, 4)}), "places"),
        "cycle": (_archive(tmp_path / "cycle.3mf", {"3D/3dmodel.model": _model(
            '<object id="1"><components><component objectid="2"/></components></object>'
            '<object id="2"><components><component objectid="1"/></components></object>', '<item objectid="1"/>')}),
            "nest deeper"),
        "rels_bomb": (rels_bomb, "'_rels/.rels' declares"),
        "encrypted": (encrypted, "encrypted"),
        "bzip2": (_archive(tmp_path / "bzip2.3mf", {"3D/3dmodel.model": _model(TETRA, '<item objectid="1"/>')},
                           zipfile.ZIP_BZIP2), "compression method 12"),
        "bad_crc": (bad_crc, "bad CRC-32"),
        "huge_index": (_archive(tmp_path / "index.3mf", {"3D/3dmodel.model": _model(
            TETRA.replace('v3="1"', 'v3="1000000000000000000000000000000"'), '<item objectid="1"/>')}),
            "non-numeric"),
        "float_index": (_archive(tmp_path / "index2.3mf", {"3D/3dmodel.model": _model(
            TETRA.replace('v3="1"', 'v3="1e30"'), '<item objectid="1"/>')}), "non-numeric"),
    }


@pytest.mark.parametrize("case", ["nested", "cycle", "rels_bomb", "encrypted", "bzip2", "bad_crc", "huge_index",
                                  "float_index"])
def test_hostile_3mf_is_one_line_exit_2_in_bounded_time_and_memory(hostile, case):
    """Nested components (4^15 placements in a small file), a component cycle, a zip bomb in _rels/.rels, an
    encrypted member, an unknown compression method, a bad CRC and absurd vertex indices: `info` exits 2 with one
    line naming the problem, within seconds and a few hundred MB."""
    from test_mesh_limits import assert_one_line_refusal, run_bounded

    path, fragment = hostile[case]
    assert_one_line_refusal(run_bounded("info", path), fragment, rss_mib=300.0)


def test_a_flood_of_vertex_elements_streams_within_the_mesh_budget(tmp_path):
    """1,000,000 vertex elements (40 MB of XML, a small zip) are read as a stream into flat arrays: `info`
    succeeds within a memory bound ElementTree's whole tree (hundreds of bytes an element) would exceed."""
    from test_mesh_limits import run_bounded

    path = _archive(tmp_path / "flood.3mf", {"3D/3dmodel.model": vertex_flood(1_000_000)})
    code, out, err, seconds, rss = run_bounded("info", path)
    assert code == 0, err
    assert rss < 300.0 and seconds < 60.0, (rss, seconds)


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
