"""Benchmark of `heoslice slice` against the baselines of issue 2, measured in the same run.

    python benchmarks/bench_slice.py            # vase + sphere, 0.1 mm, 600 dpi
    python benchmarks/bench_slice.py --quick    # smaller, for a smoke test
    python benchmarks/bench_slice.py --mesh path/to/model.ply

For each mesh it prints:
- slicing + contour building (heoslice, in-process, best of --repeats) against
  manifold3d's ``Manifold.slice`` over the same planes (target: ratio <= 2);
- the whole ``heoslice slice`` command (subprocess, all cores) with its stage
  seconds and peak memory, against the pipeline a user would write with trimesh
  ``section_multiplane`` + Pillow polygon fill + tifffile (subprocess, one core as
  written), same layers and resolution (target: heoslice at least 5x faster).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from timing import best_of

_WRAPPER = (
    "import resource, subprocess, sys\n"
    "done = subprocess.run(sys.argv[1:])\n"
    "print('PEAK_KB', resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr)\n"
    "sys.exit(done.returncode)\n"
)


def run_child(args: list[str]) -> tuple[float, float, str]:
    """Run a command in a fresh wrapper; return (wall s, peak RSS MB of its largest process, stdout)."""
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", _WRAPPER, *args], capture_output=True, text=True, check=False)
    wall = time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f"benchmark child failed: {' '.join(args)}\n{done.stderr}")
    peak_kb = int(done.stderr.rsplit("PEAK_KB", 1)[1].split()[0])
    return wall, peak_kb / 1024.0, done.stdout


def trimesh_pipeline(mesh_path: str, out_dir: str, layer: float, dpi: float) -> None:
    """The baseline a user would write: trimesh sections, Pillow polygon fill, tifffile, one layer at a time."""
    import tifffile
    import trimesh
    from PIL import Image, ImageDraw

    mesh = trimesh.load(mesh_path, force="mesh")
    low, high = mesh.bounds
    pixel = 25.4 / dpi
    width = int(np.ceil((high[0] - low[0] + 2) / pixel))
    height = int(np.ceil((high[1] - low[1] + 2) / pixel))
    x_left, y_top = low[0] - 1, high[1] + 1
    heights = np.arange(int(np.ceil((high[2] - low[2]) / layer))) * layer + layer / 2
    sections = mesh.section_multiplane(plane_origin=[0, 0, low[2]], plane_normal=[0, 0, 1], heights=heights)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for index, section in enumerate(sections):
        image = Image.new("1", (width, height), 0)
        if section is not None:
            draw = ImageDraw.Draw(image)
            for polygon in section.polygons_full:
                # section_multiplane returns paths in the plane frame; for a z-plane that is x, y
                def pix(coords):
                    coords = np.asarray(coords)
                    return list(zip((coords[:, 0] - x_left) / pixel - 0.5, (y_top - coords[:, 1]) / pixel - 0.5))
                draw.polygon(pix(polygon.exterior.coords), fill=1)
                for hole in polygon.interiors:
                    draw.polygon(pix(hole.coords), fill=0)
        tifffile.imwrite(out / f"layer_{index:05d}.tif", np.asarray(image), compression="zlib",
                         compressionargs={"level": 1}, resolution=(dpi, dpi), resolutionunit="INCH")


def slicing_ratio(mesh_path: Path, layer: float, repeats: int) -> dict:
    """heoslice slice+contours vs manifold3d slice over the same planes (best of repeats, seconds)."""
    import manifold3d

    from heoslice.layers import plane_heights, slice_mesh
    from heoslice.layers.contours import build_contours
    from heoslice.mesh import load_mesh

    mesh = load_mesh(mesh_path)
    z = plane_heights(mesh.bounds[0, 2], mesh.bounds[1, 2], layer)
    solid = manifold3d.Manifold(manifold3d.Mesh(vert_properties=mesh.vertices.astype(np.float32),
                                                tri_verts=mesh.faces.astype(np.uint32)))
    manifold_s, _ = best_of(repeats, lambda: [solid.slice(float(h)) for h in z])
    slice_s, sections = best_of(repeats, slice_mesh, mesh.vertices, mesh.faces, z)
    contour_s, _ = best_of(repeats, build_contours, sections)
    return {"triangles": len(mesh.faces), "layers": len(z), "segments": len(sections.layer),
            "slice_s": slice_s, "contours_s": contour_s, "manifold_s": manifold_s,
            "ratio": (slice_s + contour_s) / manifold_s}


def make_meshes(folder: Path, quick: bool) -> list[Path]:
    """The procedural benchmark meshes, written as binary PLY."""
    from heoslice import procedural

    meshes = {
        "vase": procedural.vase(sections=64 if quick else 256, rings_outer=26 if quick else 100,
                                rings_inner=22 if quick else 90),
        "sphere": procedural.uv_sphere(25.0, (64, 64) if quick else (256, 256)),
        "organ": procedural.liver_phantom(scale=0.25 if quick else 1.0, subdivisions=4 if quick else 5)[0],
    }
    paths = []
    for name, mesh in meshes.items():
        path = folder / f"{name}.ply"
        path.write_bytes(mesh.export(file_type="ply", encoding="binary"))
        paths.append(path)
    return paths


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", action="append", default=[], help="mesh file(s) instead of the procedural set")
    parser.add_argument("--layer", type=float, default=0.1)
    parser.add_argument("--dpi", type=float, default=600.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="small meshes, coarser layers")
    parser.add_argument("--skip-trimesh", action="store_true", help="skip the (slow) trimesh pipeline baseline")
    parser.add_argument("--trimesh-pipeline", nargs=2, metavar=("MESH", "OUT"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.trimesh_pipeline:
        trimesh_pipeline(args.trimesh_pipeline[0], args.trimesh_pipeline[1], args.layer, args.dpi)
        return
    layer = 0.5 if args.quick else args.layer
    work = Path(tempfile.mkdtemp(prefix="heoslice-bench-"))
    try:
        paths = [Path(p) for p in args.mesh] or make_meshes(work, args.quick)
        print(f"layer {layer} mm, {args.dpi:g} dpi, {os.cpu_count()} cores; best of {args.repeats} in-process")
        for path in paths:
            ratio = slicing_ratio(path, layer, args.repeats)
            print(f"\n{path.name}: {ratio['triangles']} triangles, {ratio['layers']} layers, "
                  f"{ratio['segments']} segments")
            print(f"  slicing {ratio['slice_s']:.3f} s + contours {ratio['contours_s']:.3f} s  vs  manifold3d "
                  f"slice {ratio['manifold_s']:.3f} s  ->  ratio {ratio['ratio']:.2f} (target <= 2)")
            out = work / f"{path.stem}_stack"
            wall, peak, stdout = run_child([sys.executable, "-m", "heoslice", "slice", str(path), "--layer",
                                           str(layer), "--dpi", str(args.dpi), "-o", str(out), "--force",
                                           "--json"])
            stages = json.loads(stdout)["seconds"]
            print(f"  heoslice slice: {wall:.2f} s wall, peak {peak:.0f} MB; stages: slice "
                  f"{stages['slice']:.2f}, contours {stages['contours']:.2f}, raster {stages['raster_cpu']:.2f} "
                  f"(CPU), encode {stages['encode_cpu']:.2f} (CPU)")
            if not args.skip_trimesh:
                base_wall, base_peak, _ = run_child([sys.executable, __file__, "--layer", str(layer), "--dpi",
                                                     str(args.dpi), "--trimesh-pipeline", str(path),
                                                     str(work / f"{path.stem}_trimesh")])
                print(f"  trimesh+Pillow+tifffile: {base_wall:.2f} s wall, peak {base_peak:.0f} MB  ->  "
                      f"heoslice is {base_wall / wall:.1f}x faster (target >= 5)")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
