"""PLY reading: every format and variant read as trimesh reads it, each malformed input a one-line error.

Test files are written here by hand (PLY bytes built from numpy) or exported by
trimesh, the independent reference for what a file holds. The helpers (ply_bytes,
one_line_error, the cube and tetrahedron) are shared by the other mesh tests.
"""

from __future__ import annotations

import struct
import tracemalloc

import numpy as np
import pytest
import shapely
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice import procedural
from heoslice.errors import InputError
from heoslice.mesh import check_ply_header, load_mesh, read_ply

PLY_NUMPY = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4",
             "float": "f4", "double": "f8", "int32": "i4", "uint8": "u1", "float32": "f4", "float64": "f8"}


CUBE_VERTICES = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
                          [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], dtype=float) * 10.0


CUBE_QUADS = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]


TETRA_VERTICES = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]], dtype=float)


TETRA_FACES = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]


def ply_bytes(fmt: str, vertices, faces, *, coord="float", index="int", count="uchar",
              vertex_extra=(), face_extra=(), extra_elements=()) -> bytes:
    """A PLY file built by hand. vertex_extra / face_extra: (name, type, values); faces may be any polygons.

    extra_elements: (name, [(prop name, type)], rows (n, k)) written after the faces.
    """
    vertices = np.asarray(vertices)
    lines = ["ply", f"format {fmt} 1.0", "comment built by test_loading", f"element vertex {len(vertices)}"]
    lines += [f"property {coord} {axis}" for axis in "xyz"]
    lines += [f"property {kind} {name}" for name, kind, _ in vertex_extra]
    lines += [f"element face {len(faces)}", f"property list {count} {index} vertex_indices"]
    lines += [f"property {kind} {name}" for name, kind, _ in face_extra]
    for name, props, rows in extra_elements:
        lines += [f"element {name} {len(rows)}"] + [f"property {kind} {prop}" for prop, kind in props]
    header = ("\n".join(lines + ["end_header"]) + "\n").encode()
    vcols = [(axis, coord, vertices[:, i]) for i, axis in enumerate("xyz")] + list(vertex_extra)
    if fmt == "ascii":
        body = []
        for row in range(len(vertices)):
            body.append(" ".join(repr(float(v[row])) if PLY_NUMPY[k][0] == "f" else str(int(v[row]))
                                 for _, k, v in vcols))
        for number, face in enumerate(faces):
            extra = [str(v[number]) for _, _, v in face_extra]
            body.append(" ".join([str(len(face))] + [str(i) for i in face] + extra))
        for _, props, rows in extra_elements:
            body += [" ".join(str(v) for v in row) for row in rows]
        return header + ("\n".join(body) + "\n").encode()
    order = "<" if fmt == "binary_little_endian" else ">"
    vdtype = np.dtype([(name, order + PLY_NUMPY[kind]) for name, kind, _ in vcols])
    vrows = np.zeros(len(vertices), dtype=vdtype)
    for name, _, values in vcols:
        vrows[name] = values
    body = vrows.tobytes()
    for number, face in enumerate(faces):
        body += np.array([len(face)], dtype=order + PLY_NUMPY[count]).tobytes()
        body += np.asarray(face, dtype=order + PLY_NUMPY[index]).tobytes()
        for _, kind, values in face_extra:
            body += np.array([values[number]], dtype=order + PLY_NUMPY[kind]).tobytes()
    for _, props, rows in extra_elements:
        edtype = np.dtype([(prop, order + PLY_NUMPY[kind]) for prop, kind in props])
        body += np.array([tuple(row) for row in rows], dtype=edtype).tobytes()
    return header + body


def write(tmp_path, name: str, data: bytes):
    path = tmp_path / name
    path.write_bytes(data)
    return path


def one_line_error(path) -> str:
    """load_mesh's InputError message, checked to be one line naming the file."""
    with pytest.raises(InputError) as caught:
        load_mesh(path)
    message = str(caught.value)
    assert "\n" not in message and str(path) in message
    return message


