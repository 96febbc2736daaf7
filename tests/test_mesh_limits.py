"""The resource model through the command line: hostile mesh inputs end in one line, in bounded time and memory.

Every file is generated here (sparse files by truncate, floods written out). Each case
runs ``python -m heoslice`` in a child process whose wall time and peak RSS (its
resource usage, reported by a small parent interpreter) are asserted, under an address-space limit so that a
regression fails instead of exhausting the machine.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_mesh_off import off_text
from test_mesh_ply import TETRA_FACES, TETRA_VERTICES, ply_bytes

from heoslice.errors import EXIT_INPUT, InputError
from heoslice.mesh import load_mesh

ADDRESS_LIMIT = 3 << 30  # bytes of address space a child may map


#: Run in a fresh small interpreter: starts heoslice under the address-space limit and reports its exit code,
#: output, wall time and peak RSS. (A child forked from the test process would inherit the test process's
#: RSS into its ru_maxrss, which exec does not reset.)
PROBE = """
import json, resource, subprocess, sys, time
limit, timeout = int(sys.argv[1]), float(sys.argv[2])
def cap():
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
started = time.perf_counter()
try:
    done = subprocess.run([sys.executable, "-m", "heoslice", *sys.argv[3:]], capture_output=True, text=True,
                          preexec_fn=cap, timeout=timeout, env={**__import__("os").environ, "OPENBLAS_NUM_THREADS": "1"})
    code, out, err = done.returncode, done.stdout, done.stderr
except subprocess.TimeoutExpired:
    code, out, err = -9, "", "timed out"
print(json.dumps([code, out, err, time.perf_counter() - started,
                  resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024]))
"""


def run_bounded(*args, timeout: float = 120.0) -> tuple[int, str, str, float, float]:
    """(exit code, stdout, stderr, wall seconds, peak RSS MiB) of ``python -m heoslice ARGS`` in a child."""
    probe = subprocess.run([sys.executable, "-c", PROBE, str(ADDRESS_LIMIT), str(timeout), *map(str, args)],
                           capture_output=True, text=True, check=True, timeout=timeout + 30)
    code, out, err, seconds, rss = json.loads(probe.stdout)
    return code, out, err, seconds, rss


def assert_one_line_refusal(result, *needles: str, seconds: float = 30.0, rss_mib: float = 400.0) -> None:
    """Exit 2, one stderr line 'heoslice: error: ...' holding every needle, within the time and memory bounds.

    The time bound is wide (start-up alone can take seconds on a loaded machine); an unbounded
    read or loop of these inputs takes minutes, the memory bound is the sharper check.
    """
    code, _, err, took, rss = result
    assert code == EXIT_INPUT, err
    assert err.count("\n") == 1 and err.startswith("heoslice: error: "), err
    assert all(needle in err for needle in needles), err
    assert took < seconds and rss < rss_mib, (took, rss)


def sparse(path: Path, head: bytes, size: int) -> Path:
    """``head`` followed by a hole up to ``size`` bytes (skips where the file system stores holes as data)."""
    path.write_bytes(head)
    with open(path, "r+b") as handle:
        handle.truncate(size)
    if path.stat().st_blocks * 512 > size // 2:
        pytest.skip("this file system stores no holes")
    return path


HEADER = (b"ply\nformat binary_little_endian 1.0\nelement vertex %d\nproperty float x\nproperty float y\n"
          b"property float z\nelement face %d\nproperty list uchar int vertex_indices\nend_header\n")


@pytest.mark.parametrize("vertices, needle", [(10**9, "larger than"), (10**8, "sparse")])
def test_sparse_ply_whose_size_agrees_with_its_header(tmp_path, vertices, needle):
    """Sparse PLYs whose size matches their declared vertices (12 GB for 10**9, 1.2 GB, 360 MB) are refused
    from the file's size, the vertex limit or the holes, before the body is read."""
    head = HEADER % (vertices, 0)
    path = sparse(tmp_path / "sparse.ply", head, len(head) + 12 * vertices)
    assert_one_line_refusal(run_bounded("info", path), needle)


def test_sparse_binary_stl_of_2_to_the_28_triangles(tmp_path):
    """A 13 GB sparse binary STL of 2**28 triangles, and a 800 MB one within the triangle limit, are refused
    before any body is read."""
    for count, needle in ((2**28, "larger than"), (2**24, "sparse")):
        head = b"binary".ljust(80, b" ") + np.uint32(count).tobytes()
        path = sparse(tmp_path / f"sparse{count}.stl", head, 84 + 50 * count)
        assert_one_line_refusal(run_bounded("info", path), needle)


