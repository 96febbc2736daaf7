"""errors.py: values in user-visible messages are shown as plain numbers, never as numpy reprs.

The command-line cases write each bad input here and check the one ``heoslice: error:`` line
(exit 2) holds no ``np.`` (numpy 2 writes ``np.float64(4000000000.0)`` for a scalar's repr).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_mesh_ply import TETRA_FACES, TETRA_VERTICES, ply_bytes

from heoslice.errors import EXIT_INPUT, shown


@pytest.mark.parametrize("value, text", [
    (np.float64(4e9), "4000000000.0"), (np.int64(-3), "-3"), (np.float32(2.5), "2.5"),
    (np.array([1.0, 2.0, 3.0]), "[1.0, 2.0, 3.0]"), ((1.5, "x"), "(1.5, 'x')"), ("a", "'a'"),
    (np.arange(1000.0), "[0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7..."),
])
def test_shown_writes_numpy_values_as_python_ones(value, text):
    """shown() is the repr of the plain Python value (numpy scalars and arrays converted), cut to 40 chars."""
    assert shown(value) == text


def _coloured_tetra(red: str = "255", index: str = "1", length: str = "3") -> bytes:
    """An ASCII PLY tetrahedron with uchar colours; ``red`` of vertex 0, one index and one list length as given."""
    text = ply_bytes("ascii", TETRA_VERTICES, TETRA_FACES,
                     vertex_extra=[(c, "uchar", np.full(4, 255)) for c in ("red", "green", "blue")]).decode()
    head, body = text.split("end_header\n")
    rows = body.splitlines()
    rows[0] = rows[0].rsplit(" ", 3)[0] + f" {red} 255 255"
    rows[4] = f"{length} 0 2 {index}"
    return (head + "end_header\n" + "\n".join(rows) + "\n").encode()


MATERIALS = '[materials.gel]\ncolor = {}\nchannel = 1\n'


@pytest.mark.parametrize("case, needle", [
    ("ply red 4e9", "'red' 4000000000 is not a uint8"),
    ("ply red -1", "'red' -1 is not a uint8"),
    ("ply red inf", "'red' inf is not a uint8"),
    ("ply index 4e9", "4000000000 is not a int32"),
    ("ply list length 2.5", "2.5 is not a uint8"),
    ("materials [4e9, 0, 0]", "materials.gel"),
    ("materials [1e400, 0, 0]", "materials.gel"),
    ("materials hex", "materials.gel"),
    ("--to 4e9,0,0", "--to"),
    ("--to hex", "--to"),
    ("--from 1e400,0,0", "--from"),
    ("--at 1e308", "--at"),
])
def test_no_message_shows_a_numpy_repr(tmp_path, run_cli, case, needle):
    """Out-of-range colours and numbers in mesh files, materials files and options are one line (exit 2)
    naming the value as a plain number, without 'np.'."""
    model = tmp_path / "tetra.ply"
    model.write_bytes(_coloured_tetra())
    materials = tmp_path / "materials.toml"
    args = ["info", model]
    if case.startswith("ply"):
        value = case.split()[-1]
        model.write_bytes(_coloured_tetra(**{"ply red": {"red": value}, "ply index": {"index": value},
                                             "ply list length": {"length": value}}[case.rsplit(" ", 1)[0]]))
    elif case.startswith("materials"):
        color = case.split(" ", 1)[1]
        materials.write_text(MATERIALS.format('"#ff00ff00ff"' if color == "hex" else color))
        args = ["slice", model, "-o", tmp_path / "s", "--grade", "linear", "--to", "gel", "--materials", materials]
    elif case.startswith("--at"):
        args = ["color", model, "-o", tmp_path / "c.ply", "--ref", "point", "--at", "1e308,1e308,1e308"]
    else:
        flag, value = case.split()
        args = ["slice", model, "-o", tmp_path / "s", "--grade", "linear", flag,
                "#1234567" if value == "hex" else value]
    code, out, err = run_cli(*args)
    lines = err.strip().splitlines()
    assert code == EXIT_INPUT and len(lines) == 1 and lines[0].startswith("heoslice: error:"), err
    assert needle in lines[0] and "np." not in lines[0], lines[0]
