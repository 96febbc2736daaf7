"""Costs of heoslice's safety checks, each against a baseline measured in the same run.

    python benchmarks/bench_robustness.py
    python benchmarks/bench_robustness.py --quick

Prints:
- refusing a PLY header that declares 10**9 / 10**12 elements: wall time and peak RSS of
  ``heoslice info`` in a subprocess, against ``heoslice --version`` (start-up only)
  (issue 7 target: under 1 s and 100 MB);
- the hostile mesh inputs of issue 22 (sparse PLY and STL whose size agrees with the
  header, repeated faces, blank-line and comment floods, FIFO, /dev/zero, symlink loop,
  OBJ index 0, --scale 1e308; previews of small files declaring 32768^2 1-bit and 16384^2
  RGBA layers, absurd sheets, FIFO layers; --materials /dev/zero and FIFO; --canvas, --margin,
  --offsets, --nozzle, --depth and verify --scale beyond range; 100,000 layers; a manifest
  without z_range_mm), each through the command line, and the worst wall time and peak RSS
  over them;
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
    """(wall seconds, peak RSS KiB, exit code) of ``python -m heoslice ARGS`` in a fresh child process
    (killed after 300 s: exit -9)."""
    probe = ("import resource, subprocess, sys, time; t = time.perf_counter(); "
             "r = subprocess.run([sys.executable, '-m', 'heoslice'] + sys.argv[1:], capture_output=True, "
             "stdin=subprocess.DEVNULL, timeout=300); "
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


def fake_stack(directory: Path, width: int, height: int, mode: str = "1", layers: int = 1) -> Path:
    """A complete stack of blank deflate layers of ``width`` x ``height`` px, written without holding a
    layer's pixels (the strips are compressed from one repeated row): a small file declaring a huge layer."""
    import hashlib
    import io
    import json
    import zlib

    import numpy as np
    import tifffile

    from heoslice.stack import encode_bilevel_tiff

    directory.mkdir()
    entries = []
    for index in range(layers):
        if mode == "1":
            rows = np.broadcast_to(np.zeros((1, -(-width // 8)), np.uint8), (height, -(-width // 8)))
            data = encode_bilevel_tiff(rows, width, (600.0, 600.0), "deflate")
        else:
            buffer = io.BytesIO()
            strips = (zlib.compress(bytes(min(64, height - row) * width * 4), 1) for row in range(0, height, 64))
            tifffile.imwrite(buffer, data=strips, shape=(height, width, 4), dtype=np.uint8, photometric="rgb",
                             extrasamples=["unassalpha"], compression="adobe_deflate", rowsperstrip=64,
                             resolution=(600.0, 600.0), resolutionunit="INCH")
            data = buffer.getvalue()
        name = f"layer_{index:05d}.tif"
        (directory / name).write_bytes(data)
        entries.append({"index": index, "z_mm": 0.05 + 0.1 * index, "file": name,
                        "sha256": hashlib.sha256(data).hexdigest(), "solid_pixels": 0, "open_contours": False})
    manifest = {"format": "heoslice-stack", "version": 1, "complete": True, "created_by": "bench",
                "source": {"file": "x.ply", "sha256": "0" * 64}, "layer_height_mm": 0.1, "dpi": [600.0, 600.0],
                "pixel_size_mm": [25.4 / 600.0, 25.4 / 600.0],
                "image": {"width": width, "height": height, "origin_mm": [0.0, 0.0], "mode": mode,
                          "compression": "deflate"},
                "mask": "nonzero" if mode == "1" else "alpha", "z_range_mm": [0.0, 0.1 * layers], "layers": entries}
    (directory / "manifest.json").write_text(json.dumps(manifest))
    return directory


def option_cases(work: Path) -> list[tuple[str, list[str]]]:
    """(name, heoslice arguments) of issue 22's hostile previews, special files and absurd option values."""
    import json
    import shutil as shell

    from heoslice import procedural

    box = work / "box.ply"
    procedural.box((5.0, 5.0, 2.0)).export(box)
    pillar = work / "pillar.ply"
    procedural.box((1.0, 1.0, 100.0)).export(pillar)
    bilevel = fake_stack(work / "bilevel_32768", 32768, 32768)
    rgba = fake_stack(work / "rgba_16384", 16384, 16384, mode="RGBA")
    small = fake_stack(work / "small", 64, 64, layers=3)
    fifo_stack = fake_stack(work / "fifo_stack", 64, 64, layers=2)
    (fifo_stack / "layer_00001.tif").unlink()
    os.mkfifo(fifo_stack / "layer_00001.tif")
    materials_fifo = work / "materials.toml"
    os.mkfifo(materials_fifo)
    shell.copytree(small, work / "cut_short")
    manifest = work / "cut_short" / "manifest.json"
    fields = json.loads(manifest.read_text())
    del fields["z_range_mm"]
    manifest.write_text(json.dumps(fields))
    graded = ["slice", str(box), "-o", str(work / "graded"), "--grade", "linear", "--layer", "0.5", "--dpi", "100"]
    plain = ["slice", str(box), "-o", str(work / "plain"), "--layer", "0.5", "--dpi", "100"]
    return [("preview 32768^2 1-bit layer (1.3 MB)", ["preview", str(bilevel), "-o", str(work / "a.png")]),
            ("preview 16384^2 RGBA layer (4.7 MB)", ["preview", str(rgba), "-o", str(work / "b.png")]),
            ("preview --sheet --layers x20000", ["preview", str(small), "--sheet", "--layers",
                                                  ",".join(["0"] * 20000), "-o", str(work / "c.png")]),
            ("preview --tile 1e6", ["preview", str(small), "--sheet", "--tile", "1000000", "-o", str(work / "d.png")]),
            ("preview --columns 1e9", ["preview", str(small), "--sheet", "--columns", "1000000000",
                                       "-o", str(work / "e.png")]),
            ("preview of a FIFO layer", ["preview", str(fifo_stack), "--layer", "1", "-o", str(work / "f.png")]),
            ("--materials /dev/zero", graded + ["--materials", "/dev/zero"]),
            ("--materials FIFO", graded + ["--materials", str(materials_fifo)]),
            ("--canvas 1e308x1e308", plain + ["--canvas", "1e308x1e308"]),
            ("--margin 1e308", plain + ["--margin", "1e308"]),
            ("--offsets 1e9", graded + ["--offsets", "1000000000"]),
            ("--nozzle 1e-9", graded + ["--nozzle", "1e-9"]),
            ("--depth 1e9", graded + ["--depth", "1e9"]),
            ("verify --scale 1e308", ["verify", str(small), "--mesh", str(box), "--scale", "1e308"]),
            ("--layer 0.001 on a 100 mm pillar", ["slice", str(pillar), "-o", str(work / "thin"), "--layer", "0.001",
                                                 "--dpi", "50"]),
            ("verify without z_range_mm", ["verify", str(work / "cut_short")])]


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
    for name, command in hostile_cases(work) + option_cases(work):
        seconds, rss, code = run_measured(command)
        worst_s, worst_rss = max(worst_s, seconds), max(worst_rss, rss)
        print(f"{name:36s} exit {code}, {seconds:.2f} s, {rss / 1024:.0f} MB")
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
