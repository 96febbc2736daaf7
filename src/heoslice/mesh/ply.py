"""PLY reading (ascii, binary little and big endian), strict: the header is checked before the body is read.

Element counts the file cannot hold are refused from the header alone; binary rows of
varying polygon size are located without a loop per row; ASCII bodies are tokenised
by :mod:`heoslice.mesh.text`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from heoslice.errors import InputError
from heoslice.files import open_regular, read_bounded
from heoslice.mesh.limits import MAX_MESH_BYTES, MAX_TRIANGLES, MAX_VERTICES, check_count, check_text_body
from heoslice.mesh.raw import RawMesh, checked_triangles, strip_triangles
from heoslice.mesh.text import as_type, ascii_rows

#: PLY scalar type names (with their aliases) -> numpy type code.
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


_PLY_MAX_HEADER_BYTES = 1 << 16


_PLY_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}


_PLY_FACE_LISTS = ("vertex_indices", "vertex_index")


@dataclass(frozen=True)
class PlyProperty:
    """One property of a PLY element: numpy type code of its values, and of its list length (None: scalar)."""

    name: str
    kind: str
    count_kind: str | None = None


@dataclass(frozen=True)
class PlyHeader:
    """A parsed PLY header: format ('ascii' or a binary byte order), elements in file order, body offset, and
    its ``comment`` and ``obj_info`` lines' text in file order (where ``heoslice color`` records the design)."""

    format: str
    elements: tuple[tuple[str, int, tuple[PlyProperty, ...]], ...]
    body_offset: int
    comments: tuple[str, ...] = ()


def parse_ply_header(path: Path, head: bytes) -> PlyHeader:
    """Parse and check the header at the start of ``head`` (the file's first bytes); InputError on any flaw."""
    if not (head.startswith(b"ply\n") or head.startswith(b"ply\r\n")):
        raise InputError(f"{path}: not a PLY file (no 'ply' magic line)")
    marker = head.find(b"end_header")
    if marker < 0:
        raise InputError(f"{path}: PLY header has no 'end_header' in its first {_PLY_MAX_HEADER_BYTES // 1024} KiB")
    newline = head.find(b"\n", marker)
    if newline < 0 or head[marker + len(b"end_header"):newline].strip():
        raise InputError(f"{path}: PLY 'end_header' is not followed by a line break")
    fmt = None
    elements: list[tuple[str, int, list[PlyProperty]]] = []
    comments: list[str] = []
    lines = head[:marker].decode("ascii", errors="replace").splitlines()
    for number, raw in enumerate(lines[1:], start=2):
        words = raw.split()
        where = f"{path}: PLY header line {number}"
        if not words:
            continue
        if words[0] in ("comment", "obj_info"):
            comments.append(" ".join(words[1:]))
            continue
        if words[0] == "format":
            if len(words) != 3 or words[1] not in _PLY_FORMATS or fmt is not None:
                raise InputError(f"{where}: bad or repeated format line {raw.strip()[:80]!r}")
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdecimal() or not words[2].isascii():
                raise InputError(f"{where}: bad element line {raw.strip()[:80]!r}")
            if any(name == words[1] for name, _, _ in elements):
                raise InputError(f"{where}: element {words[1]!r} declared twice")
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            if not elements:
                raise InputError(f"{where}: property before any element")
            if len(words) == 5 and words[1] == "list":
                if words[2] not in _PLY_TYPES or words[3] not in _PLY_TYPES:
                    raise InputError(f"{where}: unknown property type in {raw.strip()[:80]!r}")
                if _PLY_TYPES[words[2]][0] == "f":
                    raise InputError(f"{where}: a list length must have an integer type, not {words[2]!r}")
                prop = PlyProperty(words[4], _PLY_TYPES[words[3]], _PLY_TYPES[words[2]])
            elif len(words) == 3 and words[1] in _PLY_TYPES:
                prop = PlyProperty(words[2], _PLY_TYPES[words[1]])
            else:
                raise InputError(f"{where}: bad property line {raw.strip()[:80]!r}")
            if any(p.name == prop.name for p in elements[-1][2]):
                raise InputError(f"{where}: property {prop.name!r} declared twice")
            elements[-1][2].append(prop)
        else:
            raise InputError(f"{where}: unknown header keyword {words[0][:40]!r}")
    if fmt is None:
        raise InputError(f"{path}: PLY header has no format line")
    for name, count, props in elements:
        if count and not props:
            raise InputError(f"{path}: PLY element {name!r} has {count} rows but no properties")
    return PlyHeader(fmt, tuple((n, c, tuple(p)) for n, c, p in elements), newline + 1, tuple(comments))


