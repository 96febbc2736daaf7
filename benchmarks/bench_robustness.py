"""Costs of heoslice's safety checks, each against a baseline measured in the same run.

    python benchmarks/bench_robustness.py
    python benchmarks/bench_robustness.py --quick

Prints:
- refusing a PLY header that declares 10**9 / 10**12 elements: wall time and peak RSS of
  ``heoslice info`` in a subprocess, against ``heoslice --version`` (start-up only)
  (issue 7 target: under 1 s and 100 MB);
- the strict PLY reader (``heoslice.mesh.read_ply``) against trimesh's PLY reader on the same
  binary and ASCII files (ratio = heoslice / trimesh);
- ``verify_stack`` (hash, header checks and a full strip-by-strip decode of every
  layer) against writing the same stack with ``slice_to_stack``.
"""

from __future__ import annotations

import argparse
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


if __name__ == "__main__":
    main()
