"""Distribution functions (eq. 2-5), safe expressions, reference distances, normalisation, surface distance.

References: the equations written out in numpy, exact geometry of procedural meshes
(a sphere about its centre, a box about its base plane, a cylinder about its axis),
and a brute-force minimum over every triangle using trimesh's closest-point routine.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from heoslice import procedural
from heoslice.distribution import (FUNCTION_KINDS, DistributionFunction, build_surface_index,
                                   closest_points_on_triangles, compile_expression, evaluate, make_function,
                                   make_reference, material_fraction, normalise, point_triangle_distance,
                                   reference_distance, surface_distance)
from heoslice.errors import InputError

R = np.linspace(0.0, 1.0, 1001)
coefficient = st.floats(-10, 10, allow_nan=False)


def brute_force_distance(points: np.ndarray, mesh: trimesh.Trimesh) -> np.ndarray:
    """min over all triangles of |p - closest point| with trimesh's own point-triangle routine."""
    out = np.empty(len(points))
    triangles = mesh.triangles
    for i, p in enumerate(points):
        closest = trimesh.triangles.closest_point(triangles, np.repeat(p[None], len(triangles), axis=0))
        out[i] = np.linalg.norm(closest - p, axis=1).min()
    return out


# --- functions ----------------------------------------------------------------------------

def test_defaults_span_zero_to_one():
    """With make_function's defaults, linear, quadratic and sine reach exactly 0 and 1 over r in [0, 1]."""
    for kind in ("linear", "quadratic", "sine"):
        f = evaluate(make_function(kind), R)
        assert f.min() == pytest.approx(0.0, abs=1e-12) and f.max() == pytest.approx(1.0, abs=1e-12), kind


def test_default_shapes():
    """Defaults: linear f = r, quadratic f = r^2, sine f = 0.5 + 0.5 sin(2 pi r), constant f = 1."""
    assert np.array_equal(evaluate(make_function("linear"), R), R)
    assert np.allclose(evaluate(make_function("quadratic"), R), R ** 2, rtol=0, atol=1e-15)
    assert np.allclose(evaluate(make_function("sine"), R), 0.5 + 0.5 * np.sin(2 * np.pi * R), rtol=0, atol=1e-15)
    assert np.array_equal(evaluate(make_function("constant"), R), np.ones_like(R))


@given(alpha=coefficient, beta=coefficient, lam=coefficient)
def test_equations_2_to_5(alpha, beta, lam):
    """evaluate() is eq. 2 (lam), 3 (alpha r + lam), 4 (alpha r^2 + beta r + lam), 5 (alpha sin(beta r) + lam)."""
    r = np.linspace(0, 1, 33)
    expected = {
        "constant": np.full_like(r, lam),
        "linear": alpha * r + lam,
        "quadratic": alpha * r ** 2 + beta * r + lam,
        "sine": alpha * np.sin(beta * r) + lam,
    }
    for kind, values in expected.items():
        func = make_function(kind, alpha=None if kind == "constant" else alpha,
                             beta=None if kind in ("constant", "linear") else beta, lam=lam)
        assert np.allclose(evaluate(func, r), values, rtol=1e-12, atol=1e-12), kind
        assert np.allclose(func(r), values, rtol=1e-12, atol=1e-12)


def test_sine_periods():
    """periods = p sets beta = 2 pi p: f completes p periods over r in [0, 1]; beta and periods conflict."""
    func = make_function("sine", periods=3)
    assert func.beta == pytest.approx(6 * math.pi)
    assert evaluate(func, np.array([1 / 12, 3 / 12]))[0] == pytest.approx(1.0)
    with pytest.raises(InputError, match="beta or periods"):
        make_function("sine", beta=2.0, periods=1.0)


@pytest.mark.parametrize("kind", ["spline", "", "Linear2"])
def test_unknown_kind(kind):
    """An unknown function kind is an InputError listing the known ones."""
    with pytest.raises(InputError, match="unknown distribution function"):
        make_function(kind)


