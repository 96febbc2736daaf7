"""OFF reading: variants read the same solid, each malformed input a one-line error."""

from __future__ import annotations

import pytest
import trimesh
from test_mesh_ply import (
    CUBE_QUADS,
    CUBE_VERTICES,
    TETRA_FACES,
    TETRA_VERTICES,
    one_line_error,
)

from heoslice.mesh import load_mesh


def off_text(vertices, faces, header: str = "OFF\n", colours: bool = False) -> str:
    """An OFF file: header keyword, counts, one vertex and one face per line (optional RGB after each)."""
    extra = " 255 0 0" if colours else ""
    lines = [f"{len(vertices)} {len(faces)} 0"]
    lines += [" ".join(repr(float(c)) for c in v) + extra for v in vertices]
    lines += [" ".join(str(i) for i in [len(f), *f]) + extra for f in faces]
    return header + "\n".join(lines) + "\n"


def test_off_variants_read_the_same_solid(tmp_path):
    """OFF with comments, counts on the keyword line, COFF colours and quads all give the 1000 mm^3 cube."""
    plain = off_text(CUBE_VERTICES, CUBE_QUADS)
    variants = {
        "plain.off": plain,
        "comments.off": "# made by hand\n" + plain.replace("\n", "  # note\n", 3),
        "inline.off": plain.replace("\n", " ", 1),
        "coff.off": off_text(CUBE_VERTICES, CUBE_QUADS, header="COFF\n", colours=True),
    }
    for name, text in variants.items():
        path = tmp_path / name
        path.write_text(text)
        mesh = load_mesh(path)
        assert len(mesh.faces) == 12 and mesh.warnings == (), name
        assert trimesh.Trimesh(mesh.vertices, mesh.faces).volume == pytest.approx(1000.0), name


TETRA_OFF = off_text(TETRA_VERTICES, TETRA_FACES)


@pytest.mark.parametrize("name, text, expected", [
    ("missing face", TETRA_OFF.replace("3 1 2 3\n", ""), "declares 4 vertices and 4 faces"),
    ("huge counts", TETRA_OFF.replace("4 4 0", "1000000000000 1000000000000 0"), "declares 1000000000000"),
    ("extra rows", TETRA_OFF + "1 2 3\n", "data after the last face"),
    ("two-vertex face", TETRA_OFF.replace("3 1 2 3", "2 1 2"), "face 3 has 2 vertices"),
    ("index out of range", TETRA_OFF.replace("3 1 2 3", "3 1 2 7"), "face 3 refers to vertex 7"),
    ("negative index", TETRA_OFF.replace("3 1 2 3", "3 1 2 -1"), "face 3 refers to vertex -1"),
    ("face longer than its line", TETRA_OFF.replace("3 1 2 3", "5 1 2 3"), "does not match"),
    ("NaN", TETRA_OFF.replace("10.0 0.0 0.0", "10.0 nan 0.0"), "vertex 1 has a NaN"),
    ("short vertex", TETRA_OFF.replace("10.0 0.0 0.0", "10.0 0.0"), "needs 3 coordinates"),
    ("garbage", TETRA_OFF.replace("10.0 0.0 0.0", "10.0 zz 0.0"), "'zz' is not a number"),
    ("not off", TETRA_OFF.replace("OFF", "PLY"), "not an OFF file"),
])
def test_malformed_off_is_one_line_input_error(tmp_path, name, text, expected):
    """Each kind of malformed OFF gives one InputError line naming the file and the problem."""
    path = tmp_path / "bad.off"
    path.write_text(text)
    assert expected in one_line_error(path)

