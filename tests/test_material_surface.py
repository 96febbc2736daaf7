"""Point-triangle and nearest-surface distances against brute force.

References: trimesh's closest point on one triangle, and a brute-force minimum over
every triangle of a mesh.
"""

from __future__ import annotations

import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import trimesh
from helpers import brute_force_distance, modules_loaded_by_command
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from heoslice import procedural
from heoslice.material import (
    build_surface_index,
    closest_points_on_triangles,
    point_triangle_distance,
    surface_distance,
)
from heoslice.material.field import R_STEPS, R_TOLERANCE
from heoslice.material.surface import layer_r, packed_layer_steps

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


def test_surface_distance_on_a_fine_sphere_in_chunks():
    """A 5,120-triangle sphere, points near and far, measured in chunks on two threads: brute force, and
    progress follows the chunks."""
    mesh = procedural.sphere(radius=10.0, subdivisions=4)
    index = build_surface_index(mesh.vertices, mesh.faces)
    rng = np.random.default_rng(11)
    points = np.vstack([rng.uniform(-40, 40, size=(80, 3)), rng.normal(size=(40, 3)) * 3])
    calls = []
    ours = surface_distance(points, index, chunk=32, workers=2, progress=lambda done, total: calls.append((done, total)))
    assert np.allclose(ours, brute_force_distance(points, mesh), rtol=0, atol=1e-9)
    assert calls == [(32, 120), (64, 120), (96, 120), (120, 120)]


def test_a_degenerate_triangle_has_no_plane_bound_and_is_still_measured():
    """A collinear triangle (no plane: its row of planes is zeros, so it is never skipped by a plane's distance)
    nearest to points beside it, among triangles whose planes pass near those points: brute force distances."""
    from heoslice.material.surface import _planes

    corners = np.array([[[0, 0, 0], [2, 0, 0], [4, 0, 0]],  # collinear: measured as its segment
                        [[0, 5, -3], [4, 5, -3], [0, 5, 3]],  # a wall whose plane y = 5 is near y = 4 points
                        [[10, 0, 0], [11, 0, 0], [10, 1, 0]]], dtype=float)
    planes = _planes(corners)
    assert np.array_equal(planes[0], np.zeros(4)) and np.allclose(np.abs(planes[1]), [0, 1, 0, 5])
    points = np.array([[1.0, 0.5, 0.0], [3.0, 4.0, 0.0], [2.0, -0.25, 0.1], [5.0, 0.3, 0.0]])
    along = np.clip(points[:, 0], 0.0, 4.0)  # the segment's nearest point, written out (trimesh is not exact there)
    segment = np.linalg.norm(points - np.column_stack([along, np.zeros((len(points), 2))]), axis=1)
    others = brute_force_distance(points, trimesh.Trimesh(corners[1:].reshape(-1, 3), np.arange(6).reshape(2, 3),
                                                          process=False))
    ours = surface_distance(points, build_surface_index(corners.reshape(-1, 3), np.arange(9).reshape(3, 3)))
    assert np.allclose(ours, np.minimum(segment, others), rtol=0, atol=1e-12)
    assert (segment < others).sum() == 3


