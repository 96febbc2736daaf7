"""Fuzzing the readers of untrusted files: PLY headers and bodies, manifests, layer TIFFs.

Property: whatever the bytes, loading a mesh raises nothing but InputError, and
verifying a stack raises nothing at all (every flaw becomes a problem line); reading
a manifest raises nothing but VerifyError. Example counts are modest for CI; set
HEOSLICE_FUZZ_EXAMPLES for a longer run, or run ``python benchmarks/fuzz.py --minutes 10``.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from heoslice import procedural
from heoslice.errors import InputError, VerifyError
from heoslice.mesh import load_mesh
from heoslice.pipeline import SliceSpec, slice_to_stack
from heoslice.stack import (
    MANIFEST,
    layer_file_name,
    read_layer_mask,
    read_manifest,
    verify_stack,
)

#: A RuntimeWarning would reach the user's terminal as extra lines: treat it as a failure.
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

EXAMPLES = int(os.environ.get("HEOSLICE_FUZZ_EXAMPLES", "60"))
FUZZ = settings(max_examples=EXAMPLES, deadline=None, derandomize=EXAMPLES <= 60,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

TYPES = ["char", "uchar", "short", "ushort", "int", "uint", "float", "double", "int8", "uint8", "int16",
         "uint16", "int32", "uint32", "float32", "float64", "flot", "list", ""]
NAMES = ["x", "y", "z", "red", "green", "blue", "alpha", "material", "vertex_indices", "vertex_index", "nx", "q"]
COUNTS = st.one_of(st.integers(0, 12), st.sampled_from([10**9, 10**12, 2**31, 2**32 - 1, 2**63, 10**30]))


def seed_files() -> list[bytes]:
    """Valid PLY files in every format, with colours, polygons and extra properties, to mutate."""
    from test_mesh_ply import (
        CUBE_QUADS,
        CUBE_VERTICES,
        TETRA_FACES,
        TETRA_VERTICES,
        ply_bytes,
    )

    colours = [(c, "uchar", np.array([10, 20, 30, 40])) for c in ("red", "green", "blue")]
    files = []
    for fmt in ("ascii", "binary_little_endian", "binary_big_endian"):
        files.append(ply_bytes(fmt, TETRA_VERTICES, TETRA_FACES, vertex_extra=colours))
        files.append(ply_bytes(fmt, CUBE_VERTICES, CUBE_QUADS, coord="double", count="int"))
        mixed = [[0, 1, 2], [0, 1, 2, 3, 4, 5], [4, 5, 6, 7], [1, 2, 6]] * 3
        files.append(ply_bytes(fmt, CUBE_VERTICES, mixed, count="ushort", index="uint"))
    return files


SEEDS = seed_files()


@st.composite
def mutated(draw, seeds=None) -> bytes:
    """A seed file with a few random byte edits: flips, insertions, deletions, truncation, header number swaps."""
    data = bytearray(draw(st.sampled_from(seeds or SEEDS)))
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["flip", "insert", "delete", "truncate", "number"]))
        at = draw(st.integers(0, max(len(data) - 1, 0)))
        if kind == "flip" and data:
            data[at] = draw(st.integers(0, 255))
        elif kind == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=16))
        elif kind == "delete":
            del data[at:at + draw(st.integers(1, 16))]
        elif kind == "truncate":
            del data[at:]
        else:
            digits = [i for i, b in enumerate(data[:300]) if chr(b).isdigit()]
            if digits:
                spot = draw(st.sampled_from(digits))
                data[spot:spot + 1] = str(draw(COUNTS)).encode()
    return bytes(data)


@st.composite
def generated(draw) -> bytes:
    """A header built from the PLY grammar (with wrong types, huge counts, odd names) and a random body."""
    fmt = draw(st.sampled_from(["ascii", "binary_little_endian", "binary_big_endian", "binary"]))
    lines = ["ply", f"format {fmt} 1.0"]
    for element in draw(st.lists(st.sampled_from(["vertex", "face", "edge", "tristrips", "vertex"]), max_size=3)):
        lines.append(f"element {element} {draw(COUNTS)}")
        for _ in range(draw(st.integers(0, 5))):
            kind = draw(st.sampled_from(TYPES))
            name = draw(st.sampled_from(NAMES))
            if draw(st.booleans()):
                lines.append(f"property list {kind} {draw(st.sampled_from(TYPES))} {name}")
            else:
                lines.append(f"property {kind} {name}")
    header = ("\n".join(lines) + "\nend_header\n").encode()
    if fmt == "ascii":
        numbers = draw(st.lists(st.one_of(st.integers(-5, 20), st.floats(allow_nan=True, allow_infinity=True),
                                          st.sampled_from(["nan", "x", "1e999", "-0", "3.5.1"])), max_size=80))
        rows = [" ".join(str(v) for v in numbers[i:i + 4]) for i in range(0, len(numbers), 4)]
        return header + "\n".join(rows).encode()
    return header + draw(st.binary(max_size=400))


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


def load_only_input_errors(path: Path, data: bytes) -> None:
    path.write_bytes(data)
    try:
        load_mesh(path)
    except InputError as err:
        assert "\n" not in str(err) and "np." not in str(err)


@FUZZ
@given(data=mutated())
def test_mutated_ply_files_raise_only_input_errors(scratch, data):
    """Random edits of valid PLY files (any format) either load or raise a one-line InputError."""
    load_only_input_errors(scratch / "mutated.ply", data)


def off_seeds() -> list[bytes]:
    from test_mesh_off import off_text
    from test_mesh_ply import CUBE_QUADS, CUBE_VERTICES, TETRA_FACES, TETRA_VERTICES

    return [off_text(TETRA_VERTICES, TETRA_FACES).encode(),
            off_text(CUBE_VERTICES, CUBE_QUADS, header="COFF\n# comment\n", colours=True).encode()]


@FUZZ
@given(data=mutated(off_seeds()))
def test_mutated_off_files_raise_only_input_errors(scratch, data):
    """Random edits of valid OFF files either load or raise a one-line InputError."""
    load_only_input_errors(scratch / "mutated.off", data)


@FUZZ
@given(data=generated())
def test_generated_ply_headers_raise_only_input_errors(scratch, data):
    """Grammar-built headers with wrong types and huge counts, over random bodies: only InputError."""
    load_only_input_errors(scratch / "generated.ply", data)


@st.composite
def repeated_faces(draw) -> tuple[bytes, int, int]:
    """(a seed mesh whose faces are each repeated 1..4 times in a random order, in any format; distinct faces;
    all faces)."""
    from test_mesh_ply import TETRA_FACES, TETRA_VERTICES, ply_bytes

    copies = draw(st.lists(st.integers(1, 4), min_size=len(TETRA_FACES), max_size=len(TETRA_FACES)))
    faces = [face for face, k in zip(TETRA_FACES, copies) for _ in range(k)]
    faces = [faces[i] for i in draw(st.permutations(range(len(faces))))]
    rotate = draw(st.integers(0, 2))
    faces = [face[rotate:] + face[:rotate] for face in faces]  # a rotated copy is the same face
    fmt = draw(st.sampled_from(["ascii", "binary_little_endian", "binary_big_endian"]))
    return ply_bytes(fmt, TETRA_VERTICES, faces), len(TETRA_FACES), len(faces)


@FUZZ
@given(case=repeated_faces())
def test_repeated_faces_load_as_the_distinct_geometry(scratch, case):
    """Faces repeated any number of times, in any order and rotation, load as the distinct faces alone
    (the slicer's work then follows the distinct geometry), the drop reported in the warnings."""
    data, distinct, total = case
    path = scratch / "repeated.ply"
    path.write_bytes(data)
    mesh = load_mesh(path)
    assert len(mesh.faces) == distinct
    assert mesh.duplicate_faces == total - distinct
    assert (mesh.duplicate_faces > 0) == any("duplicate face" in note for note in mesh.warnings)


@st.composite
def flooded(draw) -> tuple[str, bytes]:
    """(suffix, an ASCII PLY or OFF seed with runs of blank, whitespace or comment lines inserted between lines)."""
    from test_mesh_off import off_text
    from test_mesh_ply import TETRA_FACES, TETRA_VERTICES, ply_bytes

    suffix = draw(st.sampled_from([".ply", ".off"]))
    seed = ply_bytes("ascii", TETRA_VERTICES, TETRA_FACES) if suffix == ".ply" else \
        off_text(TETRA_VERTICES, TETRA_FACES).encode()
    lines = seed.split(b"\n")
    body_from = lines.index(b"end_header") + 1 if suffix == ".ply" else 1
    filler = [b"", b"   ", b"\t", b"# note"] if suffix == ".off" else [b"", b"   ", b"\t"]
    for _ in range(draw(st.integers(1, 3))):
        at = draw(st.integers(body_from, len(lines)))
        run = draw(st.sampled_from([1, 10, 20_000, 300_000]))
        lines[at:at] = [draw(st.sampled_from(filler))] * run
    return suffix, b"\n".join(lines)


@FUZZ
@given(case=flooded())
def test_blank_and_comment_floods_load_or_are_refused_in_one_line(scratch, case):
    """Blank, whitespace and comment lines between rows load as the plain seed when few, and are a one-line
    InputError naming the flood when they outnumber the rows beyond the limit; nothing else."""
    suffix, data = case
    path = scratch / f"flooded{suffix}"
    path.write_bytes(data)
    try:
        mesh = load_mesh(path)
    except InputError as err:
        assert "\n" not in str(err) and "flood" in str(err)
        assert data.count(b"\n") > 10_000
        return
    assert len(mesh.faces) == 4


@FUZZ
@given(suffix=st.sampled_from([".ply", ".stl", ".off", ".obj"]), holes=st.sampled_from([1 << 12, 1 << 24, 1 << 26]),
       where=st.sampled_from(["end", "declared"]))
def test_sparse_files_are_refused_or_read_in_one_line(scratch, suffix, holes, where):
    """A valid file extended by a hole (at its end, or with the header's count made to match the hole):
    from 16 MiB of holes a one-line 'sparse' InputError before any read; a small hole loads or is one line."""
    from test_mesh_off import off_text
    from test_mesh_ply import TETRA_FACES, TETRA_VERTICES, ply_bytes

    path = scratch / f"sparse{suffix}"
    seed = {".ply": ply_bytes("binary_little_endian", TETRA_VERTICES, TETRA_FACES),
            ".off": off_text(TETRA_VERTICES, TETRA_FACES).encode(),
            ".obj": b"v 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 10\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
            ".stl": procedural.sphere(5.0, 1).export(file_type="stl")}[suffix]
    if where == "declared" and suffix == ".stl":
        seed = seed[:80] + np.uint32((len(seed) - 84 + holes) // 50).tobytes() + seed[84:]
        holes -= holes % 50
    elif where == "declared" and suffix == ".ply":
        seed = seed.replace(b"element face 4", b"element face %d" % (4 + holes // 13))
    path.write_bytes(seed)
    with open(path, "r+b") as handle:
        handle.truncate(len(seed) + holes)
    if holes >= 1 << 24 and path.stat().st_blocks * 512 >= holes:
        pytest.skip("this file system stores no holes")
    try:
        load_mesh(path)
    except InputError as err:
        assert "\n" not in str(err)
        assert holes < 1 << 24 or "sparse" in str(err)
    else:
        assert holes < 1 << 24


# --- manifests and layer files ----------------------------------------------------------------------


class Pristine(tuple):
    """(directory, manifest bytes, {layer file: bytes}) of the stack to damage; a short repr for failure reports."""

    def __repr__(self) -> str:
        return f"Pristine({self[0]})"


@pytest.fixture(scope="module")
def small_stack(tmp_path_factory) -> Pristine:
    """A five-layer stack (its directory, manifest bytes and the layer files' bytes) to damage and restore."""
    root = tmp_path_factory.mktemp("stack")
    model = root / "box.ply"
    procedural.box().export(model)
    directory = root / "stack"
    slice_to_stack(load_mesh(model), directory, SliceSpec(layer_height_mm=2.0, dpi=(50.0, 50.0), jobs=1))
    layers = {p.name: p.read_bytes() for p in directory.glob("layer_*.tif")}
    return Pristine((directory, (directory / MANIFEST).read_bytes(), layers))


def restore(stack) -> Path:
    directory, manifest, layers = stack
    (directory / MANIFEST).write_bytes(manifest)
    for name, data in layers.items():
        (directory / name).write_bytes(data)
    return directory


JSON = st.recursive(
    st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats(allow_nan=False) | st.text(max_size=20),
    lambda children: st.lists(children, max_size=5) | st.dictionaries(st.text(max_size=12), children, max_size=5),
    max_leaves=25,
)


def verify_never_raises(directory: Path) -> None:
    report = verify_stack(directory)
    assert all(isinstance(line, str) and "\n" not in line for line in report.problems)
    try:
        read_manifest(directory)
    except VerifyError as err:
        assert "\n" not in str(err)


@FUZZ
@given(data=st.binary(max_size=600))
def test_random_bytes_as_manifest(small_stack, data):
    """Arbitrary bytes as manifest.json: verify reports problems, read_manifest raises only VerifyError."""
    directory = restore(small_stack)
    (directory / MANIFEST).write_bytes(data)
    verify_never_raises(directory)


def paths_of(value, prefix=()):
    """Every (path) into a JSON value, for replacing one node."""
    yield prefix
    if isinstance(value, dict):
        for key, child in value.items():
            yield from paths_of(child, prefix + (key,))
    elif isinstance(value, list):
        for index, child in enumerate(value):
            yield from paths_of(child, prefix + (index,))


@FUZZ
@given(data=st.data())
def test_manifest_with_random_values_in_random_places(small_stack, data):
    """A valid manifest with some nodes replaced by random JSON: verify never raises, read_manifest raises
    only VerifyError."""
    directory = restore(small_stack)
    manifest = json.loads(small_stack[1])
    for _ in range(data.draw(st.integers(1, 3))):
        path = data.draw(st.sampled_from(list(paths_of(manifest))[1:]))
        node = manifest
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = data.draw(JSON)
    (directory / MANIFEST).write_text(json.dumps(manifest))
    verify_never_raises(directory)


@FUZZ
@given(data=st.data())
def test_damaged_layer_tiffs_with_matching_hashes(small_stack, data):
    """Random edits of a layer TIFF, with the manifest's sha256 updated so the TIFF reader itself is exercised:
    verify never raises, and when it finds nothing wrong the layer still decodes to the original mask."""
    directory = restore(small_stack)
    name = data.draw(st.sampled_from(sorted(small_stack[2])))
    original = small_stack[2][name]
    damaged = bytearray(original)
    for _ in range(data.draw(st.integers(1, 6))):
        at = data.draw(st.integers(0, len(damaged) - 1))
        if data.draw(st.booleans()):
            damaged[at] = data.draw(st.integers(0, 255))
        else:
            del damaged[at:at + data.draw(st.integers(1, 8))]
    (directory / name).write_bytes(bytes(damaged))
    manifest = json.loads(small_stack[1])
    entry = next(e for e in manifest["layers"] if e["file"] == name)
    entry["sha256"] = hashlib.sha256(bytes(damaged)).hexdigest()
    (directory / MANIFEST).write_text(json.dumps(manifest))
    verify_never_raises(directory)
    if verify_stack(directory).ok:
        index = entry["index"]
        damaged_mask = read_layer_mask(directory, manifest, index)
        restore(small_stack)
        np.testing.assert_array_equal(damaged_mask, read_layer_mask(directory, json.loads(small_stack[1]), index))


def test_fuzz_fixture_stack_is_clean(small_stack):
    """The stack the fuzzers damage verifies clean when restored (so reported problems come from the damage)."""
    assert verify_stack(restore(small_stack)).ok
    assert len(small_stack[2]) == 5 and layer_file_name(4) in small_stack[2]
