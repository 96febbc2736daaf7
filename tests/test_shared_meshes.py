"""Real third-party meshes (../shared/data or $HEOSLICE_SHARED_DATA; skipped when absent).

Slices are compared with manifold3d's slice, masks with a shapely point-in-polygon
reference, and stack volumes with the mesh volume.
"""

from __future__ import annotations

import manifold3d
import numpy as np
import pytest
import shapely
from conftest import shared_data_dir
from helpers import layer_loops, near_contour, winding_reference

from heoslice.errors import HeosliceError
from heoslice.layers import plane_heights, slice_mesh
from heoslice.layers.contours import build_contours
from heoslice.layers.bits import count_solid
from heoslice.layers.rasterising import grid_for, packed_mask, solid_mask
from heoslice.mesh import load_mesh

pytestmark = pytest.mark.shared_data

#: Closed meshes from the shared folder's README (watertight = yes), with faces to slice.
WATERTIGHT = [
    "anatomy/sofa_liver_smooth.ply",
    "anatomy/footbones_26parts_ascii.ply",
    "bad/busted.ply",
    "bad/multibody_ascii.ply",
    "colour/airplane_binLE_double_rgba.ply",
    "colour/horse_binBE_rgb.ply",
    "large/turbineblade_199k.ply",
    "scans/bunny_watertight_7k.ply",
    "scans/dragon_23k.ply",
    "scans/lucy_100k.ply",
    "shapes/fertility_genus4.ply",
    "shapes/gears_7parts.ply",
    "shapes/plate_holes.ply",
    "shapes/torus.ply",
    "shapes/vase_goblet.ply",
    "shapes/vase_goblet.stl",
]


def load_shared(relative: str):
    path = shared_data_dir() / relative
    if not path.is_file():
        pytest.skip(f"{path} not present")
    return load_mesh(path)


def planes_for(mesh, count: int) -> np.ndarray:
    low, high = mesh.bounds[:, 2]
    return plane_heights(low, high, (high - low) / count)


def mesh_volume(mesh) -> float:
    corner = mesh.vertices[mesh.faces]
    return float(np.einsum("ij,ij->i", corner[:, 0], np.cross(corner[:, 1], corner[:, 2])).sum() / 6.0)


@pytest.mark.parametrize("relative", WATERTIGHT)
def test_layer_areas_match_manifold3d(relative):
    """Per-layer contour areas within 1e-5 relative of manifold3d's slice, where manifold3d accepts the mesh.

    Compared on layers whose loops are simple and do not touch each other: where a
    self-intersecting surface makes loops cross, the winding-number integral and
    manifold3d's positive-fill area are different quantities.
    """
    mesh = load_shared(relative)
    centre = (mesh.bounds[0] + mesh.bounds[1]) / 2.0
    solid = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=mesh.vertices - centre,
                                                  tri_verts=mesh.faces.astype(np.uint64)))
    if solid.status() != manifold3d.Error.NoError:
        pytest.skip(f"manifold3d rejects {relative}: {solid.status()}")
    z = planes_for(mesh, 60)
    contours = build_contours(slice_mesh(mesh.vertices, mesh.faces, z))
    ours = contours.layer_area()
    reference = np.array([solid.slice(float(h - centre[2])).area() for h in z])
    clean = np.array([loops_are_disjoint_and_simple(*layer_loops(contours, k)) for k in range(len(z))])
    compare = clean & (reference > 1e-12)
    assert compare.sum() >= len(z) // 3  # touching bones leave 22 of 60 footbones layers
    np.testing.assert_allclose(ours[compare], reference[compare], rtol=1e-5)


def loops_are_disjoint_and_simple(points: np.ndarray, offsets: np.ndarray) -> bool:
    """True when every loop is a simple ring and no two loops touch (shapely's is_simple on them all)."""
    rings = [points[a:b] for a, b in zip(offsets[:-1], offsets[1:])]
    if any(len(ring) < 3 for ring in rings):
        return False
    lines = shapely.MultiLineString([np.vstack([ring, ring[:1]]) for ring in rings])
    return bool(shapely.is_simple(lines))


@pytest.mark.parametrize("relative", ["anatomy/sofa_liver_smooth.ply", "shapes/plate_holes.ply",
                                      "shapes/gears_7parts.ply", "shapes/fertility_genus4.ply"])
def test_masks_match_point_in_polygon_reference(relative):
    """Masks equal the shapely winding reference at pixel centres except within 1e-6 mm of a contour."""
    mesh = load_shared(relative)
    z = planes_for(mesh, 8)
    contours = build_contours(slice_mesh(mesh.vertices, mesh.faces, z))
    extent = float((mesh.bounds[1] - mesh.bounds[0])[:2].max())
    grid = grid_for(mesh.bounds[:, :2], (25.4 * 300 / extent,) * 2, margin_mm=extent / 100)
    x, y = grid.centres()
    xx, yy = np.meshgrid(x, y)
    for layer in range(len(z)):
        points, offsets = layer_loops(contours, layer)
        mask = solid_mask(points, offsets, grid)
        reference = winding_reference(points, offsets, xx, yy) > 0
        differ = mask != reference
        if differ.any():
            assert near_contour(points, offsets, xx[differ], yy[differ]).all()


@pytest.mark.parametrize("relative", WATERTIGHT)
def test_stack_volume_matches_mesh_volume(relative):
    """Solid pixels x pixel area x layer height within 0.5 % of the mesh volume (closed meshes)."""
    mesh = load_shared(relative)
    extent = mesh.bounds[1] - mesh.bounds[0]
    layer = float(extent[2]) / 200
    dpi = 25.4 * 800 / float(extent[:2].max())
    z = plane_heights(mesh.bounds[0, 2], mesh.bounds[1, 2], layer)
    contours = build_contours(slice_mesh(mesh.vertices, mesh.faces, z))
    grid = grid_for(mesh.bounds[:, :2], (dpi, dpi))
    solid = sum(count_solid(packed_mask(*layer_loops(contours, k), grid)) for k in range(len(z)))
    stack_volume = solid * grid.px * grid.py * layer
    # where shells overlap, the solid (winding number > 0) counts the overlap once, the signed volume twice
    area_integral = float(contours.layer_area().sum()) * layer
    expected = mesh_volume(mesh)
    assert area_integral == pytest.approx(expected, rel=5e-3)
    if not np.any((contours.parent >= 0) & (contours.area > 0)):
        assert stack_volume == pytest.approx(expected, rel=5e-3)


def test_every_bad_mesh_slices_or_fails_with_one_line(shared_data):
    """Each mesh in bad/ loads and slices to layers, or raises one HeosliceError line."""
    for path in sorted((shared_data / "bad").glob("*.ply")):
        try:
            mesh = load_mesh(path)
        except HeosliceError as err:
            assert "\n" not in str(err) and path.name in str(err)
            continue
        z = planes_for(mesh, 20)
        contours = build_contours(slice_mesh(mesh.vertices, mesh.faces, z))
        extent = float((mesh.bounds[1] - mesh.bounds[0])[:2].max()) or 1.0
        grid = grid_for(mesh.bounds[:, :2], (25.4 * 200 / extent,) * 2)
        for k in range(len(z)):
            count_solid(packed_mask(*layer_loops(contours, k), grid))