def _one_by_one(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The least over the triangles of the kernel's own distance to each alone (n,): what the search must find,
    whatever it prunes."""
    return np.min([surface_distance(points, build_surface_index(t, np.array([[0, 1, 2]]))) for t in triangles], axis=0)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), thin=st.floats(-13.0, -3.0), shift=st.sampled_from([0.0, 1e3, 1e4, 1e5]))
def test_the_search_never_prunes_a_nearer_sliver(seed, thin, shift):
    """Slivers (a third corner 10^thin mm off the line of the other two, some under the width whose computed normal
    is rounding noise), beside ordinary triangles, far from the origin too: the hierarchy's search gives exactly
    the least of the kernel's own distances to each triangle alone (the bounds it prunes by, the spheres and the
    planes, never skip a nearer triangle; a plane used as a bound for a sliver did, by 2e-7 mm in 0.5)."""
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=(2, 3))
    across = np.cross(b - a, rng.normal(size=3))
    sliver = np.array([a, b, a + rng.uniform(-0.5, 1.5) * (b - a) + 10.0 ** thin * across / np.linalg.norm(across)])
    others = rng.normal(size=(6, 3, 3)) * 0.3 + (a + b) / 2 + rng.normal(size=(6, 1, 3))
    triangles = np.concatenate([sliver[None], others]) + shift
    points = (a + b) / 2 + rng.normal(size=(40, 3)) * rng.choice([0.05, 0.5, 3.0], size=(40, 1)) + shift
    ours = surface_distance(points, build_surface_index(triangles.reshape(-1, 3), np.arange(21).reshape(7, 3)))
    assert np.array_equal(ours, _one_by_one(points, triangles))


def test_a_sliver_whose_computed_normal_tilts_is_not_pruned_by_its_plane():
    """A review's case: a sliver (angle sine 7e-12) whose computed plane passes 2e-7 mm too far from a point beside
    it, and a small triangle just farther away: the sliver is the nearer, and the search finds it, in either
    order of the triangles."""
    sliver = np.array([[0.345584192064786, 0.8216181435011584, 0.33043707618338714],
                       [-0.4449869335091003, 1.3708597769758128, 0.6012339067906368],
                       [-0.04970137072144151, 1.0962389602408695, 0.46583549148426623]])
    small = np.array([[-0.03986450653153688, 1.0971791157420527, 0.45571856455304594],
                      [-0.0556759290430146, 1.1081639484115458, 0.46113450116519095],
                      [-0.05356333631136168, 1.083374128926017, 0.48065376861622666]])
    point = np.array([[-0.34026468550596145, 0.8295147493186374, 0.1585389646419595]])
    for triangles in (np.array([sliver, small]), np.array([small, sliver])):
        got = surface_distance(point, build_surface_index(triangles.reshape(-1, 3), np.arange(6).reshape(2, 3)))
        assert np.array_equal(got, _one_by_one(point, triangles))
        assert got[0] < 0.5


def test_coloring_by_a_surface_loads_no_numba(tmp_path):
    """`heoslice color --ref surface` (a fresh process) runs the surface distance's compiled kernels: it never
    imports numba or LLVM, which would compile them just in time on a machine's first run."""
    model, lesion = tmp_path / "vase.ply", tmp_path / "lesion.ply"
    model.write_bytes(procedural.vase(sections=16, rings_outer=10, rings_inner=8).export(file_type="ply"))
    lesion.write_bytes(procedural.sphere(radius=3.0, subdivisions=2, center=(0.0, 0.0, 30.0)).export(file_type="ply"))
    args = ["color", str(model), "--ref", "surface", "--surface", str(lesion), "-o", str(tmp_path / "out.ply")]
    assert modules_loaded_by_command(args, ("numba", "llvmlite")) == []


def test_the_nearest_distance_kernel_lets_other_threads_run():
    """While the compiled nearest-distance kernel works, another Python thread keeps running: the kernel
    releases the GIL (as numba's nogil does just in time), so surface_distance's threads measure side by side.
    With a switch interval longer than the call, a kernel that held the GIL would let the waiting counter
    thread in only after the call, when nothing is counted any more."""
    from heoslice.material.surface_kernels import nearest_distances

    mesh = procedural.sphere(radius=10.0, subdivisions=4)
    index = build_surface_index(mesh.vertices, mesh.faces)
    points = np.random.default_rng(5).uniform(-30, 30, size=(20_000, 3))
    out = np.empty(len(points))
    nearest_distances(points[:10], index.tree, out[:10])
    counted, working, stop = [0], threading.Event(), threading.Event()

    def count() -> None:
        while not stop.is_set():
            if working.is_set():
                counted[0] += 1

    interval = sys.getswitchinterval()
    counter = threading.Thread(target=count)
    try:
        sys.setswitchinterval(0.5)
        counter.start()
        working.set()
        nearest_distances(points, index.tree, out)
        working.clear()
    finally:
        stop.set()
        sys.setswitchinterval(interval)
        counter.join()
    assert counted[0] > 0
    assert np.allclose(out[:200], brute_force_distance(points[:200], mesh), rtol=0, atol=1e-9)


