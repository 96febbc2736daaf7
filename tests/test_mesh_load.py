"""load_mesh and info: renamed non-mesh files said as what they are, colours said as what they belong to."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_loading import TETRA_FACES, TETRA_VERTICES, ply_bytes

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