def _ply_min_body_bytes(header: PlyHeader) -> int:
    """Fewest body bytes the declared elements can occupy (every list empty)."""
    total = 0
    for _, count, props in header.elements:
        if header.format == "ascii":
            row = 2 * len(props)  # one character and one separator per value
        else:
            row = sum(np.dtype(p.count_kind or p.kind).itemsize for p in props)
        total += count * max(row, 1)
    return total - 1 if header.format == "ascii" and total else total


def check_ply_header(path: Path) -> dict[str, int]:
    """Parse a PLY header and refuse element counts the file cannot hold.

    Returns {element name: count}. Reads at most 64 KiB and allocates nothing for the
    body, so a header declaring 10**12 vertices in a small file fails at once; counts
    beyond the limits of :mod:`heoslice.mesh.limits` and ASCII bodies far larger than
    their rows are refused alike.
    """
    path = Path(path)
    with open_regular(path, "mesh") as handle:
        size = os.fstat(handle.fileno()).st_size
        head = handle.read(_PLY_MAX_HEADER_BYTES)
    header = parse_ply_header(path, head)
    needed = _ply_min_body_bytes(header)
    body_bytes = size - header.body_offset
    if needed > body_bytes:
        declared = ", ".join(f"{count} {name}" for name, count, _ in header.elements)
        raise InputError(
            f"{path}: truncated or corrupt PLY: the header declares {declared} "
            f"(at least {needed} bytes) but the body holds {body_bytes} bytes"
        )
    for name, count, _ in header.elements:
        limit = MAX_VERTICES if name == "vertex" else MAX_TRIANGLES
        check_count(path, f"{name!r} rows" if name != "vertex" else "vertices", count, limit)
    if header.format == "ascii":
        check_text_body(path, body_bytes, sum(count for _, count, _ in header.elements))
    return {name: count for name, count, _ in header.elements}


def _list_dtype(props: tuple[PlyProperty, ...], lengths: list[int], order: str) -> np.dtype:
    """Structured dtype of one binary row whose list properties have the given lengths."""
    fields, lists = [], iter(lengths)
    for prop in props:
        if prop.count_kind is None:
            fields.append((prop.name, order + prop.kind))
        else:
            fields.append((f"{prop.name} length", order + prop.count_kind))
            fields.append((prop.name, order + prop.kind, (next(lists),)))
    return np.dtype(fields)


def _gather(data: np.ndarray, starts: np.ndarray, kind: str) -> np.ndarray:
    """Values of numpy type ``kind`` (with byte order) stored at byte offsets ``starts`` of ``data``: (k,) native."""
    width = np.dtype(kind).itemsize
    raw = np.empty((len(starts), width), dtype=np.uint8)
    for byte in range(width):  # one pass per byte of the type, not per value
        raw[:, byte] = data[starts + byte]
    return raw.view(kind).reshape(-1).astype(np.dtype(kind).newbyteorder("="))


def _row_ends(data: np.ndarray, starts: np.ndarray, props: tuple[PlyProperty, ...],
              order: str) -> tuple[np.ndarray, np.ndarray]:
    """For rows beginning at byte offsets ``starts`` (k,): (end offsets (k,), readable (k,) bool).

    A row is unreadable when a list length lies past the end of the data, is
    negative, or makes the row run past the end.
    """
    cursor = starts.astype(np.int64)
    readable = np.ones(len(starts), dtype=bool)
    for prop in props:
        if prop.count_kind is None:
            cursor = cursor + np.dtype(prop.kind).itemsize
            continue
        width = np.dtype(prop.count_kind).itemsize
        readable &= cursor + width <= len(data)
        lengths = np.zeros(len(starts), dtype=np.int64)
        lengths[readable] = _gather(data, cursor[readable], order + prop.count_kind)
        readable &= lengths >= 0
        cursor = cursor + width + np.where(readable, lengths, 0) * np.dtype(prop.kind).itemsize
    return cursor, readable & (cursor <= len(data))


