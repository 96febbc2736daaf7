"""Point-triangle and nearest-surface distances against brute force.

References: trimesh's closest point on one triangle, and a brute-force minimum over
every triangle of a mesh.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from heoslice import procedural
from heoslice.material import (build_surface_index, closest_points_on_triangles, point_triangle_distance,
                               surface_distance)


def brute_force_distance(points: np.ndarray, mesh: trimesh.Trimesh) -> np.ndarray:
    """min over all triangles of |p - closest point| with trimesh's own point-triangle routine."""
    out = np.empty(len(points))
    triangles = mesh.triangles
    for i, p in enumerate(points):
        closest = trimesh.triangles.closest_point(triangles, np.repeat(p[None], len(triangles), axis=0))
        out[i] = np.linalg.norm(closest - p, axis=1).min()
    return out


# --- surface distance -----------------------------------------------------------------------

triangle_arrays = arrays(np.float64, (3, 3), elements=st.floats(-5, 5, allow_nan=False, width=32))
point_arrays = arrays(np.float64, (3,), elements=st.floats(-8, 8, allow_nan=False, width=32))


@settings(max_examples=300, deadline=None)
@given(triangle=triangle_arrays, point=point_arrays)
def test_closest_point_on_triangle_matches_trimesh(triangle, point):
    """Our vectorised closest point gives the same distance as trimesh.triangles.closest_point.

    Only triangles of real area: trimesh is not exact on degenerate ones (tested separately).
    """
    assume(np.linalg.norm(np.cross(triangle[1] - triangle[0], triangle[2] - triangle[0])) > 1e-3)
    ours = point_triangle_distance(point[None], triangle[None])[0]
    theirs = np.linalg.norm(trimesh.triangles.closest_point(triangle[None], point[None])[0] - point)
    assert ours == pytest.approx(theirs, abs=1e-9, rel=1e-9)


def test_closest_point_degenerate_triangles():
    """Zero-area triangles (collinear or coincident corners) give the distance to their segment or point."""
    triangles = np.array([[[0, 0, 0], [2, 0, 0], [4, 0, 0]], [[1, 1, 1], [1, 1, 1], [1, 1, 1]]], dtype=float)
    points = np.array([[1.0, 3.0, 0.0], [1.0, 1.0, 4.0]])
    closest = closest_points_on_triangles(points, triangles)
    assert np.allclose(closest, [[1.0, 0.0, 0.0], [1.0, 1.0, 1.0]], rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["sphere", "torus", "vase", "nested"])
def test_surface_distance_matches_brute_force(name):
    """Distances to a small mesh (points inside, outside, near and far) equal the minimum over all triangles."""
    mesh = {
        "sphere": lambda: procedural.sphere(radius=10.0, subdivisions=2),
        "torus": lambda: procedural.torus(major=12.0, minor=4.0, sections=24, rings=12),
        "vase": lambda: procedural.vase(sections=16, rings_outer=10, rings_inner=8),
        "nested": lambda: procedural.nested_shells(outer=12.0, inner=4.0, subdivisions=2),
    }[name]()
    rng = np.random.default_rng(7)
    low, high = mesh.bounds
    span = high - low
    points = np.vstack([rng.uniform(low - span, high + span, size=(150, 3)),
                        mesh.sample(100, seed=3) + rng.normal(scale=0.3, size=(100, 3)),
                        mesh.vertices[:20]])
    index = build_surface_index(mesh.vertices, mesh.faces)
    ours = surface_distance(points, index)
    assert np.allclose(ours, brute_force_distance(points, mesh), rtol=0, atol=1e-9)
    assert np.allclose(ours[-20:], 0.0, rtol=0, atol=1e-12)


def test_surface_distance_with_coarse_seeds():
    """With far fewer seeds than vertices, the downhill walks still reach the brute-force distance."""
    mesh = procedural.sphere(radius=10.0, subdivisions=4)
    index = build_surface_index(mesh.vertices, mesh.faces, seed_count=40)
    assert len(index.seeds) < len(mesh.faces) // 10
    rng = np.random.default_rng(11)
    points = np.vstack([rng.uniform(-40, 40, size=(80, 3)), rng.normal(size=(40, 3)) * 3])
    assert np.allclose(surface_distance(points, index), brute_force_distance(points, mesh), rtol=0, atol=1e-9)


def test_surface_distance_bounds_with_few_seeds():
    """With very few start points on a thin-walled vase the result stays within [true, true + seed_spacing]."""
    mesh = procedural.vase(sections=24, rings_outer=12, rings_inner=10)
    index = build_surface_index(mesh.vertices, mesh.faces, seed_count=8)
    rng = np.random.default_rng(5)
    points = np.vstack([rng.uniform(mesh.bounds[0] - 5, mesh.bounds[1] + 5, size=(150, 3)),
                        mesh.sample(100, seed=2) + rng.normal(scale=0.5, size=(100, 3))])
    calls = []
    ours = surface_distance(points, index, chunk=64, progress=lambda done, total: calls.append((done, total)))
    truth = brute_force_distance(points, mesh)
    assert np.all(ours >= truth - 1e-9) and np.all(ours <= truth + index.seed_spacing + 1e-9)
    assert calls[-1] == (250, 250) and len(calls) == 4
