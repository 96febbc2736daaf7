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
  without z_range_mm) and of issue 47 (export/preview/print --log over the stack, a device
  node or a link; nested, bomb, encrypted, bzip2 and absurd-index 3MF; a 3MF flood of vertex
  elements; non-finite fractions; a deeply nested defaults file; non-ASCII --expr; info of
  100,000 shells apart and piled; print --dry-run of 50,000 layers; a print of 20 layers at byte errors
  1e-2 without SACK, and one to a controller that dies), each through the command
  line, and the worst wall time and peak RSS over them;
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
             "p = subprocess.Popen([sys.executable, '-m', 'heoslice'] + sys.argv[1:], stdout=subprocess.DEVNULL, "
             "stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL)\n"
             "try:\n    code = p.wait(timeout=300)\n"
             "except subprocess.TimeoutExpired:\n    p.kill(); p.wait(); code = -9\n"
             "print(time.perf_counter() - t, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, code)")
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


def issue47_cases(work: Path, quick: bool) -> list[tuple[str, list[str]]]:
    """(name, heoslice arguments) of issue 47's cases: outputs that must not destroy (the stack, a device node or
    a link's target as -o), hostile 3MF archives, non-finite fractions, deep TOML, non-ASCII --expr, info of
    100,000 shells, the dry run of a 50,000-layer stack (5,000 with --quick), and prints of a 20-layer stack over a
    link corrupting 1 byte in 100 without SACK and to a controller that dies mid-job (exit 11)."""
    import json
    import stat
    import zipfile

    import numpy as np
    import trimesh

    from heoslice import procedural
    from heoslice.mesh import load_mesh
    from heoslice.pipeline import SliceSpec, slice_to_stack
    from heoslice.stack import write_manifest

    box = work / "box47.ply"
    procedural.box((5.0, 5.0, 2.0)).export(box)
    stack = work / "stack47"
    slice_to_stack(load_mesh(box), stack, SliceSpec(layer_height_mm=0.5, dpi=(100.0, 100.0)))
    plate = work / "plate47.ply"
    procedural.box((20.0, 20.0, 2.0)).export(plate)
    plates = work / "plates47"
    slice_to_stack(load_mesh(plate), plates, SliceSpec(layer_height_mm=0.1, dpi=(300.0, 300.0)))
    node = work / "node47"
    if os.geteuid() == 0:
        os.mknod(node, 0o666 | stat.S_IFCHR, os.stat("/dev/null").st_rdev)
    else:
        os.mkfifo(node)
    target = work / "target47.txt"
    target.write_text("not heoslice's\n")
    (work / "link47.png").symlink_to(target)
    (work / "link47.jsonl").symlink_to(target)

    ns = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
    tetra = ('<object id="1" type="model"><mesh><vertices><vertex x="0" y="0" z="0"/><vertex x="1" y="0" z="0"/>'
             '<vertex x="0" y="1" z="0"/><vertex x="0" y="0" z="1"/></vertices><triangles>'
             '<triangle v1="0" v2="2" v3="1"/><triangle v1="0" v2="1" v3="3"/><triangle v1="0" v2="3" v3="2"/>'
             '<triangle v1="1" v2="2" v3="3"/></triangles></mesh></object>')

    def model(resources: str, build: str) -> str:
        return (f'<?xml version="1.0" encoding="UTF-8"?><model unit="millimeter" xmlns="{ns}"><resources>{resources}'
                f"</resources><build>{build}</build></model>")

    def archive(name: str, members: dict, method=zipfile.ZIP_DEFLATED) -> Path:
        with zipfile.ZipFile(work / name, "w", method) as out:
            for member, data in members.items():
                out.writestr(member, data)
        return work / name

    nested = [tetra] + [f'<object id="{k + 1}"><components>' + f'<component objectid="{k}"/>' * 4
                        + "</components></object>" for k in range(1, 16)]
    flood = "".join(f'<vertex x="{k}" y="{k % 7}" z="{k % 11}"/>' for k in range(300_000 if quick else 3_000_000))
    fan = "".join(f'<triangle v1="0" v2="{k}" v3="{k + 1}"/>' for k in range(1, 1000))
    plain = model(tetra, '<item objectid="1"/>')
    encrypted = archive("encrypted47.3mf", {"3D/3dmodel.model": plain})
    data = bytearray(encrypted.read_bytes())
    for signature, field in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):
        data[data.find(signature) + field] |= 1
    encrypted.write_bytes(bytes(data))
    nan_ply = work / "nan47.ply"
    nan_ply.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                       "property float z\nproperty float material\nelement face 4\n"
                       "property list uchar int vertex_indices\nend_header\n0 0 0 0.5\n10 0 0 nan\n0 10 0 0.5\n"
                       "0 0 10 0.5\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n")
    deep = work / "deep47.toml"
    deep.write_text("a = " + "[" * 5000 + "]" * 5000 + "\n")

    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    tet_faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    for name, centres in (("apart", 2.0 * np.stack(np.meshgrid(*map(np.arange, (50, 50, 40)), indexing="ij"),
                                                    -1).reshape(-1, 3)),
                          ("piled", np.random.default_rng(1).random((100_000, 3)) * 0.5)):
        trimesh.Trimesh((centres[:, None] + corners[None]).reshape(-1, 3),
                        (tet_faces[None] + 4 * np.arange(len(centres))[:, None, None]).reshape(-1, 3),
                        process=False).export(work / f"{name}47.ply")

    layers = 5_000 if quick else 50_000
    tall = work / "tall47"
    manifest, _ = slice_to_stack(load_mesh(_tiny(work)), tall, SliceSpec(layer_height_mm=0.001, dpi=(50.0, 50.0)))
    first = manifest["layers"][0]
    entries = []
    for index in range(layers):
        name = f"layer_{index:05d}.tif"
        if index >= len(manifest["layers"]):
            os.link(tall / first["file"], tall / name)
        entries.append({**first, "index": index, "file": name, "z_mm": 0.0005 + 0.001 * index})
    write_manifest(tall, {**manifest, "layers": entries, "z_range_mm": [0.0, 0.001 * layers]})
    return [("export -o STACK --force", ["export", str(stack), "--format", "png", "-o", str(stack), "--force"]),
            ("export -o a device node --force", ["export", str(stack), "--format", "png", "-o", str(node), "--force"]),
            ("preview -o a symlink", ["preview", str(stack), "-o", str(work / "link47.png")]),
            ("print --log a symlink", ["print", str(stack), "--port", "sim://", "--log", str(work / "link47.jsonl")]),
            ("3MF 4^15 nested placements", ["info", str(archive("nested47.3mf", {"3D/3dmodel.model": model(
                "".join(nested), '<item objectid="16"/>')}))]),
            (f"3MF {len(flood) >> 20} MB of vertex elements", ["info", str(archive("flood47.3mf", {
                "3D/3dmodel.model": model(f'<object id="1"><mesh><vertices>{flood}</vertices><triangles>{fan}'
                                          "</triangles></mesh></object>", '<item objectid="1"/>')}))]),
            ("3MF 64 MB zip bomb in _rels/.rels", ["info", str(archive("bomb47.3mf", {
                "_rels/.rels": b" " * (64 << 20), "3D/3dmodel.model": plain}))]),
            ("3MF encrypted member", ["info", str(encrypted)]),
            ("3MF bzip2 member", ["info", str(archive("bzip47.3mf", {"3D/3dmodel.model": plain}, zipfile.ZIP_BZIP2))]),
            ("3MF index 1e30", ["info", str(archive("index47.3mf", {"3D/3dmodel.model": plain.replace(
                'v3="1"', 'v3="1e30"')}))]),
            ("color --periods 1e308", ["color", str(box), "--func", "sine", "--periods", "1e308",
                                       "-o", str(work / "sine47.ply")]),
            ("PLY material nan", ["slice", str(nan_ply), "-o", str(work / "nan47_stack")]),
            ("defaults file nested 5000 deep", ["--config", str(deep), "info", str(box)]),
            ("--expr with a fullwidth r", ["color", str(box), "--expr", "\uff52", "-o", str(work / "expr47.ply")]),
            ("info: 100,000 separate shells", ["info", str(work / "apart47.ply")]),
            ("info: 100,000 piled shells", ["info", str(work / "piled47.ply")]),
            (f"print --dry-run of {layers} layers", ["print", str(tall), "--dry-run"]),
            ("print at byte errors 1e-2, no SACK", ["print", str(plates), "--port",
                                                    "sim://?byte_error_rate=0.01&features=0",
                                                    "--log", str(work / "noisy47.jsonl")]),
            ("print to a controller that dies", ["print", str(plates), "--port", "sim://?dead_at_layer=5",
                                                 "--log", str(work / "dead47.jsonl")])]


def _tiny(work: Path) -> Path:
    """A 2 x 2 x 0.002 mm box: two layers at 0.001 mm, the seed of a many-layer stack."""
    from heoslice import procedural

    path = work / "tiny47.ply"
    procedural.box((2.0, 2.0, 0.002)).export(path)
    return path


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
    for name, command in hostile_cases(work) + option_cases(work) + issue47_cases(work, args.quick):
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