def _binary_row_starts(path: Path, data: np.ndarray, offset: int, count: int, name: str,
                       props: tuple[PlyProperty, ...], order: str, window: int = 1 << 18) -> np.ndarray:
    """Byte offsets of the ``count`` rows of a binary element whose list lengths vary from row to row.

    Each row's start depends on all earlier list lengths. Window by window, the end of a
    row that would start at every byte position is computed at once, and the chain of
    row starts is followed by pointer doubling (log2 steps per window, no loop per row).
    """
    found: list[np.ndarray] = []
    rows = 0
    while rows < count:
        size = min(window, len(data) - offset)
        if size <= 0:
            raise InputError(f"{path}: truncated PLY: element {name!r} ends at row {rows} of {count}")
        positions = offset + np.arange(size, dtype=np.int64)
        ends, readable = _row_ends(data, positions, props, order)
        step = np.where(readable, np.minimum(ends - offset, size), size + 1)  # size: leaves the window; +1: bad
        jump = np.concatenate([step, [size, size + 1]])
        chain = np.zeros(1, dtype=np.int64)
        if readable[0]:
            while len(chain) < count - rows:
                further = jump[chain]  # the next len(chain) chain members, in order
                outside = np.flatnonzero(further >= size)
                chain = np.concatenate([chain, further[:outside[0]] if len(outside) else further])
                if len(outside):
                    break
                jump = jump[jump]
        chain = chain[:count - rows]
        last = int(chain[-1])
        if not readable[last]:
            raise InputError(f"{path}: truncated or corrupt PLY: element {name!r} row {rows + len(chain) - 1} "
                             "has a negative list length or runs past the end of the file")
        found.append(offset + chain)
        rows += len(chain)
        offset = int(ends[last])
    return np.concatenate(found)


def _binary_columns(data: np.ndarray, starts: np.ndarray, props: tuple[PlyProperty, ...],
                    order: str) -> tuple[dict, int]:
    """Columns of binary rows at known starts: ({name: array, or (lengths, flat values) for lists}, end offset)."""
    columns: dict = {}
    cursor = starts.astype(np.int64)
    for prop in props:
        if prop.count_kind is None:
            columns[prop.name] = _gather(data, cursor, order + prop.kind)
            cursor = cursor + np.dtype(prop.kind).itemsize
            continue
        width, item = np.dtype(prop.count_kind).itemsize, np.dtype(prop.kind).itemsize
        lengths = _gather(data, cursor, order + prop.count_kind).astype(np.int64)
        within = np.arange(int(lengths.sum())) - np.repeat(np.cumsum(lengths) - lengths, lengths)
        columns[prop.name] = (lengths, _gather(data, np.repeat(cursor + width, lengths) + within * item,
                                               order + prop.kind))
        cursor = cursor + width + lengths * item
    return columns, int(cursor[-1]) if len(cursor) else int(starts.max(initial=0))


def _read_binary_element(path: Path, buffer: memoryview, offset: int, name: str, count: int,
                         props: tuple[PlyProperty, ...], order: str) -> tuple[dict, int]:
    """Read one binary element: ({property: array, or (lengths, flat values) for lists}, end offset).

    Rows whose lists all have the first row's lengths (all-triangle files) are one
    zero-copy read; otherwise the row starts are found by :func:`_binary_row_starts`.
    """
    end = len(buffer)
    lengths: list[int] = []
    if any(p.count_kind for p in props) and count:
        data = np.frombuffer(buffer, dtype=np.uint8)
        _, readable = _row_ends(data, np.array([offset]), props, order)
        if not readable[0]:
            raise InputError(f"{path}: truncated or corrupt PLY: element {name!r} row 0 "
                             "has a negative list length or runs past the end of the file")
        lengths = [int(v) for v in _first_row_lengths(data, offset, props, order)]
    dtype = _list_dtype(props, lengths, order)
    if count * dtype.itemsize > end - offset and not lengths:
        raise InputError(f"{path}: truncated PLY: element {name!r} needs {count * dtype.itemsize} bytes, "
                         f"{end - offset} left")
    if count * dtype.itemsize <= end - offset:
        rows = np.frombuffer(buffer, dtype, count, offset)
        uniform = all(np.all(rows[f"{p.name} length"] == n) for p, n in zip((p for p in props if p.count_kind),
                                                                             lengths))
        if uniform:
            columns = {p.name: rows[p.name] if p.count_kind is None else
                       (np.full(count, n, dtype=np.int64), rows[p.name].reshape(-1))
                       for p, n in zip(props, _list_lengths_per_prop(props, lengths))}
            return columns, offset + count * dtype.itemsize
    data = np.frombuffer(buffer, dtype=np.uint8)
    starts = _binary_row_starts(path, data, offset, count, name, props, order)
    return _binary_columns(data, starts, props, order)