def test_kind_is_case_insensitive_and_bad_numbers_refused():
    """'LINEAR' is linear; NaN or infinite coefficients, and coefficients the kind does not use, are refused."""
    assert make_function("LINEAR").kind == "linear"
    with pytest.raises(InputError, match="alpha must be finite"):
        make_function("linear", alpha=float("nan"))
    with pytest.raises(InputError, match="only used with the 'expression'"):
        make_function("linear", expression="r")
    with pytest.raises(InputError, match="periods only applies"):
        make_function("linear", periods=2)
    with pytest.raises(InputError, match="beta is not used by the linear"):
        make_function("linear", beta=2)
    with pytest.raises(InputError, match="alpha and beta are not used by the constant"):
        make_function("constant", alpha=1, beta=2)


def test_function_is_frozen_dataclass():
    """DistributionFunction is immutable and comparable (a specification, not state)."""
    func = make_function("linear")
    assert func == DistributionFunction("linear", 1.0, 0.0, 0.0)
    with pytest.raises(AttributeError):
        func.alpha = 2.0  # type: ignore[misc]
    assert set(FUNCTION_KINDS) == {"constant", "linear", "quadratic", "sine", "expression"}


# --- expressions --------------------------------------------------------------------------

@pytest.mark.parametrize("text, reference", [
    ("r", lambda r: r),
    ("0.5 - 0.5*cos(2*pi*r)", lambda r: 0.5 - 0.5 * np.cos(2 * np.pi * r)),
    ("r**2*(3-2*r)", lambda r: r ** 2 * (3 - 2 * r)),
    ("-r + 1", lambda r: 1 - r),
    ("clip(2*r - 0.5, 0, 1)", lambda r: np.clip(2 * r - 0.5, 0, 1)),
    ("max(r, 0.3) + min(r, 0.1)", lambda r: np.maximum(r, 0.3) + np.minimum(r, 0.1)),
    ("exp(-r/0.2) * sqrt(abs(r - 0.5))", lambda r: np.exp(-r / 0.2) * np.sqrt(np.abs(r - 0.5))),
    ("floor(4*r)/4", lambda r: np.floor(4 * r) / 4),
    ("0.25", lambda r: np.full_like(r, 0.25)),
    ("e**-r", lambda r: np.e ** -r),
])
def test_expression_values(text, reference):
    """A whitelisted expression evaluates to the same values as the numpy formula, vectorised over r."""
    func = make_function("expression", expression=text)
    assert np.allclose(evaluate(func, R), reference(R), rtol=1e-14, atol=1e-14)
    assert evaluate(func, R).shape == R.shape


@pytest.mark.parametrize("text, fragment", [
    ("__import__('os').system('true')", "unknown function"),
    ("r.__class__", "attribute is not allowed"),
    ("().__class__.__bases__", "not allowed"),
    ("open('x')", "unknown function"),
    ("x + 1", "unknown name"),
    ("lambda: 1", "lambda is not allowed"),
    ("[r for r in 'ab']", "not allowed"),
    ("'text'", "only numbers"),
    ("True + r", "only numbers"),
    ("1j * r", "only numbers"),
    ("r if r else 0", "not allowed"),
    ("r > 0.5", "not allowed"),
    ("r % 2", "not allowed"),
    ("sin(r, 2)", "takes 1 argument"),
    ("clip(r, a_min=0, a_max=1)", "takes 3 argument"),
    ("np.sin(r)", "unknown function"),
    ("sin", "is a function"),
    ("r +", "does not parse"),
    ("", "needs an expression"),
    ("r" + "+r" * 300, "too complex"),
    ("x" * 2000, "longer than"),
])
def test_expression_refusals(text, fragment):
    """Anything outside numbers, r, pi, e, + - * / **, unary +/- and whitelisted calls is an InputError."""
    with pytest.raises(InputError, match=fragment):
        evaluate(make_function("expression", expression=text), R)


def test_expression_deep_nesting_and_nan():
    """Deep nesting is an InputError or a value, never a crash; NaN results name the r where they occur."""
    try:
        compile_expression("(" * 300 + "r" + ")" * 300)
    except InputError:
        pass
    with pytest.raises(InputError, match=r"undefined \(NaN\) at r = "):
        evaluate(make_function("expression", expression="sqrt(r - 0.5)"), R)
    huge = evaluate(make_function("expression", expression="9**9**9 * r"), np.array([0.5]))
    assert np.isinf(huge).all()  # floats overflow to inf; the blend clips them, nothing hangs


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
    with pytest.raises(InputError, match="normal only applies"):
        make_reference("point", points, normal=(0, 0, 1))
    with pytest.raises(InputError, match="direction only applies"):
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