def test_curve_order_is_a_permutation_that_keeps_neighbours_close():
    """curve_order is a permutation of the points, and consecutive points in it are on average far closer
    than in a random order (what makes the previous nearest triangle a tight first bound)."""
    from heoslice.material.surface import curve_order

    rng = np.random.default_rng(3)
    points = rng.uniform(-50, 50, size=(20_000, 3))
    order = curve_order(points)
    assert np.array_equal(np.sort(order), np.arange(len(points)))
    step = np.linalg.norm(np.diff(points[order], axis=0), axis=1).mean()
    shuffled = np.linalg.norm(np.diff(points, axis=0), axis=1).mean()
    assert step < shuffled / 10, (step, shuffled)
    assert len(surface_distance(np.empty((0, 3)), build_surface_index(*_tetra()))) == 0


def _tetra():
    return np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float), np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2],
                                                                                   [1, 2, 3]])


# --- exact on non-convex references (issue 19) ----------------------------------------------

def literal_point_triangle_distance(point: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Distance (m,) from one point (3,) to each triangle (m, 3, 3), written out independently of heoslice:
    the foot of the perpendicular on the triangle's plane when it lies inside the triangle (all three
    edge cross products point along the normal), else the nearest of the three edges as segments."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    normal = np.cross(b - a, c - a)
    length = np.linalg.norm(normal, axis=1)
    unit = normal / np.where(length > 0, length, 1.0)[:, None]
    height = np.einsum("ij,ij->i", point - a, unit)
    foot = point - height[:, None] * unit
    inside = length > 0
    for start, end in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("ij,ij->i", np.cross(end - start, foot - start), normal) >= 0
    best = np.where(inside, np.abs(height), np.inf)
    for start, end in ((a, b), (b, c), (c, a)):
        edge = end - start
        length2 = np.einsum("ij,ij->i", edge, edge)
        t = np.clip(np.einsum("ij,ij->i", point - start, edge) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
        gap = point - (start + t[:, None] * edge)
        best = np.minimum(best, np.sqrt(np.einsum("ij,ij->i", gap, gap)))
    return best


def literal_surface_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """min over every triangle of :func:`literal_point_triangle_distance`, point by point."""
    triangles = vertices[faces]
    return np.array([literal_point_triangle_distance(p, triangles).min() for p in points])


def wavy_sphere() -> tuple[np.ndarray, np.ndarray]:
    """A sphere of radius 20 mm with bumps of +-25 % (non-convex, 5,120 triangles)."""
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    v = np.asarray(mesh.vertices)
    radius = 20.0 * (1.0 + 0.25 * np.sin(5 * v[:, 0]) * np.sin(4 * v[:, 1]) * np.cos(3 * v[:, 2]))
    return v * radius[:, None], np.asarray(mesh.faces)


def torus_knot(p: int = 2, q: int = 3, along: int = 240, around: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """A tube of radius 1.5 mm along a (p, q) torus knot of about 30 mm (5,760 triangles)."""
    t = np.linspace(0.0, 2 * np.pi, along, endpoint=False)
    curve = np.column_stack([(2 + np.cos(q * t)) * np.cos(p * t), (2 + np.cos(q * t)) * np.sin(p * t),
                             -np.sin(q * t)]) * 5.0
    tangent = np.roll(curve, -1, axis=0) - np.roll(curve, 1, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1)[:, None]
    side = np.cross(tangent, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side, axis=1)[:, None]
    up = np.cross(side, tangent)
    angle = np.linspace(0.0, 2 * np.pi, around, endpoint=False)
    ring = np.cos(angle)[None, :, None] * side[:, None] + np.sin(angle)[None, :, None] * up[:, None]
    vertices = (curve[:, None] + 1.5 * ring).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(along), np.arange(around), indexing="ij")
    a, b = i * around + j, ((i + 1) % along) * around + j
    c, d = ((i + 1) % along) * around + (j + 1) % around, i * around + (j + 1) % around
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return vertices, faces


def nearly_touching() -> tuple[np.ndarray, np.ndarray]:
    """Two spheres of radius 5 mm, 0.01 mm apart (two parts, 2 x 1,280 triangles)."""
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=5.0)
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    return np.vstack([v - [5.005, 0, 0], v + [5.005, 0, 0]]), np.vstack([f, f + len(v)])