FORMATS = ["ascii", "binary_little_endian", "binary_big_endian"]


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("coord", ["float", "double"])
def test_ply_formats_match_trimesh(tmp_path, fmt, coord):
    """PLY ascii / binary LE / BE with float or double coordinates read the same arrays as trimesh's reader."""
    mesh = procedural.sphere(radius=7.0, subdivisions=2)
    path = write(tmp_path, "s.ply", ply_bytes(fmt, mesh.vertices, mesh.faces.tolist(), coord=coord))
    ours = read_ply(path)
    reference = trimesh.load(path, force="mesh", process=False)
    np.testing.assert_array_equal(ours.vertices, reference.vertices)
    np.testing.assert_array_equal(ours.faces, reference.faces)
    loaded = load_mesh(path)
    assert loaded.warnings == ()
    assert trimesh.Trimesh(loaded.vertices, loaded.faces).volume == pytest.approx(mesh.volume, rel=1e-6)


def test_trimesh_exported_ply_reads_back(tmp_path):
    """A binary PLY written by trimesh (with vertex colours) reads back with the same geometry and colours."""
    mesh = procedural.torus()
    colors = np.random.default_rng(1).integers(0, 256, (len(mesh.vertices), 4), dtype=np.uint8)
    mesh.visual.vertex_colors = colors
    path = tmp_path / "t.ply"
    mesh.export(path)
    ours = read_ply(path)
    np.testing.assert_allclose(ours.vertices, mesh.vertices)
    np.testing.assert_array_equal(ours.faces, mesh.faces)
    loaded = load_mesh(path)
    # load_mesh welds by coordinate keeping first occurrences in order: unique vertices stay as they are
    np.testing.assert_array_equal(loaded.vertices, ours.vertices)
    np.testing.assert_array_equal(loaded.colors, colors[:, :3])


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("kind, alpha", [("uchar", False), ("uchar", True), ("float", False), ("float", True)])
def test_vertex_colours_uchar_and_float_rgb_and_rgba(tmp_path, fmt, kind, alpha):
    """Colours as uchar 0..255 or float 0..1, with or without alpha, become (n, 3) uint8 RGB."""
    rgb = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [51, 102, 153]])
    values = rgb / 255.0 if kind == "float" else rgb
    extra = [(c, kind, values[:, i]) for i, c in enumerate(("red", "green", "blue"))]
    if alpha:
        extra.append(("alpha", kind, np.full(4, 1.0 if kind == "float" else 255)))
    path = write(tmp_path, "c.ply", ply_bytes(fmt, TETRA_VERTICES, TETRA_FACES, vertex_extra=extra))
    mesh = load_mesh(path)
    np.testing.assert_array_equal(mesh.colors, rgb)


@pytest.mark.parametrize("fmt", FORMATS)
def test_quads_and_polygons_are_triangulated(tmp_path, fmt):
    """A cube of quads is a closed mesh of 12 triangles, volume 1000; a hexagon fan keeps the polygon's area."""
    path = write(tmp_path, "cube.ply", ply_bytes(fmt, CUBE_VERTICES, CUBE_QUADS))
    mesh = load_mesh(path)
    assert len(mesh.faces) == 12 and mesh.warnings == ()
    assert trimesh.Trimesh(mesh.vertices, mesh.faces).volume == pytest.approx(1000.0)
    angle = np.linspace(0, 2 * np.pi, 7)[:-1]
    ring = np.column_stack([5 * np.cos(angle), 3 * np.sin(angle), np.zeros(6)])
    apex = [[0.0, 0.0, 4.0]]
    faces = [[5, 4, 3, 2, 1, 0]] + [[i, (i + 1) % 6, 6] for i in range(6)]
    ours = read_ply(write(tmp_path, "hexa.ply", ply_bytes(fmt, np.vstack([ring, apex]), faces)))
    base = ours.faces[:4]
    assert len(ours.faces) == 4 + 6
    area = 0.5 * np.linalg.norm(np.cross(ours.vertices[base[:, 1]] - ours.vertices[base[:, 0]],
                                         ours.vertices[base[:, 2]] - ours.vertices[base[:, 0]]), axis=1).sum()
    assert area == pytest.approx(shapely.Polygon(ring[:, :2]).area)


