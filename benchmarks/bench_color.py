"""Benchmark: colouring 1 M vertices about a plane, a point, an axis and a 100 k-triangle surface.

Usage: python benchmarks/bench_color.py [--vertices 1000000] [--triangles 100000] [--repeat 3]

Targets (issue 3): under 1 s per million vertices for plane, point and axis references,
under 10 s against a 100 k-triangle reference surface. The model is a liver-like blob
(a deformed latitude-longitude sphere about 160 x 165 x 200 mm); the reference surface a
torus "lesion" inside it. Baselines measured in the same run:

* plane / point / axis: the same arithmetic as a plain Python loop over vertices,
  timed on a subset and scaled to the full count;
* surface: trimesh.proximity.closest_point (trimesh's default, rtree candidates), timed
  on a few hundred points and scaled; and libigl's point_mesh_squared_distance (an AABB
  tree in C++) on every vertex when the ``igl`` module is installed (it is not a
  dependency: the candidate the exact hierarchy was measured against).

The surface distance is also checked against a brute-force minimum over all triangles
on random vertices, and the largest difference printed; the surface case's CPU time is
printed with the load average (the wall time on a shared machine is not the code's).
"""

from __future__ import annotations

import argparse
import math
import os
import resource
from pathlib import Path

import numpy as np
import trimesh
from timing import best_of

from heoslice.material import (
    ColorSpec,
    build_surface_index,
    color_mesh,
    make_function,
    surface_distance,
)
from heoslice.mesh import Mesh


def process_cpu_seconds() -> float:
    """User + system CPU seconds of this process so far, every thread included."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _workers() -> int:
    return max(1, len(os.sched_getaffinity(0)))


def organ(vertex_count: int) -> Mesh:
    """A smooth liver-like blob with about ``vertex_count`` vertices, as a loaded Mesh."""
    side = int(math.sqrt(vertex_count / 2)) + 1  # uv_sphere: about 2 side^2 vertices
    sphere = trimesh.creation.uv_sphere(radius=1.0, count=[side, side])
    v = np.asarray(sphere.vertices)
    lobe = 1.0 + 0.18 * np.sin(2.1 * v[:, 0] + 0.7) * np.cos(1.7 * v[:, 1]) + 0.1 * v[:, 2] ** 2
    vertices = v * lobe[:, None] * (np.array([80.0, 82.5, 100.0]) / 1.3)
    vertices[:, 2] -= vertices[:, 2].min()
    faces = np.asarray(sphere.faces, dtype=np.int64)
    return Mesh(vertices=vertices, faces=faces, colors=None, material=None,
                shell=np.zeros(len(faces), dtype=np.int64), source=Path("organ"), sha256="", warnings=())


def lesion(triangles: int) -> trimesh.Trimesh:
    """A torus (major 18 mm, minor 6 mm) of about ``triangles`` triangles, tilted, inside the organ."""
    minor = int(math.sqrt(triangles / 2 / 1.25))
    major = int(triangles / 2 / minor)
    torus = trimesh.creation.torus(major_radius=18.0, minor_radius=6.0, major_sections=major, minor_sections=minor)
    torus.apply_transform(trimesh.transformations.rotation_matrix(0.6, [1, 0, 0]))
    torus.apply_translation([20.0, 10.0, 90.0])
    return torus


def python_loop_distances(points: np.ndarray, kind: str) -> list[float]:
    """The baseline: each vertex's distance to the reference in a plain Python loop."""
    out = []
    for x, y, z in points.tolist():
        if kind == "plane":
            out.append(abs(z))
        elif kind == "point":
            out.append(math.sqrt((x - 1.0) ** 2 + (y - 2.0) ** 2 + (z - 90.0) ** 2))
        else:
            out.append(math.sqrt((x - 1.0) ** 2 + (y - 2.0) ** 2))
    return out


