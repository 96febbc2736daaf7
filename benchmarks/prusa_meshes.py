"""Benchmark meshes for bench_prusa.py: procedural ones made by code, and real scans from the shared folder.

Every mesh is a closed, outward-oriented trimesh.Trimesh in mm, resting on z = 0.
The full procedural set follows issue 6 (sphere ~1.3 M triangles, thick vase ~100 k, a
part with holes and islands, an organ-sized blob 160 x 165 x 200 mm); the quick set is
the same shapes made small and short, for smoke tests. The scans (issue 20) are
third-party meshes from ../shared/data (or $HEOSLICE_SHARED_DATA) scaled to the size
of what a lab prints: the SOFA liver to 160 mm, Lucy to 200 mm tall, the dragon as it
is (155 mm); they are left out when that folder is absent.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh

from heoslice import procedural


def on_bed(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The mesh translated so that its lowest point is at z = 0 (x, y unchanged)."""
    mesh = mesh.copy()
    mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])
    return mesh


def sphere(radius: float, count: int) -> trimesh.Trimesh:
    """A latitude-longitude sphere of about 4 * count**2 triangles (trimesh.creation.uv_sphere)."""
    return on_bed(procedural.uv_sphere(radius, (count, count)))


def thick_vase(height: float, sections: int, rings: int) -> trimesh.Trimesh:
    """A thick-walled vase of revolution: about 2 * sections * (2 * rings) triangles, ``height`` mm tall."""
    return on_bed(procedural.vase(height=height, radius=0.3 * height, bulge=0.1 * height, wall=0.05 * height,
                                  floor=0.06 * height, rings_outer=rings + 3, rings_inner=rings - 3,
                                  sections=sections))


def organ(extents: tuple[float, float, float], subdivisions: int = 5) -> trimesh.Trimesh:
    """heoslice.procedural.liver_phantom's organ, stretched to exactly ``extents`` (mm)."""
    mesh = procedural.liver_phantom(subdivisions=subdivisions)[0].copy()
    mesh.vertices = (mesh.vertices - mesh.bounds[0]) * (np.asarray(extents, dtype=float) / mesh.extents)
    return mesh


FULL: dict[str, Callable[[], trimesh.Trimesh]] = {
    "sphere": lambda: sphere(25.0, 570),
    "vase": lambda: thick_vase(100.0, 512, 49),
    "holes": lambda: procedural.holes_and_islands((80.0, 50.0, 30.0), 256),
    "organ": lambda: organ((160.0, 165.0, 200.0)),
}

QUICK: dict[str, Callable[[], trimesh.Trimesh]] = {
    "sphere": lambda: sphere(10.0, 90),
    "vase": lambda: thick_vase(20.0, 128, 12),
    "holes": lambda: procedural.holes_and_islands((40.0, 25.0, 10.0), 64),
    "organ": lambda: organ((32.0, 33.0, 40.0), subdivisions=4),
}


#: Real scans: name -> (file in the shared folder, largest extent in mm; the quick set makes them 40 mm).
SCANS: dict[str, tuple[str, float]] = {
    "liver_scan": ("anatomy/sofa_liver_smooth.ply", 160.0),
    "lucy": ("scans/lucy_100k.ply", 200.0),
    "dragon": ("scans/dragon_23k.ply", 155.1),
}


def shared_data() -> Path:
    """The third-party meshes: $HEOSLICE_SHARED_DATA, else ../shared/data beside the repo."""
    return Path(os.environ.get("HEOSLICE_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def available_scans() -> list[str]:
    """The scans whose files are in the shared folder."""
    return [name for name, (file, _) in SCANS.items() if (shared_data() / file).is_file()]


def scan(name: str, quick: bool) -> trimesh.Trimesh:
    """A shared scan scaled uniformly so that its largest extent is the set size, resting on z = 0."""
    file, size = SCANS[name]
    mesh = trimesh.load(shared_data() / file, force="mesh", process=False)
    mesh.apply_scale((40.0 if quick else size) / float(mesh.extents.max()))
    mesh.apply_translation(-mesh.bounds[0])
    return mesh


def names(quick: bool) -> list[str]:
    """Every benchmark mesh that can be built here: the procedural set, then the available scans."""
    return list(QUICK if quick else FULL) + available_scans()


def build(name: str, quick: bool) -> trimesh.Trimesh:
    """The named benchmark mesh (full or quick set); raises KeyError for an unknown name."""
    if name in SCANS:
        return scan(name, quick)
    return (QUICK if quick else FULL)[name]()
