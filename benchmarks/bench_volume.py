"""The volume route against the mesh route a user takes today, on the shared 41-label TotalSegmentator map.

    python benchmarks/bench_volume.py                          # 0.1 mm layers, 600 dpi (the issue's settings)
    python benchmarks/bench_volume.py --layer 0.5 --dpi 300    # a shorter run
    python benchmarks/bench_volume.py --repeats 2 --jobs 1    # both routes in one process

Volume route: ``heoslice slice example_seg.nii.gz`` (every label, one material). Mesh route: scikit-image's
marching cubes of each label (level 0.5 of its 0/1 mask, in RAS mm by the file's affine), each written as a
PLY, then ``heoslice slice *.ply --parts`` (one multi-part stack, every part one material): meshing time
included. Both slices run on ``--jobs`` worker processes (default 0: one per core). Each route runs as its own
process, alternating, ``--repeats`` times; reported: each route's best wall time, CPU time (user + system of
the route and its workers: steadier than wall time on a shared machine) and peak RSS (ru_maxrss from wait4: the
largest of the route's processes), their ratios (mesh / volume) and the load average.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("HEOSLICE_SHARED_DATA", ROOT.parent / "shared" / "data")) / "imaging" / "example_seg.nii.gz"

MESH_ROUTE = r'''
import sys, numpy as np, nibabel as nib
from pathlib import Path
from skimage.measure import marching_cubes
from heoslice.cli import main
seg, out, layer, dpi, jobs = sys.argv[1], Path(sys.argv[2]), sys.argv[3], sys.argv[4], sys.argv[5]
image = nib.load(seg)
data, affine = np.asarray(image.dataobj), image.affine
files = []
for value in np.unique(data[data > 0]):
    mask = np.pad(data == value, 1).astype(np.float32)
    verts, faces, _, _ = marching_cubes(mask, 0.5)
    verts = (verts - 1.0) @ affine[:3, :3].T + affine[:3, 3]
    path = out / f"label_{int(value):03d}.ply"
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(verts)}\nproperty float x\n"
              f"property float y\nproperty float z\nelement face {len(faces)}\nproperty list uchar int vertex_indices\n"
              "end_header\n").encode()
    rows = np.zeros(len(faces), dtype=[("n", "u1"), ("i", "<i4", 3)])
    rows["n"], rows["i"] = 3, faces[:, ::-1]  # marching cubes winds inwards for a mask of ones: flip
    path.write_bytes(header + verts.astype("<f4").tobytes() + rows.tobytes())
    files.append(str(path))
materials = out / "mats.toml"
materials.write_text('[materials.M1]\ncolor = "#f0f0f0"\nchannel = 1\n[parts]\n'
                     + "".join(f'{Path(f).stem} = "M1"\n' for f in files))
sys.argv = ["heoslice", "--no-config", "slice", *files, "--materials", str(materials), "--layer", layer, "--dpi", dpi,
            "-j", jobs, "-o", str(out / "stack"), "--force"]
main()
'''


def run(arguments: list[str]) -> tuple[float, float, float]:
    """(wall seconds, peak RSS MiB, CPU seconds: user + system) of one child process running ``arguments``."""
    started = time.perf_counter()
    child = subprocess.Popen(arguments, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                             env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
    _, status, usage = os.wait4(child.pid, 0)
    seconds = time.perf_counter() - started
    if status != 0:
        raise SystemExit(f"{' '.join(arguments[:4])} ... failed: {child.stderr.read().decode()[-400:]}")
    return seconds, usage.ru_maxrss / 1024, usage.ru_utime + usage.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--layer", default="0.1")
    parser.add_argument("--dpi", default="600")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--jobs", default="0", help="worker processes of both routes' slices (0: one per core)")
    args = parser.parse_args()
    if not DATA.is_file():
        raise SystemExit(f"{DATA}: not found (set HEOSLICE_SHARED_DATA)")
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        volume_cmd = [sys.executable, "-m", "heoslice", "--no-config", "slice", str(DATA), "--layer", args.layer,
                      "--dpi", args.dpi, "-j", args.jobs, "-o", str(folder / "volume_stack"), "--force"]
        mesh_cmd = [sys.executable, "-c", MESH_ROUTE, str(DATA), str(folder), args.layer, args.dpi, args.jobs]
        results = {"volume": [], "mesh": []}
        for repeat in range(args.repeats):
            for name, command in (("volume", volume_cmd), ("mesh", mesh_cmd)) if repeat % 2 == 0 else (
                    ("mesh", mesh_cmd), ("volume", volume_cmd)):
                results[name].append(run(command))
                wall, rss, cpu = results[name][-1]
                print(f"{name:>6}: {wall:8.1f} s wall, {cpu:8.1f} s CPU, peak RSS {rss:7.0f} MiB", flush=True)
    best = {name: (min(r[0] for r in runs), max(r[1] for r in runs), min(r[2] for r in runs))
            for name, runs in results.items()}
    volume, mesh = best["volume"], best["mesh"]
    print(f"layer {args.layer} mm, {args.dpi} dpi, best of {args.repeats}: volume route {volume[0]:.1f} s wall "
          f"{volume[2]:.1f} s CPU {volume[1]:.0f} MiB; mesh route {mesh[0]:.1f} s wall {mesh[2]:.1f} s CPU "
          f"{mesh[1]:.0f} MiB; mesh / volume: wall x{mesh[0] / volume[0]:.2f}, CPU x{mesh[2] / volume[2]:.2f}, "
          f"RSS x{mesh[1] / volume[1]:.2f}; load average {', '.join(f'{v:.1f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
