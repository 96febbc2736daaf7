"""Reference features (plane, point, axis, surface), their distances and the normalisation to r.

References: exact geometry of procedural meshes (a sphere about its centre, a box about
its base plane, a cylinder about its axis) and a brute-force minimum over every triangle.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from helpers import brute_force_distance

from heoslice import procedural
from heoslice.errors import InputError
from heoslice.material import (
    make_function,
    make_reference,
    material_fraction,
    normalise,
    reference_distance,
)

# --- references and normalisation -----------------------------------------------------------

def test_sphere_about_its_centre_gives_one_r():
    """Every vertex of a sphere is at the same distance from its centre: one r (= 1) for all."""
    sphere = procedural.sphere(radius=12.0, subdivisions=3, center=(5.0, -2.0, 30.0))
    reference = make_reference("point", sphere.vertices, at=(5.0, -2.0, 30.0))
    r = normalise(reference_distance(reference, sphere.vertices))
    assert np.allclose(r, 1.0, rtol=0, atol=1e-12)
    default = make_reference("point", sphere.vertices)  # bounding-box centre is the centre here
    assert np.allclose(default.point, (5.0, -2.0, 30.0), rtol=0, atol=1e-9)


def test_box_about_its_base_plane_gives_z_over_height():
    """The default reference (X-Y plane through the lowest point) gives r = (z - z0) / height exactly."""
    box = procedural.box((20.0, 10.0, 8.0), origin=(-3.0, 4.0, 2.0), z_cuts=(3.0, 4.5, 7.25))
    reference = make_reference("plane", box.vertices)
    assert reference.point[2] == 2.0 and reference.direction == (0.0, 0.0, 1.0)
    r = normalise(reference_distance(reference, box.vertices))
    assert np.array_equal(r, (box.vertices[:, 2] - 2.0) / 8.0)
    r, f = material_fraction(box.vertices, reference, make_function("quadratic"))
    assert np.allclose(f, ((box.vertices[:, 2] - 2.0) / 8.0) ** 2, rtol=0, atol=1e-15)


def test_tilted_plane_and_default_anchor():
    """A plane by normal only passes through the model's extreme point against the normal; distance |n.(x-p)|."""
    points = np.random.default_rng(1).uniform(-10, 10, size=(500, 3))
    normal = np.array([1.0, 2.0, -2.0]) / 3.0
    reference = make_reference("plane", points, normal=(1, 2, -2))
    assert np.allclose(reference.direction, normal, rtol=0, atol=1e-12)
    d = reference_distance(reference, points)
    assert np.allclose(d, (points - points[np.argmin(points @ normal)]) @ normal, rtol=0, atol=1e-12)
    assert d.min() == pytest.approx(0.0, abs=1e-12)
    at = make_reference("plane", points, at=(0, 0, 1))
    assert np.allclose(reference_distance(at, points), np.abs(points[:, 2] - 1.0), rtol=0, atol=1e-12)


def test_cylinder_about_its_axis():
    """Vertices of a cylinder are all at its radius from its axis, whatever the axis direction."""
    cylinder = trimesh.creation.cylinder(radius=7.0, height=30.0, sections=48)
    direction = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    rotation = trimesh.geometry.align_vectors([0, 0, 1], direction)
    cylinder.apply_transform(rotation)
    cylinder.apply_translation([3.0, -1.0, 2.0])
    reference = make_reference("axis", cylinder.vertices, at=(3.0, -1.0, 2.0), direction=(2, 2, 0))
    d = reference_distance(reference, cylinder.vertices)
    on_axis = np.isclose(d, 0.0, atol=1e-9)  # the two cap centres
    assert on_axis.sum() == 2 and np.allclose(d[~on_axis], 7.0, rtol=0, atol=1e-9)
    vertical = make_reference("axis", cylinder.vertices)
    assert vertical.direction == (0.0, 0.0, 1.0)


def test_reference_refusals():
    """Unknown reference kinds, zero normals, and options that do not belong to a kind are InputErrors."""
    points = np.eye(3)
    with pytest.raises(InputError, match="unknown reference"):
        make_reference("cone", points)
    with pytest.raises(InputError, match="zero vector"):
        make_reference("plane", points, normal=(0, 0, 0))
    with pytest.raises(InputError, match="normal: only applies"):
        make_reference("point", points, normal=(0, 0, 1))
    with pytest.raises(InputError, match="direction: only applies"):
        make_reference("plane", points, direction=(0, 0, 1))
    with pytest.raises(InputError, match="three numbers"):
        make_reference("point", points, at=(1, 2))


def test_normalise():
    """r = d / max d by default; with (R0, R1) r = (d - R0) / (R1 - R0) clipped; zero width is an InputError."""
    d = np.array([0.0, 1.0, 2.0, 4.0])
    assert np.array_equal(normalise(d), [0.0, 0.25, 0.5, 1.0])
    assert np.array_equal(normalise(d, (1.0, 3.0)), [0.0, 0.0, 0.5, 1.0])
    with pytest.raises(InputError, match="zero width"):
        normalise(np.zeros(5))
    with pytest.raises(InputError, match="zero or negative width"):
        normalise(d, (2.0, 2.0))



def test_surface_reference_to_second_mesh():
    """--ref surface with a second mesh: the distance of each vertex to that mesh, normalised by the largest."""
    organ = procedural.sphere(radius=20.0, subdivisions=3)
    lesion = procedural.sphere(radius=4.0, subdivisions=2, center=(5.0, 0.0, 0.0))
    reference = make_reference("surface", organ.vertices, organ.faces, surface=(lesion.vertices, lesion.faces))
    d = reference_distance(reference, organ.vertices)
    assert np.allclose(d, brute_force_distance(organ.vertices, lesion), rtol=0, atol=1e-9)
    own = make_reference("surface", organ.vertices, organ.faces)
    assert np.allclose(reference_distance(own, organ.vertices), 0.0, rtol=0, atol=1e-12)
    inside = reference_distance(own, np.array([[0.0, 0.0, 0.0]]))
    assert inside[0] == pytest.approx(brute_force_distance(np.zeros((1, 3)), organ)[0], abs=1e-9)