@pytest.mark.parametrize("pattern", ["alternating", "blocks"])
def test_binary_mixed_polygon_sizes_match_ascii(tmp_path, pattern):
    """Binary PLY with polygon sizes changing from row to row reads exactly like the same ASCII file."""
    rng = np.random.default_rng(7)
    vertices = rng.uniform(0, 10, (40, 3))
    if pattern == "alternating":
        sizes = [3 + (i % 3) for i in range(3000)]
    else:
        sizes = [3] * 1500 + [4] * 2500 + [5] * 7 + [3] * 1100
    faces = [list(rng.choice(40, size, replace=False)) for size in sizes]
    binary = read_ply(write(tmp_path, "b.ply", ply_bytes("binary_little_endian", vertices, faces)))
    text = read_ply(write(tmp_path, "a.ply", ply_bytes("ascii", vertices, faces)))
    np.testing.assert_array_equal(binary.faces, text.faces)
    assert len(binary.faces) == sum(s - 2 for s in sizes)
    np.testing.assert_array_equal(binary.faces[:1], [faces[0][:3]])


@pytest.mark.parametrize("fmt", FORMATS)
def test_extra_properties_and_elements_are_ignored(tmp_path, fmt):
    """Normals, confidence, face flags and unknown elements do not change the geometry read."""
    extra = [("nx", "float", np.zeros(4)), ("confidence", "double", np.ones(4)), ("intensity", "uchar", np.ones(4))]
    face_extra = [("flags", "int", np.arange(4))]
    edges = ("edge", [("vertex1", "int"), ("vertex2", "int")], [[0, 1], [1, 2]])
    path = write(tmp_path, "x.ply", ply_bytes(fmt, TETRA_VERTICES, TETRA_FACES, vertex_extra=extra,
                                               face_extra=face_extra, extra_elements=[edges]))
    ours = read_ply(path)
    np.testing.assert_array_equal(ours.vertices, TETRA_VERTICES)
    np.testing.assert_array_equal(ours.faces, TETRA_FACES)


def test_hostile_element_counts_are_refused_without_allocating(tmp_path):
    """10**9 and 10**12 declared elements in a tiny file: one-line error, < 5 MB traced allocation."""
    for fmt in ("binary_little_endian", "ascii"):
        for count in (10**9, 10**12, 2**63 + 5):
            data = ply_bytes(fmt, TETRA_VERTICES, TETRA_FACES).replace(b"element vertex 4",
                                                                       f"element vertex {count}".encode())
            path = write(tmp_path, "hostile.ply", data)
            tracemalloc.start()
            try:
                message = one_line_error(path)
                _, peak = tracemalloc.get_traced_memory()
            finally:
                tracemalloc.stop()
            assert "truncated or corrupt" in message and str(count) in message
            assert peak < 5 << 20


def test_hostile_list_length_is_refused(tmp_path):
    """A binary face declaring 2**32-1 indices in a small file is refused before reading them."""
    good = ply_bytes("binary_little_endian", TETRA_VERTICES, TETRA_FACES, count="uint")
    header_end = good.index(b"end_header\n") + len(b"end_header\n")
    at = header_end + 4 * 12
    data = good[:at] + struct.pack("<I", 2**32 - 1) + good[at + 4:]
    tracemalloc.start()
    try:
        message = one_line_error(write(tmp_path, "list.ply", data))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert "truncated" in message and peak < 5 << 20


TETRA_ASCII = ply_bytes("ascii", TETRA_VERTICES, TETRA_FACES)


TETRA_BINARY = ply_bytes("binary_little_endian", TETRA_VERTICES, TETRA_FACES)


HEADER_END = TETRA_BINARY.index(b"end_header\n") + len(b"end_header\n")


