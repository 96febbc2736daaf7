"""OBJ and ASCII STL reading through trimesh, its failures turned into one-line errors."""

from __future__ import annotations

import logging
import re
import warnings
from pathlib import Path

import numpy as np

from heoslice.errors import InputError
from heoslice.files import read_bounded
from heoslice.mesh.limits import MAX_TRIMESH_BYTES
from heoslice.mesh.raw import RawMesh

#: A face line with an index 0 (as a vertex, texture or normal index), which OBJ does not have: it counts from 1.
_ZERO_INDEX = re.compile(rb"(?m)^[ \t]*f[ \t](?:[^\n#]*?[ \t/])?0(?=[\s/]|$)")


def check_obj_indices(path: Path, data: bytes) -> None:
    """InputError for an OBJ face index 0 (OBJ indices start at 1, negative ones count back from the end)."""
    zero = _ZERO_INDEX.search(data)
    if zero:
        line = data.count(b"\n", 0, zero.start()) + 1
        raise InputError(f"{path}: line {line}: OBJ face index 0 (OBJ vertex indices start at 1)")


def read_with_trimesh(path: Path) -> RawMesh:
    """Let trimesh parse the file (OBJ, ASCII STL) into a :class:`RawMesh`; any failure is one InputError line.

    Colours trimesh found (per vertex, or per face and spread to the vertices by trimesh)
    become ``vertex_colors``, with ``color_source`` saying which the file gave. The file is
    at most MAX_TRIMESH_BYTES (trimesh's parsers hold Python objects per line).
    """
    data = read_bounded(path, MAX_TRIMESH_BYTES, "mesh")
    if path.suffix.lower() == ".obj":
        check_obj_indices(path, data)
    del data
    import trimesh

    logging.getLogger("trimesh").setLevel(logging.CRITICAL)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception as err:  # trimesh raises many types for malformed files
        detail = " ".join(str(err).split())[:160] or type(err).__name__
        raise InputError(f"{path}: cannot be read as a mesh ({detail})") from err
    if not isinstance(loaded, trimesh.Trimesh):
        raise InputError(f"{path}: contains no triangle mesh")
    kind = getattr(getattr(loaded, "visual", None), "kind", None)
    colors = np.asarray(loaded.visual.vertex_colors)[:, :3].astype(np.uint8) if kind in ("vertex", "face") else None
    return RawMesh(np.asarray(loaded.vertices), np.asarray(loaded.faces, dtype=np.int64).reshape(-1, 3),
                   vertex_colors=colors, color_source=kind if colors is not None else None)
