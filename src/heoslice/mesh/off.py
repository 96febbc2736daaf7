"""OFF reading (OFF, COFF, NOFF, CNOFF, STOFF), strict: counts checked against the rows present."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from heoslice.errors import InputError
from heoslice.files import read_bounded
from heoslice.mesh.limits import MAX_MESH_BYTES, MAX_TRIANGLES, MAX_VERTICES, check_count, check_text_body
from heoslice.mesh.raw import RawMesh, checked_triangles
from heoslice.mesh.text import as_type, ascii_rows

_COMMENT = re.compile(rb"#[^\n]*")
#: The keyword and the vertex and face counts after any blank or comment lines (the counts the limits check).
_COUNTS = re.compile(rb"(?:\s|#[^\n]*)*(\S*?OFF)(?:\s|#[^\n]*)+(\d+)(?:\s|#[^\n]*)+(\d+)")


def read_off(path: Path) -> RawMesh:
    """Read an OFF file (OFF, COFF, NOFF, CNOFF, STOFF; '#' comments) strictly into a :class:`RawMesh`.

    Counts are checked against the rows present; one vertex or face per line; extra
    values on a row (colours, normals, texture coordinates) are ignored; faces with
    fewer than 3 vertices, indices outside the vertex list and NaN coordinates are
    one-line InputErrors. Polygons are fan-triangulated. Counts and the body's size are
    checked against :mod:`heoslice.mesh.limits` before the body is tokenised.
    """
    path = Path(path)
    data = read_bounded(path, MAX_MESH_BYTES, "mesh")
    declared = _COUNTS.match(data)
    rows = 0
    if declared:
        vertex_count, face_count = int(declared.group(2)), int(declared.group(3))
        check_count(path, "vertices", vertex_count, MAX_VERTICES)
        check_count(path, "faces", face_count, MAX_TRIANGLES)
        rows = 1 + vertex_count + face_count
    check_text_body(path, len(data), rows, data.count(b"\n"))
    text = _COMMENT.sub(b"", data)  # a comment runs to the end of its line; the line break stays
    del data
    words = text.split(None, 1)
    keyword = words[0].decode("ascii", "replace") if words else ""
    if not keyword.endswith("OFF") or keyword[:-3] not in ("", "C", "N", "CN", "NC", "ST", "STC", "STN", "STCN"):
        raise InputError(f"{path}: not an OFF file (first word {keyword[:20]!r}, expected OFF)")
    start = text.index(words[0]) + len(words[0])
    body = b" " * start + text[start:]
    values, row_start, row_length, row_line = ascii_rows(path, body, 1)
    if len(row_start) == 0 or row_length[0] < 2:
        raise InputError(f"{path}: OFF has no 'vertices faces edges' count line")
    counts = as_type(path, values[row_start[0]:row_start[0] + 2], "i8", row_line[[0, 0]], "count")
    vertex_count, face_count = int(counts[0]), int(counts[1])
    if vertex_count < 0 or face_count < 0 or 1 + vertex_count + face_count > len(row_start):
        raise InputError(f"{path}: OFF declares {vertex_count} vertices and {face_count} faces, "
                         f"but holds {len(row_start) - 1} rows")
    if 1 + vertex_count + face_count < len(row_start):
        raise InputError(f"{path}: OFF line {row_line[1 + vertex_count + face_count]}: data after the last face")
    rows = slice(1, 1 + vertex_count)
    short = row_length[rows] < 3
    if short.any():
        raise InputError(f"{path}: OFF line {row_line[rows][np.argmax(short)]}: a vertex needs 3 coordinates")
    vertices = values[row_start[rows][:, None] + np.arange(3)]
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.all():
        raise InputError(f"{path}: vertex {int(np.argmin(finite))} has a NaN or infinite coordinate")
    rows = slice(1 + vertex_count, 1 + vertex_count + face_count)
    first, length, lines = row_start[rows], row_length[rows], row_line[rows]
    lengths = as_type(path, values[first], "i4", lines, "face size").astype(np.int64)
    over = (lengths < 0) | (1 + lengths > length)
    if over.any():
        raise InputError(f"{path}: OFF line {lines[np.argmax(over)]}: face size {lengths[np.argmax(over)]} "
                         "does not match the values on the line")
    within = np.arange(int(lengths.sum())) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    flat = as_type(path, values[np.repeat(first + 1, lengths) + within], "i8",
                        np.repeat(lines, lengths), "vertex index")
    triangles, _ = checked_triangles(path, vertex_count, lengths, flat)
    return RawMesh(vertices, triangles)