@pytest.mark.parametrize("name, data, expected", [
    ("truncated binary body", TETRA_BINARY[:-5], "truncated"),
    ("truncated inside the vertices", TETRA_BINARY[:HEADER_END + 20], "truncated"),
    ("binary garbage after the body", TETRA_BINARY + b"GARBAGE!", "after the last declared"),
    ("ascii garbage token", TETRA_ASCII.replace(b"10.0 0.0 0.0", b"10.0 zz 0.0"), "'zz' is not a number"),
    ("ascii hex token", TETRA_ASCII.replace(b"10.0 0.0 0.0", b"0x1A 0.0 0.0"), "is not a number"),
    ("ascii lines after the last element", TETRA_ASCII + b"1 2 3\n", "after the last declared"),
    ("ascii missing face row", TETRA_ASCII.replace(b"3 1 2 3\n", b""), "3 of its 4 rows"),
    ("ascii short vertex line", TETRA_ASCII.replace(b"10.0 0.0 0.0", b"10.0 0.0"), "too few values"),
    ("ascii long vertex line", TETRA_ASCII.replace(b"10.0 0.0 0.0", b"10.0 0.0 0.0 4"), "more values"),
    ("ascii list longer than its line", TETRA_ASCII.replace(b"3 1 2 3", b"4 1 2 3"), "declares 4 values"),
    ("ascii fractional index", TETRA_ASCII.replace(b"3 1 2 3", b"3 1 2 2.5"), "is not a int32"),
    ("ascii non-ascii byte", TETRA_ASCII.replace(b"10.0 0.0 0.0", b"10.0 \xc3\xa9 0.0"), "non-ASCII"),
    ("ascii token too long", TETRA_ASCII.replace(b"10.0 0.0 0.0", b"1" * 100 + b" 0 0"), "longer than"),
    ("unknown property type", TETRA_ASCII.replace(b"property float y", b"property flot y"), "bad property"),
    ("float list length", TETRA_ASCII.replace(b"list uchar int", b"list float int"), "integer type"),
    ("float vertex indices", TETRA_ASCII.replace(b"list uchar int", b"list uchar float"), "must be integers"),
    ("duplicate property", TETRA_ASCII.replace(b"property float y", b"property float x"), "declared twice"),
    ("no x property", TETRA_ASCII.replace(b"property float x\n", b"property float w\n"), "'x'"),
    ("no end_header", TETRA_ASCII.replace(b"end_header", b"end_headr"), "end_header"),
    ("no magic", b"plx" + TETRA_ASCII[3:], "not a PLY file"),
    ("no format line", TETRA_ASCII.replace(b"format ascii 1.0\n", b""), "no format line"),
    ("unknown format", TETRA_ASCII.replace(b"format ascii", b"format binary_middle_endian"), "format"),
    ("unknown keyword", TETRA_ASCII.replace(b"comment", b"frobnicate"), "unknown header keyword"),
    ("no face element", TETRA_ASCII.replace(b"element face 4", b"element edge 4"), "face"),
    ("negative index", TETRA_ASCII.replace(b"3 1 2 3", b"3 1 2 -3"), "face 3 refers to vertex -3"),
    ("index out of range", TETRA_ASCII.replace(b"3 1 2 3", b"3 1 2 9"), "face 3 refers to vertex 9"),
    ("two-vertex face", TETRA_ASCII.replace(b"3 1 2 3", b"2 1 2"), "face 3 has 2 vertices"),
    ("empty face", TETRA_ASCII.replace(b"3 1 2 3", b"0"), "face 3 has 0 vertices"),
    ("NaN coordinate", TETRA_ASCII.replace(b"10.0 0.0 0.0", b"10.0 nan 0.0"), "vertex 1 has a NaN"),
    ("infinite coordinate", TETRA_ASCII.replace(b"10.0 0.0 0.0", b"10.0 1e999 0.0"), "vertex 1 has a NaN"),
])
def test_malformed_ply_is_one_line_input_error(tmp_path, name, data, expected):
    """Each kind of malformed PLY gives one InputError line naming the file and the problem."""
    assert expected in one_line_error(write(tmp_path, "bad.ply", data))


@pytest.mark.parametrize("fmt", ["binary_little_endian", "binary_big_endian"])
def test_binary_index_and_nan_errors(tmp_path, fmt):
    """Binary bodies: negative and out-of-range indices, short faces, NaN and a negative list length."""
    cases = [([[0, 2, 1], [0, 1, 3], [0, 3, -2], [1, 2, 3]], TETRA_VERTICES, "char", "face 2 refers to vertex -2"),
             ([[0, 2, 1], [0, 1, 3], [0, 3, 70000], [1, 2, 3]], TETRA_VERTICES, "char", "face 2 refers to vertex"),
             ([[0, 2], [0, 1, 3], [0, 3, 2], [1, 2, 3]], TETRA_VERTICES, "char", "face 0 has 2 vertices"),
             (TETRA_FACES, np.where(np.eye(4, 3) > 0, np.nan, TETRA_VERTICES), "char", "vertex 0 has a NaN")]
    for faces, vertices, count, expected in cases:
        path = write(tmp_path, "bad.ply", ply_bytes(fmt, vertices, faces, count=count))
        assert expected in one_line_error(path)
    data = bytearray(ply_bytes(fmt, TETRA_VERTICES, TETRA_FACES, count="char"))
    data[data.index(b"end_header\n") + 11 + 4 * 12] = 0xFF  # first face's length: -1
    assert "negative list length" in one_line_error(write(tmp_path, "neg.ply", bytes(data)))


