"""OBJ and ASCII STL through trimesh: text with Latin-1 bytes reads, face index 0 is refused, errors are one line."""

from __future__ import annotations

import pytest
import trimesh

from heoslice.errors import InputError
from heoslice.mesh import load_mesh


@pytest.mark.parametrize("suffix", [".stl", ".obj"])
def test_latin1_bytes_in_ascii_stl_and_obj_read(tmp_path, run_cli, suffix):
    """`solid Leber_\\xfc` (ASCII STL) and a `# Modell f\\xfcr Leber` comment (OBJ), Latin-1 encoded, read as the
    10 mm cube (trimesh needs charset_normalizer to decode them; pyproject declares it)."""
    cube = trimesh.creation.box(extents=(10.0, 10.0, 10.0))
    if suffix == ".stl":
        text = cube.export(file_type="stl_ascii").replace("solid", "solid Leber_\xfc", 1)
    else:
        text = "# Modell f\xfcr Leber\n" + cube.export(file_type="obj")
    path = tmp_path / f"leber{suffix}"
    path.write_bytes(text.encode("latin-1"))
    code, out, err = run_cli("info", path, "--json")
    assert code == 0, err
    assert '"triangles": 12' in out and '"volume_mm3": 1000.0' in out


def test_obj_face_index_zero_names_its_line(tmp_path):
    """OBJ indices start at 1: 'f 0 ...' and a texture index 0 are InputErrors naming the line; 'f 10 ...' is not."""
    lines = ["v 0 0 0", "v 10 0 0", "v 0 10 0", "v 0 0 10"] + [f"v {i} 20 20" for i in range(7)]
    faces = ["f 1 3 2", "f 1 2 4", "f 1 4 3", "f 2 3 4", "f 10 11 9"]
    path = tmp_path / "m.obj"
    path.write_text("\n".join(lines + faces) + "\n")
    load_mesh(path)
    for bad in ("f 0 3 2", "f 1/0 3/1 2/1", "f 1 3 0"):
        path.write_text("\n".join(lines + [bad] + faces[1:]) + "\n")
        with pytest.raises(InputError, match="line 12: OBJ face index 0"):
            load_mesh(path)