def _first_row_lengths(data: np.ndarray, offset: int, props: tuple[PlyProperty, ...], order: str) -> list[int]:
    """List lengths of the row starting at ``offset`` (in property order)."""
    lengths, cursor = [], offset
    for prop in props:
        if prop.count_kind is None:
            cursor += np.dtype(prop.kind).itemsize
            continue
        length = int(_gather(data, np.array([cursor]), order + prop.count_kind)[0])
        lengths.append(length)
        cursor += np.dtype(prop.count_kind).itemsize + length * np.dtype(prop.kind).itemsize
    return lengths


def _list_lengths_per_prop(props: tuple[PlyProperty, ...], lengths: list[int]) -> list[int | None]:
    """``lengths`` (one per list property) spread over all properties (None for scalars)."""
    spread = iter(lengths)
    return [next(spread) if p.count_kind else None for p in props]


def _read_ascii_elements(path: Path, header: PlyHeader, body: bytes, first_line: int) -> dict[str, dict]:
    """Every element of an ASCII body (one row per non-empty line), vectorised per property."""
    values, row_start, row_length, row_line = ascii_rows(path, body, first_line)
    elements: dict[str, dict] = {}
    row = 0
    for name, count, props in header.elements:
        if row + count > len(row_start):
            raise InputError(f"{path}: truncated PLY: element {name!r} has {len(row_start) - row} "
                             f"of its {count} rows")
        cursor = row_start[row:row + count].astype(np.int64)
        stop = cursor + row_length[row:row + count]
        lines = row_line[row:row + count]
        columns: dict = {}
        for prop in props:
            short = cursor >= stop
            if short.any():
                raise InputError(f"{path}: PLY line {lines[np.argmax(short)]}: too few values for element {name!r}")
            if prop.count_kind is None:
                columns[prop.name] = as_type(path, values[cursor], prop.kind, lines, f"{prop.name!r}")
                cursor = cursor + 1
                continue
            lengths = as_type(path, values[cursor], prop.count_kind, lines,
                                   f"list length of {prop.name!r}").astype(np.int64)
            if (lengths < 0).any():
                raise InputError(f"{path}: PLY line {lines[np.argmax(lengths < 0)]}: negative list length")
            cursor = cursor + 1
            over = cursor + lengths > stop
            if over.any():
                raise InputError(f"{path}: PLY line {lines[np.argmax(over)]}: list {prop.name!r} declares "
                                 f"{lengths[np.argmax(over)]} values, the line holds fewer")
            within = np.arange(int(lengths.sum())) - np.repeat(np.cumsum(lengths) - lengths, lengths)
            flat = values[np.repeat(cursor, lengths) + within]
            columns[prop.name] = (lengths, as_type(path, flat, prop.kind, np.repeat(lines, lengths),
                                                        f"{prop.name!r} value"))
            cursor = cursor + lengths
        extra = cursor != stop
        if extra.any():
            raise InputError(f"{path}: PLY line {lines[np.argmax(extra)]}: more values than element {name!r} declares")
        elements[name] = columns
        row += count
    if row < len(row_start):
        raise InputError(f"{path}: PLY line {row_line[row]}: data after the last declared element")
    return elements