def test_check_ply_header_returns_counts(tmp_path):
    """check_ply_header gives {element: count} of a well-formed file."""
    path = write(tmp_path, "t.ply", TETRA_BINARY)
    assert check_ply_header(path) == {"vertex": 4, "face": 4}


@settings(max_examples=30, deadline=None)
@given(data=st.data())
def test_ply_round_trip(tmp_path_factory, data):
    """Any vertex table and polygon list written in any format and types reads back exactly (fan-triangulated)."""
    fmt = data.draw(st.sampled_from(FORMATS))
    coord = data.draw(st.sampled_from(["float", "double"]))
    index = data.draw(st.sampled_from(["int", "uint", "short", "ushort"]))
    count = data.draw(st.sampled_from(["uchar", "char", "int", "ushort"]))
    n = data.draw(st.integers(3, 30))
    vertices = np.array(data.draw(st.lists(st.tuples(*[st.integers(-1000, 1000)] * 3), min_size=n, max_size=n)),
                        dtype=float) / 8.0
    polygons = data.draw(st.lists(st.lists(st.integers(0, n - 1), min_size=3, max_size=7), min_size=1, max_size=40))
    path = tmp_path_factory.mktemp("rt") / "r.ply"
    path.write_bytes(ply_bytes(fmt, vertices, polygons, coord=coord, index=index, count=count))
    mesh = read_ply(path)
    np.testing.assert_array_equal(mesh.vertices, vertices)
    expected = [[p[0], p[k], p[k + 1]] for p in polygons for k in range(1, len(p) - 1)]
    np.testing.assert_array_equal(mesh.faces, expected)


@pytest.mark.parametrize("window", [16, 61, 1000, 1 << 18])
def test_row_starts_are_the_same_for_any_window(tmp_path, window):
    """Finding binary row starts by pointer doubling gives the sequential answer whatever the window size
    (rows crossing window edges included)."""
    from heoslice.mesh.ply import _binary_row_starts, parse_ply_header

    rng = np.random.default_rng(11)
    sizes = rng.integers(3, 8, 700)
    faces = [list(rng.integers(0, 20, size)) for size in sizes]
    data = ply_bytes("binary_big_endian", rng.uniform(0, 1, (20, 3)), faces, count="ushort")
    header = parse_ply_header(tmp_path / "x.ply", data)
    offset = header.body_offset + 20 * 12
    name, count, props = header.elements[1]
    starts = _binary_row_starts(tmp_path / "x.ply", np.frombuffer(data, np.uint8), offset, count, name, props, ">",
                                window=window)
    expected = offset + np.concatenate([[0], np.cumsum(2 + 4 * sizes)[:-1]])
    np.testing.assert_array_equal(starts, expected)



def tristrips_ply(vertices, strips: list[list[int]], *, rows: bool = False, index: str = "int",
                  restart: int = -1, faces: bool = False) -> bytes:
    """An ASCII PLY whose triangles are a ``tristrips`` element: one list, the strips joined by ``restart`` (PLY's
    -1), or (``rows``) one row a strip; ``faces``: an empty face element before it."""
    lists = strips if rows else [[i for n, strip in enumerate(strips) for i in ([restart] if n else []) + strip]]
    header = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}", "property float x", "property float y",
              "property float z", *(["element face 0", "property list uchar int vertex_indices"] if faces else []),
              f"element tristrips {len(lists)}", f"property list int {index} vertex_indices", "end_header"]
    body = [" ".join(repr(float(v)) for v in vertex) for vertex in vertices]
    body += [" ".join(map(str, [len(row), *row])) for row in lists]
    return ("\n".join(header + body) + "\n").encode()