def shipped_vase() -> tuple[np.ndarray, np.ndarray]:
    """The shipped example vase (thin-walled, open at the top, 6,144 triangles)."""
    from heoslice.mesh import load_mesh

    mesh = load_mesh(Path(__file__).resolve().parents[1] / "examples" / "vase.ply")
    return mesh.vertices, mesh.faces


REFERENCES = {"vase": shipped_vase, "wavy sphere": wavy_sphere, "torus knot": torus_knot,
              "nearly touching": nearly_touching}
_INDEXED: dict = {}


def indexed(name: str):
    """(vertices, faces, SurfaceIndex) of a reference, built once per test session."""
    if name not in _INDEXED:
        vertices, faces = REFERENCES[name]()
        _INDEXED[name] = (vertices, faces, build_surface_index(vertices, faces))
    return _INDEXED[name]


unit_points = arrays(np.float64, (12, 3), elements=st.floats(0.0, 1.0, allow_nan=False))
near_points = st.tuples(arrays(np.int64, (12,), elements=st.integers(0, 10 ** 9)),
                        arrays(np.float64, (12, 3), elements=st.floats(0.0, 1.0, allow_nan=False)),
                        arrays(np.float64, (12,), elements=st.floats(-3.0, 3.0, allow_nan=False)))


@pytest.mark.parametrize("name", list(REFERENCES))
@settings(max_examples=15, deadline=None)
@given(box=unit_points, near=near_points)
def test_exact_on_non_convex_references(name, box, near):
    """Distances to the vase, a wavy sphere, a torus knot and two nearly touching parts equal a literal brute
    force within 1e-6 mm, for points anywhere around the part and points just off its surface (on either side,
    where a downhill walk would stop at a local minimum)."""
    vertices, faces, index = indexed(name)
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    around = low - 0.3 * (high - low) + box * 1.6 * (high - low)
    which, weights, offset = near
    triangles = vertices[faces[which % len(faces)]]
    weights = weights / np.maximum(weights.sum(axis=1), 1e-12)[:, None]
    normal = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
    close = np.einsum("ij,ijk->ik", weights, triangles) + offset[:, None] * normal
    points = np.vstack([around, close])
    assert np.allclose(surface_distance(points, index), literal_surface_distance(points, vertices, faces),
                       rtol=0, atol=1e-6)


def test_walk_trap_of_issue_19():
    """The points where a downhill walk stopped at a local minimum: inside the vase's cavity, nearer the far
    wall's inside than the near wall's outside, equal brute force."""
    vertices, faces, index = indexed("vase")
    centre = (vertices.min(axis=0) + vertices.max(axis=0)) / 2
    rng = np.random.default_rng(19)
    points = centre + rng.normal(scale=[8.0, 8.0, 15.0], size=(300, 3))
    assert np.allclose(surface_distance(points, index), literal_surface_distance(points, vertices, faces),
                       rtol=0, atol=1e-6)


# --- a layer's r from the lattice's proven bounds (surface.layer_r) -------------------------------------------------

def _brute_r(triangles: np.ndarray, points: np.ndarray, r_range: tuple[float, float]) -> np.ndarray:
    """The literal r of points (n, 3): min over every triangle of trimesh's closest point, normalised and clipped."""
    n, m = len(points), len(triangles)
    feet = trimesh.triangles.closest_point(np.tile(triangles, (n, 1, 1)), np.repeat(points, m, axis=0))
    distance = np.linalg.norm(feet - np.repeat(points, m, axis=0), axis=1).reshape(n, m).min(axis=1)
    return np.clip((distance - r_range[0]) / (r_range[1] - r_range[0]), 0.0, 1.0)