def brute_force(points: np.ndarray, mesh: trimesh.Trimesh) -> np.ndarray:
    """Minimum over all triangles of the point-triangle distance (trimesh.triangles.closest_point)."""
    out = np.empty(len(points))
    for i, p in enumerate(points):
        closest = trimesh.triangles.closest_point(mesh.triangles, np.repeat(p[None], len(mesh.triangles), axis=0))
        out[i] = np.linalg.norm(closest - p, axis=1).min()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vertices", type=int, default=1_000_000)
    parser.add_argument("--triangles", type=int, default=100_000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--baseline-points", type=int, default=200, help="points timed for the trimesh baseline")
    args = parser.parse_args()

    model = organ(args.vertices)
    n = len(model.vertices)
    print(f"model: {n} vertices, {len(model.faces)} triangles; extent {np.ptp(model.vertices, axis=0).round(1)} mm")
    function = make_function("linear")
    rows = []
    for kind, extra in (("plane", {}), ("point", {"at": (1.0, 2.0, 90.0)}),
                        ("axis", {"at": (1.0, 2.0, 0.0)})):
        spec = ColorSpec(function=function, reference=kind, **extra)
        ours, _ = best_of(args.repeat, lambda spec=spec: color_mesh(model, spec))
        subset = model.vertices[: min(n, 50_000)]
        loop, _ = best_of(1, lambda subset=subset, kind=kind: python_loop_distances(subset, kind))
        loop *= n / len(subset)
        rows.append((kind, ours, 1.0, loop))

    reference = lesion(args.triangles)
    print(f"reference surface: {len(reference.faces)} triangles (torus lesion)")
    spec = ColorSpec(function=function, reference="surface", surface=Mesh(
        vertices=np.asarray(reference.vertices), faces=np.asarray(reference.faces, dtype=np.int64), colors=None,
        material=None, shell=np.zeros(len(reference.faces), dtype=np.int64), source=Path("lesion"), sha256="",
        warnings=()))
    ours, colored = best_of(args.repeat, lambda: color_mesh(model, spec))
    cpu_before = process_cpu_seconds()
    color_mesh(model, spec)
    surface_cpu = process_cpu_seconds() - cpu_before
    index_time, index = best_of(1, lambda: build_surface_index(reference.vertices, reference.faces))
    rng = np.random.default_rng(0)
    sample = model.vertices[rng.choice(n, size=args.baseline_points, replace=False)]
    trimesh_time, (_, trimesh_d, _) = best_of(1, lambda: trimesh.proximity.closest_point(reference, sample))
    trimesh_time *= n / len(sample)
    rows.append(("surface", ours, 10.0, trimesh_time))

    check = model.vertices[rng.choice(n, size=300, replace=False)]
    ours_check = surface_distance(check, index)
    error = np.abs(ours_check - brute_force(check, reference)).max()
    error_trimesh = np.abs(surface_distance(sample, index) - trimesh_d).max()

    print(f"\n{'reference':<10}{'heoslice s':>12}{'target s':>10}{'baseline s':>12}{'speed-up':>10}  baseline")
    for kind, seconds, target, baseline in rows:
        name = "trimesh closest_point (scaled)" if kind == "surface" else "Python loop (scaled)"
        flag = "ok" if seconds < target else "SLOW"
        print(f"{kind:<10}{seconds:>12.3f}{target:>10.1f}{baseline:>12.1f}{baseline / seconds:>9.0f}x  "
              f"{name}  [{flag}]")
    print(f"\nsurface: {surface_cpu:.2f} s CPU (user + system, all threads) for one colouring; on {_workers()} "
          f"cores that is {surface_cpu / _workers():.2f} s of wall time when they are idle; load average "
          f"{os.getloadavg()[0]:.2f}")
    print(f"surface index build: {index_time:.3f} s ({len(index.tree.low)} boxes)")
    try:
        import igl
    except ImportError:
        print("libigl: not installed (pip install libigl to compare)")
    else:
        points = np.ascontiguousarray(model.vertices)
        vertices, faces = np.asarray(reference.vertices), np.asarray(reference.faces, dtype=np.int64)
        igl_time, (igl_d2, _, _) = best_of(args.repeat, lambda: igl.point_mesh_squared_distance(points, vertices,
                                                                                                 faces))
        ours_time, ours_d = best_of(args.repeat, lambda: surface_distance(points, index))
        print(f"distances only, {n} vertices: heoslice {ours_time:.3f} s, libigl {igl_time:.3f} s; "
              f"max |difference| {np.abs(ours_d - np.sqrt(igl_d2)).max():.3g} mm")
    print(f"surface distance vs brute force on 300 vertices: max |difference| = {error:.3g} mm")
    print(f"surface distance vs trimesh on {len(sample)} vertices: max |difference| = {error_trimesh:.3g} mm")
    print(f"r range {colored.r.min():.3f}..{colored.r.max():.3f}")


if __name__ == "__main__":
    main()