def reference_strip_triangles(strips: list[list[int]]) -> list[tuple[int, int, int]]:
    """Triangle strips decoded one triangle at a time: (v_i, v_i+1, v_i+2), the odd ones' first two swapped, those
    with a repeated vertex left out."""
    out = []
    for strip in strips:
        for i in range(len(strip) - 2):
            a, b, c = strip[i:i + 3]
            if len({a, b, c}) == 3:
                out.append((b, a, c) if i % 2 else (a, b, c))
    return out


@settings(max_examples=60, deadline=None)
@given(st.lists(st.lists(st.integers(0, 6), max_size=9), min_size=1, max_size=5))
def test_strips_decode_as_one_at_a_time(strips):
    """strip_triangles of strips joined by -1 are the strips decoded one triangle at a time, in order."""
    from heoslice.mesh.raw import strip_triangles

    flat = [index for number, strip in enumerate(strips) for index in ([-1] if number else []) + strip]
    joined = strip_triangles("t.ply", 7, np.array([len(flat)]), np.array(flat, dtype=np.int32))
    assert [tuple(t) for t in joined.tolist()] == reference_strip_triangles(strips)
    by_row = strip_triangles("t.ply", 7, np.array([len(strip) for strip in strips]),
                             np.array([i for strip in strips for i in strip], dtype=np.int32))
    assert np.array_equal(by_row, joined), "a row ends its strip, as -1 does"


def test_a_tristrips_ply_reads_as_its_triangles(tmp_path):
    """A PLY of triangle strips (no face element) is the closed mesh its strips make: the tetrahedron as one strip
    of six (0 1 2 3 0 1, its winding kept) and as four strips of one triangle read as the faces' tetrahedron."""
    from heoslice.mesh import mesh_info

    faces = mesh_info(load_mesh(write(tmp_path, "faces.ply", TETRA_BINARY)))
    one_strip, per_face = [[0, 2, 1, 3, 0, 2]], [list(face) for face in TETRA_FACES]
    for data in (tristrips_ply(TETRA_VERTICES, per_face), tristrips_ply(TETRA_VERTICES, per_face, rows=True),
                 tristrips_ply(TETRA_VERTICES, one_strip), tristrips_ply(TETRA_VERTICES, one_strip, faces=True),
                 tristrips_ply(TETRA_VERTICES, per_face, index="uint", restart=2**32 - 1)):
        mesh = load_mesh(write(tmp_path, "strips.ply", data))
        info = mesh_info(mesh)
        assert len(mesh.faces) == 4 and info["watertight"] and info["winding_consistent"]
        assert info["volume_mm3"] == pytest.approx(faces["volume_mm3"]) == pytest.approx(1000 / 6)


@pytest.mark.parametrize("strips, expected", [([[0, 2, 1, -5, 3, 0, 2]], "index -5 is outside 0..3"),
                                               ([[0, 2, 1, 3, 9]], "index 9 is outside 0..3")])
def test_a_bad_strip_index_is_one_line(tmp_path, strips, expected):
    """A negative index other than -1 (the one separator) or an index past the vertices: one line naming the file."""
    assert expected in one_line_error(write(tmp_path, "bad.ply", tristrips_ply(TETRA_VERTICES, strips, rows=True)))


@pytest.mark.shared_data
def test_the_shared_tristrips_scan_reads_closed(shared_data):
    """The shared data's igea_tristrips.ply (one tristrips list, -1 restarts, no face element) is the closed mesh
    of 268,686 triangles its README describes."""
    from heoslice.mesh import mesh_info

    mesh = load_mesh(shared_data / "bad" / "igea_tristrips.ply")
    info = mesh_info(mesh)
    assert len(mesh.faces) == 268686 and info["watertight"] and info["winding_consistent"]


def test_an_unsigned_strips_largest_value_is_a_vertex_where_it_can_be_one():
    """In a uchar strip list over 256 vertices, 255 is vertex 255, not a separator (only where the type's largest
    value cannot be a vertex does it stand for -1)."""
    from heoslice.mesh.raw import strip_triangles

    flat = np.array([0, 1, 255, 2], dtype=np.uint8)
    assert strip_triangles("t.ply", 256, np.array([4]), flat).tolist() == [[0, 1, 255], [255, 1, 2]]
    assert strip_triangles("t.ply", 200, np.array([4]), flat).tolist() == []
