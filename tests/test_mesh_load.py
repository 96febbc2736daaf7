"""load_mesh and info: file-level errors, warnings, formats through trimesh, renamed non-mesh files said as
what they are, colours said as what they belong to."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from test_mesh_ply import TETRA_FACES, TETRA_VERTICES, one_line_error, ply_bytes, write

from heoslice import procedural
from heoslice.errors import InputError
from heoslice.mesh import load_mesh

PNG = b"\x89PNG\r\n\x1a\n" + bytes(8) + b"IHDR" + bytes(200)


@pytest.mark.parametrize("suffix", [".stl", ".ply", ".obj", ".off"])
def test_a_renamed_png_is_said_to_be_a_png(tmp_path, suffix):
    """A PNG renamed to any mesh suffix is one line saying it is a PNG image, not a parser's complaint."""
    path = tmp_path / f"picture{suffix}"
    path.write_bytes(PNG)
    with pytest.raises(InputError, match="is a PNG image, not a mesh"):
        load_mesh(path)


@pytest.mark.parametrize("given, expected", [("face", "per-face RGB"), ("vertex", "per-vertex RGB"),
                                             (None, "none")])
def test_info_says_what_the_colours_belong_to(tmp_path, run_cli, given, expected):
    """A PLY with face colours is reported as face colours, one with vertex colours as vertex colours."""
    rgb = np.array([[200, 10, 10], [10, 200, 10], [10, 10, 200], [90, 90, 90]])
    extra = [(c, "uchar", rgb[:, i]) for i, c in enumerate(("red", "green", "blue"))]
    data = ply_bytes("ascii", TETRA_VERTICES, TETRA_FACES, vertex_extra=extra if given == "vertex" else (),
                     face_extra=extra if given == "face" else ())
    path = tmp_path / "coloured.ply"
    path.write_bytes(data)
    code, out, err = run_cli("info", path)
    assert code == 0, err
    assert f"colours:            {expected}" in out
    code, out, _ = run_cli("info", path, "--json")
    assert json.loads(out)["color_source"] == given


@pytest.mark.parametrize("suffix, options", [(".stl", {}), (".stl", {"file_type": "stl_ascii"}), (".obj", {}),
                                             (".off", {})])
def test_stl_obj_off(tmp_path, suffix, options):
    """STL (binary and ASCII), OBJ and OFF exported by trimesh load to the same solid (volume, bounds)."""
    mesh = procedural.vase(rings_outer=8, rings_inner=6, sections=16)
    path = tmp_path / f"v{suffix}"
    data = mesh.export(file_type=options.get("file_type", suffix[1:]))
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    loaded = load_mesh(path)
    assert trimesh.Trimesh(loaded.vertices, loaded.faces).volume == pytest.approx(mesh.volume, rel=1e-5)
    np.testing.assert_allclose(loaded.bounds, mesh.bounds, atol=1e-4)
    assert loaded.warnings == ()


@pytest.mark.parametrize("name, data, expected", [
    ("empty", b"", "file is empty"),
    ("unsupported", b"solid", "unsupported file type"),
])
def test_file_level_errors(tmp_path, name, data, expected):
    """Empty files, unknown suffixes, directories and missing files are one-line errors."""
    path = write(tmp_path, "m.ply" if name == "empty" else "m.3ds", data)
    assert expected in one_line_error(path)
    assert "no such file" in one_line_error(tmp_path / "absent.ply")
    assert "is a directory" in one_line_error(tmp_path)


def test_warning_open_mesh(tmp_path):
    """A box with one face removed loads with an 'open mesh' warning counting its 3 boundary edges."""
    box = procedural.box()
    path = write(tmp_path, "open.ply", ply_bytes("ascii", box.vertices, box.faces[1:].tolist()))
    assert any(note.startswith("open mesh: 3 boundary edge(s)") for note in load_mesh(path).warnings)