def test_repeated_faces_are_sliced_once(tmp_path):
    """A 13 MB PLY of one tetrahedron's four faces repeated 250,000 times: info reports 999,996 duplicates and
    the slice at default settings takes the time and memory of the one tetrahedron."""
    faces = np.tile(np.array(TETRA_FACES, dtype="<i4"), (250_000, 1))
    rows = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    rows["n"], rows["v"] = 3, faces
    vertices = (TETRA_VERTICES * 3.0).astype("<f4")  # a 30 mm tetrahedron
    path = tmp_path / "repeated.ply"
    path.write_bytes(HEADER % (4, len(faces)) + vertices.tobytes() + rows.tobytes())
    assert path.stat().st_size > 12_000_000
    code, out, err, took, rss = run_bounded("info", path, "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["duplicate_faces"] == 999_996 and summary["triangles"] == 4
    assert summary["volume_mm3"] == pytest.approx(30.0 ** 3 / 6)
    code, out, err, took, rss = run_bounded("slice", path, "-o", tmp_path / "stack")
    assert code == 0, err
    assert took < 60 and rss < 600, (took, rss)


@pytest.mark.parametrize("case", ["ply-blank-lines", "off-comments"])
def test_blank_line_and_comment_floods(tmp_path, case):
    """A tetrahedron followed by 100 MB of blank lines (ASCII PLY) or of '#' comment lines (OFF) is refused in
    one line, in about the memory of the file itself (no arrays per byte)."""
    if case == "ply-blank-lines":
        path = tmp_path / "flood.ply"
        path.write_bytes(ply_bytes("ascii", TETRA_VERTICES, TETRA_FACES) + b"\n" * 100_000_000)
        bound = 150.0  # refused from the file's size: nothing of the body is read (start-up is about 80 MiB)
    else:
        path = tmp_path / "flood.off"
        path.write_bytes(off_text(TETRA_VERTICES, TETRA_FACES).encode() + b"# a comment line\n" * 6_250_000)
        bound = 250.0  # the file (106 MB) is read once to find its counts
    assert_one_line_refusal(run_bounded("info", path), "flood", rss_mib=bound)


def test_special_files_are_refused_in_one_line(tmp_path):
    """A FIFO, /dev/zero and a symlink loop given as the mesh: one line each saying what the file is, at once."""
    fifo = tmp_path / "pipe.ply"
    os.mkfifo(fifo)
    assert_one_line_refusal(run_bounded("info", fifo, timeout=20), "FIFO")
    assert_one_line_refusal(run_bounded("info", "/dev/zero"), "character device")
    (tmp_path / "a.ply").symlink_to(tmp_path / "b.ply")
    (tmp_path / "b.ply").symlink_to(tmp_path / "a.ply")
    assert_one_line_refusal(run_bounded("info", tmp_path / "a.ply"), "symlink loop")


def test_obj_face_index_zero_is_refused(tmp_path):
    """OBJ counts vertices from 1: a face naming vertex 0 (or texture index 0) is one line giving the line."""
    good = "v 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 10\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
    path = tmp_path / "good.obj"
    path.write_text(good)
    code, _, err, _, _ = run_bounded("info", path)
    assert code == 0, err
    for bad, line in ((good.replace("f 1 4 3", "f 0 4 3"), 7), (good.replace("f 2 3 4", "f 2/0 3/1 4/1"), 8)):
        path.write_text(bad)
        assert_one_line_refusal(run_bounded("info", path), f"line {line}: OBJ face index 0")


def test_absurd_scale_is_a_one_line_error(tmp_path):
    """`verify --scale 1e308` and `slice --scale 1e308` are one-line errors (exit 2) before any arithmetic,
    with no RuntimeWarning lines."""
    path = tmp_path / "tetra.ply"
    path.write_bytes(ply_bytes("binary_little_endian", TETRA_VERTICES, TETRA_FACES))
    assert_one_line_refusal(run_bounded("slice", path, "-o", tmp_path / "stack", "--scale", "1e308"), "scale")
    code, _, err, _, _ = run_bounded("slice", path, "-o", tmp_path / "stack", "--dpi", "50", "--layer", "2")
    assert code == 0, err
    assert_one_line_refusal(run_bounded("verify", tmp_path / "stack", "--mesh", path, "--scale", "1e308"), "scale")
    assert_one_line_refusal(run_bounded("slice", path, "-o", tmp_path / "s2", "--scale", "1e-320"), "scale")


@pytest.mark.parametrize("limit, value, suffix, needle", [
    ("MAX_VERTICES", 3, ".ply", "declares 4 vertices"), ("MAX_TRIANGLES", 3, ".ply", "declares 4 'face' rows"),
    ("MAX_VERTICES", 3, ".off", "declares 4 vertices"), ("MAX_TRIANGLES", 3, ".off", "declares 4 faces"),
    ("MAX_TRIANGLES", 3, ".stl", "declares 4 triangles"), ("MAX_TRIANGLES", 11, "quads.ply", "make 12 triangles"),
])
def test_counts_beyond_the_limits_are_refused(tmp_path, monkeypatch, limit, value, suffix, needle):
    """Declared vertices, faces, STL triangles and the triangles polygons make are checked against the limits
    (lowered here so that a small file reaches them) before their arrays are made."""
    import trimesh
    from test_mesh_ply import CUBE_QUADS, CUBE_VERTICES

    from heoslice.mesh import off, ply, raw, stl

    for module in (ply, off, stl, raw):
        if hasattr(module, limit):
            monkeypatch.setattr(module, limit, value)
    path = tmp_path / f"m{suffix}"
    if suffix == ".ply":
        path.write_bytes(ply_bytes("binary_little_endian", TETRA_VERTICES, TETRA_FACES))
    elif suffix == "quads.ply":
        path.write_bytes(ply_bytes("ascii", CUBE_VERTICES, CUBE_QUADS))
    elif suffix == ".off":
        path.write_text(off_text(TETRA_VERTICES, TETRA_FACES))
    else:
        path.write_bytes(trimesh.Trimesh(TETRA_VERTICES, TETRA_FACES).export(file_type="stl"))
    with pytest.raises(InputError, match=needle):
        load_mesh(path)


@pytest.mark.parametrize("declared", [13, 11, 0])
def test_binary_stl_with_a_wrong_count_is_one_line(tmp_path, declared):
    """A binary STL whose triangle count disagrees with its size is refused in one line naming both (not
    handed to a text decoder: no "No module named 'charset_normalizer'")."""
    import trimesh

    data = bytearray(trimesh.creation.box((10.0, 10.0, 10.0)).export(file_type="stl"))
    data[80:84] = np.uint32(declared).tobytes()
    path = tmp_path / "wrong.stl"
    path.write_bytes(bytes(data))
    assert_one_line_refusal(run_bounded("info", path), f"declares {declared} triangles", "holds 684 bytes")