@settings(max_examples=60, deadline=None)
@given(corners=st.integers(1, 4).flatmap(lambda k: arrays(np.float64, (3 * k, 3),
                                                           elements=st.floats(-3, 3, allow_nan=False, width=32))),
       z=st.floats(-4, 4), pitch=st.floats(0.02, 0.4), start=st.floats(0.0, 2.0), span=st.floats(0.02, 6.0),
       top=st.sampled_from([2, 3, 8, 16, 64]), tolerance=st.sampled_from([1e-3, 1e-2, 0.1]),
       seed=st.integers(0, 2 ** 32 - 1), density=st.sampled_from([0.8, 0.3, 0.05]))
def test_layer_r_is_within_its_proven_bound_of_the_brute_force_r(corners, z, pitch, start, span, top, tolerance,
                                                                 seed, density):
    """Random triangles, layers, pixel pitches, ranges and cell sizes: at every solid pixel the true r (brute force)
    lies within the bound layer_r reports for it, and that bound is at most tolerance / 2. A bound that claimed
    more than the Lipschitz, second-order or nearby-triangle argument proves fails here (the second-order bound is
    nearly tight for a cell far from a triangle's corner). Triangles of real area: trimesh's closest point, the
    reference, is not exact on degenerate ones. Sparse layers with an empty band of columns: cells inside a row's
    solid span that hold no solid pixel, which the cells' emptiness test must tell from ones that do."""
    triangles = corners.reshape(-1, 3, 3)
    assume((np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1)
            > 1e-3).all())
    index = build_surface_index(corners, np.arange(len(corners)).reshape(-1, 3))
    rng = np.random.default_rng(seed)
    solid = rng.random((24, 40)) < density
    gap = rng.integers(0, 40)
    solid[:, gap:gap + rng.integers(0, 20)] = False
    frame = (-4.0 + pitch / 2, pitch, 4.0 - pitch / 2, -pitch, z)
    r_range = (start, start + span)
    r, spread = layer_r(solid, frame, index, r_range, tolerance, top=top, with_spread=True)
    rows, cols = np.nonzero(solid)
    points = np.column_stack([frame[0] + cols * pitch, frame[2] - rows * pitch, np.full(len(rows), z)])
    truth = _brute_r(triangles, points, r_range)
    assert (spread[rows, cols] <= tolerance / 2 + 1e-12).all()
    assert (np.abs(r[rows, cols] - truth) <= spread[rows, cols] + 1e-9).all()
    assert (r[~solid] == 0).all()


def test_layer_r_settles_far_cells_by_the_second_order_bound():
    """A layer 30 mm from a small triangle, 0.05 mm pixels, r over 0 .. 40 mm: the 64-pixel cells are halved once
    and the second-order bound settles the 32-pixel cells ((a^2 + b^2) / 8m is about 0.022 mm, r within 2.8e-4; no pixel
    measured exactly: every reported bound is positive), every r within 5e-4 of the truth; the Lipschitz bound
    alone (h = 1.1 mm on a 32-pixel cell) could not settle them at 1e-3."""
    corners = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    index = build_surface_index(corners, np.array([[0, 1, 2]]))
    solid = np.ones((128, 128), dtype=bool)
    frame = (-3.0, 0.05, 3.0, -0.05, 30.0)
    r, spread = layer_r(solid, frame, index, (0.0, 40.0), 1e-3, top=64, with_spread=True)
    rows, cols = np.nonzero(solid)
    points = np.column_stack([frame[0] + cols * 0.05, frame[2] - rows * 0.05, np.full(len(rows), 30.0)])
    truth = _brute_r(corners[None], points, (0.0, 40.0))
    assert (spread > 0).all() and spread.max() < 3e-4, (spread.min(), spread.max())
    assert np.abs(r[rows, cols] - truth).max() <= 5e-4