def test_warning_non_manifold(tmp_path):
    """Two tetrahedra sharing one edge give a non-manifold warning for that edge."""
    second = TETRA_VERTICES * [1, 1, -1]
    vertices = np.vstack([TETRA_VERTICES, second[[3]]])
    faces = TETRA_FACES + [[0, 1, 4], [0, 4, 2], [1, 2, 4], [0, 2, 1]]
    notes = load_mesh(write(tmp_path, "nm.ply", ply_bytes("ascii", vertices, faces))).warnings
    assert any("non-manifold: " in note for note in notes)


def test_warning_inverted_is_fixed(tmp_path):
    """An inside-out cube is flipped (warning) so that its signed volume becomes positive."""
    inverted = procedural.inverted(procedural.box())
    mesh = load_mesh(write(tmp_path, "inv.ply", ply_bytes("ascii", inverted.vertices, inverted.faces.tolist())))
    assert any("inward" in note for note in mesh.warnings)
    assert trimesh.Trimesh(mesh.vertices, mesh.faces).volume == pytest.approx(1000.0)


def test_warning_metres(tmp_path):
    """A 10 cm sphere written in metres (0.1 across) warns about units."""
    sphere = procedural.sphere(radius=0.05, subdivisions=1)
    mesh = load_mesh(write(tmp_path, "m.ply", ply_bytes("binary_little_endian", sphere.vertices,
                                                         sphere.faces.tolist())))
    assert any("metres" in note and "--scale 1000" in note for note in mesh.warnings)


def test_warning_degenerate_faces(tmp_path):
    """Faces with a repeated vertex are dropped (warning); collinear faces are counted as zero-area."""
    faces = TETRA_FACES + [[0, 0, 1]]
    notes = load_mesh(write(tmp_path, "d.ply", ply_bytes("ascii", TETRA_VERTICES, faces))).warnings
    assert any("1 degenerate face(s)" in note for note in notes)
    vertices = np.vstack([TETRA_VERTICES, [[5.0, 0.0, 0.0]]])
    faces = TETRA_FACES + [[0, 4, 1]]
    notes = load_mesh(write(tmp_path, "z.ply", ply_bytes("ascii", vertices, faces))).warnings
    assert any("1 zero-area face(s)" in note for note in notes)


def test_absurd_coordinates_are_refused(tmp_path):
    """A finite but absurd coordinate (1e300 mm) is an InputError, not an overflow deeper in."""
    vertices = TETRA_VERTICES.copy()
    vertices[3, 2] = 1e300
    path = write(tmp_path, "far.ply", ply_bytes("binary_little_endian", vertices, TETRA_FACES, coord="double"))
    assert "beyond" in one_line_error(path)



@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_a_non_finite_material_fraction_is_refused(tmp_path, run_cli, value):
    """A PLY whose vertex property `material` is NaN or infinite is refused when read (one line, exit 2, naming
    the vertex), by `info` and `slice` alike, never sliced into the M1 mask."""
    path = tmp_path / "tet.ply"
    rows = [(0, 0, 0, 0.5), (10, 0, 0, value), (0, 10, 0, 0.5), (0, 0, 10, 0.5)]
    path.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                    "property float material\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n"
                    + "".join(f"{x} {y} {z} {m}\n" for x, y, z, m in rows)
                    + "3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n")
    for command in (("info", path), ("slice", path, "-o", tmp_path / "stack", "--dpi", "50")):
        code, _, err = run_cli(*command)
        assert code == 2 and err.count("\n") == 1 and "vertex 1: 'material' is" in err, err
    assert not (tmp_path / "stack" / "manifest.json").exists()


def test_scaling_settles_every_parts_metres_warning(tmp_path):
    """An assembly of parts in metres warns per part; scaled by 1000 it warns no more (the scale settles each
    part's note, not only a whole model's)."""
    from heoslice.mesh.assembly import load_assembly
    from heoslice.mesh.load import scaled

    paths = []
    for name, radius in (("organ", 0.01), ("lesion", 0.003)):
        sphere = procedural.sphere(radius=radius, subdivisions=1)
        paths.append(write(tmp_path, f"{name}.ply", ply_bytes("binary_little_endian", sphere.vertices,
                                                                sphere.faces.tolist())))
    assembly = load_assembly(paths)
    assert sum("metres" in note for note in assembly.warnings) == 2
    assert not any("metres" in note for note in scaled(assembly, 1000.0).warnings)
