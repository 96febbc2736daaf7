"""Binary STL reading: fixed-size records read in one numpy view (ASCII STL goes to trimesh)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from heoslice.errors import InputError
from heoslice.files import open_regular
from heoslice.mesh.limits import MAX_TRIANGLES, check_count
from heoslice.mesh.raw import RawMesh


def read_binary_stl(path: Path) -> RawMesh | None:
    """A binary STL as a triangle soup (vertices (3m, 3) float32, faces (m, 3)), or None if it is ASCII.

    Binary STL is fixed-size records (12 float32 + 2 bytes), so numpy reads it in one
    view, without trimesh's per-record work. An 80-byte header may start with 'solid' (a known trap
    for ASCII detection): the size check decides. ASCII STL goes to trimesh. The
    triangle count is checked against the limit before anything is allocated.
    """
    with open_regular(path, "mesh") as handle:
        size = os.fstat(handle.fileno()).st_size
        head = handle.read(84)
    if len(head) < 84:
        return None  # shorter than any binary STL: ASCII, or trimesh says what is wrong
    count = int(np.frombuffer(head, dtype="<u4", count=1, offset=80)[0])
    if size != 84 + 50 * count:
        if head.lstrip().startswith(b"solid"):
            return None
        raise InputError(f"{path}: truncated or corrupt binary STL: it declares {count} triangles "
                         f"({84 + 50 * count} bytes) but holds {size} bytes (and it does not start with 'solid')")
    check_count(path, "triangles", count, MAX_TRIANGLES)
    record = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    data = np.fromfile(path, dtype=record, count=count, offset=84)
    vertices = np.ascontiguousarray(data["corners"]).reshape(-1, 3)  # float32: welded before widening
    del data
    faces = np.arange(3 * count, dtype=np.int64).reshape(-1, 3)
    return RawMesh(vertices, faces)