def _ply_mesh(path: Path, elements: dict[str, dict], comments: tuple[str, ...] = ()) -> RawMesh:
    """Check the parsed elements and build a :class:`RawMesh` (vertex scalar columns kept as vertex_properties)."""
    vertex = elements.get("vertex")
    if vertex is None:
        raise InputError(f"{path}: PLY has no 'vertex' element")
    for axis in "xyz":
        if axis not in vertex or isinstance(vertex[axis], tuple):
            raise InputError(f"{path}: PLY vertex element has no scalar property {axis!r}")
    vertices = np.column_stack([vertex[axis].astype(np.float64) for axis in "xyz"])
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.all():
        raise InputError(f"{path}: vertex {int(np.argmin(finite))} has a NaN or infinite coordinate")
    face = elements.get("face")
    if "tristrips" in elements and (face is None or not len(_index_list(path, face, "face")[0])):
        face = {}
        triangles = strip_triangles(path, len(vertices), *_index_list(path, elements["tristrips"], "tristrips"))
        polygon = np.arange(len(triangles))
    elif face is None:
        raise InputError(f"{path}: PLY has no 'face' element")
    else:
        lengths, flat = _index_list(path, face, "face")
        triangles, polygon = checked_triangles(path, len(vertices), lengths, flat)
    vertex_columns = {k: v for k, v in vertex.items() if not isinstance(v, tuple)}
    face_colors = None
    if all(not isinstance(face.get(c), tuple) and getattr(face.get(c), "dtype", None) == np.uint8
           for c in ("red", "green", "blue")):
        face_colors = np.stack([face[c] for c in ("red", "green", "blue")], axis=1)[polygon]
    vertex_colors = _vertex_rgb(vertex_columns)
    source = "vertex" if vertex_colors is not None else "face" if face_colors is not None else None
    return RawMesh(vertices, triangles, vertex_colors=vertex_colors, face_colors=face_colors, color_source=source,
                   vertex_properties=vertex_columns, comments=comments)


def _index_list(path: Path, element: dict, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(lengths, concatenated indices) of an element's vertex index list property (``face`` or ``tristrips``)."""
    key = next((key for key in _PLY_FACE_LISTS if isinstance(element.get(key), tuple)), None)
    if key is None:
        raise InputError(f"{path}: PLY {name} element has no list property 'vertex_indices'")
    lengths, flat = element[key]
    if flat.dtype.kind == "f":
        raise InputError(f"{path}: PLY {name} property {key!r} holds floats; vertex indices must be integers")
    return lengths, flat


def _vertex_rgb(columns: dict[str, np.ndarray]) -> np.ndarray | None:
    """Per-vertex RGB as (n, 3) uint8 from the red/green/blue columns (uchar 0..255 or float 0..1), or None."""
    if not all(name in columns for name in ("red", "green", "blue")):
        return None
    rgb = np.stack([columns[name] for name in ("red", "green", "blue")], axis=1)
    if np.issubdtype(rgb.dtype, np.floating):
        rgb = np.nan_to_num(rgb.astype(np.float64))
        if rgb.max(initial=0.0) <= 1.0:
            rgb = rgb * 255.0
        return np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
    return np.clip(rgb, 0, 255).astype(np.uint8)


def read_ply(path: Path) -> RawMesh:
    """Read a PLY file (ascii or binary, any byte order) strictly into a :class:`RawMesh`.

    Every structural flaw is an InputError naming the file and the place: impossible
    element counts (refused before the body is read), truncated or over-long bodies,
    values that are not numbers or do not fit their type, negative list lengths,
    faces with fewer than 3 vertices or indices outside the vertex list, NaN
    coordinates. Polygons are fan-triangulated; unknown elements and extra
    properties are read and ignored.
    """
    path = Path(path)
    check_ply_header(path)
    data = read_bounded(path, MAX_MESH_BYTES, "mesh")
    header = parse_ply_header(path, data[:_PLY_MAX_HEADER_BYTES])
    if header.format == "ascii":
        first_line = data[:header.body_offset].count(b"\n") + 1
        body = data[header.body_offset:]
        del data
        check_text_body(path, len(body), sum(count for _, count, _ in header.elements), body.count(b"\n"))
        elements = _read_ascii_elements(path, header, body, first_line)
    else:
        order = _PLY_FORMATS[header.format]
        buffer = memoryview(data)
        offset = header.body_offset
        elements = {}
        for name, count, props in header.elements:
            elements[name], offset = _read_binary_element(path, buffer, offset, name, count, props, order)
        if data[offset:].strip():
            raise InputError(f"{path}: {len(data) - offset} bytes of data after the last declared PLY element")
    return _ply_mesh(path, elements, header.comments)