def test_layer_r_settles_cells_near_a_flat_surface_by_its_tangent_planes():
    """A layer 0.16-0.27 mm over a large tilted triangle, 0.02 mm pixels, r over 0 .. 1 mm at 1e-3: the
    second-order bound cannot settle even a 2-pixel cell there ((a^2 + b^2) / 8m is at least 2.5e-3 mm), but d is
    a plane's distance, which its tangent planes give exactly: every pixel is settled by a bound (none measured:
    every reported bound is positive) and within it of the brute-force r."""
    vertices = np.array([[-5.0, -5.0, -0.2], [5.0, -5.0, 0.3], [5.0, 5.0, 0.3], [-5.0, 5.0, -0.2]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    index = build_surface_index(vertices, faces)
    solid = np.ones((96, 112), dtype=bool)
    solid[40:50, 30:90] = False
    frame = (1.5, 0.02, -0.5, -0.02, 0.4)
    r, spread = layer_r(solid, frame, index, (0.0, 1.0), 1e-3, top=64, with_spread=True)
    rows, cols = np.nonzero(solid)
    points = np.column_stack([frame[0] + cols * 0.02, frame[2] - rows * 0.02, np.full(len(rows), 0.4)])
    truth = _brute_r(vertices[faces], points, (0.0, 1.0))
    assert (spread[rows, cols] > 0).all() and spread.max() <= 5e-4 + 1e-12
    assert (np.abs(r[rows, cols] - truth) <= spread[rows, cols] + 1e-9).all()


@pytest.mark.parametrize("steps", [65535, 1000, 1])
def test_layer_r_steps_are_the_rounded_r(steps):
    """With ``steps``, each solid pixel gets round(r steps) (uint16) of the r it gets without them."""
    corners = procedural.sphere(radius=2.0, subdivisions=2)
    index = build_surface_index(corners.vertices, corners.faces)
    solid = np.random.default_rng(3).random((50, 60)) < 0.7
    frame = (-3.0, 0.1, 2.5, -0.1, 0.4)
    r = layer_r(solid, frame, index, (0.0, 3.0), 1e-3)
    codes = layer_r(solid, frame, index, (0.0, 3.0), 1e-3, steps=steps)
    assert codes.dtype == np.uint16
    assert np.array_equal(codes[solid], np.floor(r[solid] * steps + 0.5).astype(int))


def test_packed_layer_steps_read_the_bits_as_layer_r_reads_the_layer():
    """Steps from packed rows, the layer's columns starting at byte 2 of each row and ending inside a byte (a width
    not a multiple of 8, bits set past it), are layer_r's steps of the same pixels at every solid pixel; rows with
    a solid pixel only in their first or last column or none at all included."""
    corners = procedural.sphere(radius=2.0, subdivisions=2)
    index = build_surface_index(corners.vertices, corners.faces)
    rng = np.random.default_rng(8)
    layer = rng.random((70, 83)) < 0.4
    layer[5] = False
    layer[6], layer[7] = False, False
    layer[6, 0] = layer[7, 82] = True
    wide = np.zeros((70, 16 + 88), dtype=bool)
    wide[:, 16:16 + 83] = layer
    wide[:, 16 + 83:] = True  # past the layer's last column: never read as its pixels
    wide[:, :16] = True
    frame = (-3.0, 0.08, 2.5, -0.08, 0.3)
    expected = layer_r(layer, frame, index, (0.0, 3.0), 1e-3, steps=R_STEPS)
    codes = packed_layer_steps(np.packbits(wide, axis=1), 16, 83, frame, index, (0.0, 3.0), 1e-3, R_STEPS)
    assert codes.shape == layer.shape
    assert np.array_equal(codes[layer], expected[layer])


@pytest.mark.parametrize("steps", [0, 65536])
def test_steps_beyond_uint16_are_refused(steps):
    """r's steps are written as uint16: 0 or more than 65535 steps is a ValueError, not a wrapped code."""
    corners = procedural.sphere(radius=2.0, subdivisions=1)
    index = build_surface_index(corners.vertices, corners.faces)
    with pytest.raises(ValueError, match="steps"):
        layer_r(np.ones((4, 4), bool), (-3.0, 0.1, 2.5, -0.1, 0.4), index, (0.0, 3.0), 1e-3, steps=steps)
