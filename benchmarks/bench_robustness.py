"""Costs of heoslice's safety checks, each against a baseline measured in the same run.

    python benchmarks/bench_robustness.py
    python benchmarks/bench_robustness.py --quick

Prints:
- refusing a PLY header that declares 10**9 / 10**12 elements: wall time and peak RSS of
  ``heoslice info`` in a subprocess, against ``heoslice --version`` (start-up only)
  (issue 7 target: under 1 s and 100 MB);
- the hostile mesh inputs of issue 22 (sparse PLY and STL whose size agrees with the
  header, repeated faces, blank-line and comment floods, FIFO, /dev/zero, symlink loop,
  OBJ index 0, --scale 1e308), each through the command line, and the worst wall time
  and peak RSS over them;
- the strict PLY reader (``heoslice.mesh.read_ply``) against trimesh's PLY reader on the same
  binary and ASCII files (ratio = heoslice / trimesh);
- ``verify_stack`` (hash, header checks and a full strip-by-strip decode of every
  layer) against writing the same stack with ``slice_to_stack``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from timing import best_of

HOSTILE = (b"ply\nformat binary_little_endian 1.0\nelement vertex %d\nproperty float x\nproperty float y\n"
           b"property float z\nelement face %d\nproperty list uchar int vertex_indices\nend_header\n")


def run_measured(args: list[str]) -> tuple[float, int, int]:
    """(wall seconds, peak RSS KiB, exit code) of ``python -m heoslice ARGS`` in a fresh child process."""
    probe = ("import resource, subprocess, sys, time; t = time.perf_counter(); "
             "r = subprocess.run([sys.executable, '-m', 'heoslice'] + sys.argv[1:], capture_output=True); "
             "print(time.perf_counter() - t, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, r.returncode)")
    out = subprocess.run([sys.executable, "-c", probe, *args], capture_output=True, text=True, check=True).stdout
    seconds, rss, code = out.split()
    return float(seconds), int(rss), int(code)


def _sparse(path: Path, head: bytes, size: int) -> Path:
    """``head`` then a hole up to ``size`` bytes."""
    path.write_bytes(head)
    with open(path, "r+b") as handle:
        handle.truncate(size)
    return path


def hostile_cases(work: Path) -> list[tuple[str, list[str]]]:
    """(name, heoslice arguments) of each hostile mesh input of issue 22, its files written into ``work``."""
    import numpy as np

    tetra = np.array([[0, 0, 0], [30, 0, 0], [0, 30, 0], [0, 0, 30]], dtype="<f4")
    faces = np.tile(np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype="<i4"), (250_000, 1))
    rows = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    rows["n"], rows["v"] = 3, faces
    repeated = work / "repeated.ply"
    repeated.write_bytes(HOSTILE % (4, len(faces)) + tetra.tobytes() + rows.tobytes())
    ascii_tetra = (b"ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                   b"element face 4\nproperty list uchar int vertex_indices\nend_header\n"
                   b"0 0 0\n30 0 0\n0 30 0\n0 0 30\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n")
    (work / "blank.ply").write_bytes(ascii_tetra + b"\n" * 100_000_000)
    (work / "comments.off").write_bytes(b"OFF\n4 4 0\n0 0 0\n30 0 0\n0 30 0\n0 0 30\n3 0 2 1\n3 0 1 3\n3 0 3 2\n"
                                        b"3 1 2 3\n" + b"# a comment line\n" * 6_250_000)
    stl_head = b"binary".ljust(80, b" ") + np.uint32(2**28).tobytes()
    _sparse(work / "sparse.stl", stl_head, 84 + 50 * 2**28)
    _sparse(work / "sparse.ply", HOSTILE % (10**9, 0), len(HOSTILE % (10**9, 0)) + 12 * 10**9)
    _sparse(work / "sparse_small.ply", HOSTILE % (3 * 10**7, 0), len(HOSTILE % (3 * 10**7, 0)) + 36 * 10**7)
    fifo = work / "pipe.ply"
    if not fifo.exists():
        os.mkfifo(fifo)
    loop = work / "loop.ply"
    if not loop.is_symlink():
        loop.symlink_to(work / "loop2.ply")
        (work / "loop2.ply").symlink_to(loop)
    (work / "zero.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 0 1 2\n")
    return [("repeated faces: info", ["info", str(repeated)]),
            ("repeated faces: slice at defaults", ["slice", str(repeated), "-o", str(work / "repeated_stack"),
                                                   "--force"]),
            ("100 MB of blank lines (PLY)", ["info", str(work / "blank.ply")]),
            ("100 MB of comments (OFF)", ["info", str(work / "comments.off")]),
            ("13 GB sparse STL, 2^28 triangles", ["info", str(work / "sparse.stl")]),
            ("12 GB sparse PLY, 1e9 vertices", ["info", str(work / "sparse.ply")]),
            ("360 MB sparse PLY, 3e7 vertices", ["info", str(work / "sparse_small.ply")]),
            ("FIFO", ["info", str(fifo)]), ("/dev/zero", ["info", "/dev/zero"]),
            ("symlink loop", ["info", str(loop)]), ("OBJ face index 0", ["info", str(work / "zero.obj")]),
            ("--scale 1e308", ["slice", str(repeated), "-o", str(work / "scaled"), "--scale", "1e308"])]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="smaller meshes and stack")
    args = parser.parse_args()
    import trimesh

    from heoslice import procedural
    from heoslice.mesh import load_mesh, read_ply
    from heoslice.pipeline import SliceSpec, slice_to_stack
    from heoslice.stack import verify_stack

    work = Path(tempfile.mkdtemp(prefix="heoslice-bench-"))
    print("== hostile PLY headers (subprocess, wall time and peak RSS)")
    base_s, base_rss, _ = run_measured(["--version"])
    print(f"baseline `heoslice --version`: {base_s:.2f} s, {base_rss / 1024:.0f} MB")
    for count in (10**9, 10**12):
        path = work / f"hostile_{count}.ply"
        path.write_bytes(HOSTILE % (count, count) + bytes(64))
        seconds, rss, code = run_measured(["info", str(path)])
        print(f"{count:.0e} elements: exit {code}, {seconds:.2f} s ({seconds / base_s:.2f}x start-up), "
              f"{rss / 1024:.0f} MB ({rss / base_rss:.2f}x start-up)")

    print("== hostile mesh inputs (subprocess, wall time and peak RSS)")
    worst_s, worst_rss = 0.0, 0
    for name, command in hostile_cases(work):
        seconds, rss, code = run_measured(command)
        worst_s, worst_rss = max(worst_s, seconds), max(worst_rss, rss)
        print(f"{name:34s} exit {code}, {seconds:.2f} s, {rss / 1024:.0f} MB")
    print(f"worst over the hostile inputs: {worst_s:.2f} s, {worst_rss / 1024:.0f} MB")

    print("== PLY reading: heoslice read_ply / trimesh (best of 3)")
    count = (128, 128) if args.quick else (512, 512)
    mesh = procedural.uv_sphere(count=count)
    for encoding in ("binary", "ascii"):
        path = work / f"sphere_{encoding}.ply"
        path.write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding=encoding))
        ours, _ = best_of(3, read_ply, path)
        theirs, _ = best_of(3, lambda p: trimesh.load(p, force="mesh", process=False), path)
        print(f"{encoding:6s} {len(mesh.faces)} faces: heoslice {ours:.3f} s, trimesh {theirs:.3f} s, "
              f"ratio {ours / theirs:.2f}")

    print("== verify_stack / slice_to_stack (same stack)")
    model = work / "vase.ply"
    procedural.vase().export(model)
    spec = SliceSpec(layer_height_mm=0.5 if args.quick else 0.1, dpi=(300.0, 300.0) if args.quick else (600.0, 600.0))
    started = time.perf_counter()
    manifest, _ = slice_to_stack(load_mesh(model), work / "stack", spec)
    sliced = time.perf_counter() - started
    started = time.perf_counter()
    report = verify_stack(work / "stack")
    verified = time.perf_counter() - started
    print(f"{len(manifest['layers'])} layers of {manifest['image']['width']} x {manifest['image']['height']} px: "
          f"slice {sliced:.2f} s (all cores), verify {verified:.2f} s (one core), ratio {verified / sliced:.2f}, "
          f"{'clean' if report.ok else report.problems[:1]}")
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
