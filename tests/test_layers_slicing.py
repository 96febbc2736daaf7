"""Tests of slicing.py: plane heights, the global intersection filter, segment geometry and direction."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice import procedural
from heoslice.errors import InputError
from heoslice.layers import interpolate_at, plane_heights, slice_mesh


def test_plane_heights_are_layer_centres():
    """z_i = z_min + (i + 1/2) h for i = 0 .. ceil((z_max - z_min) / h) - 1."""
    z = plane_heights(2.0, 3.05, 0.1)
    assert len(z) == 11
    np.testing.assert_allclose(z, 2.0 + (np.arange(11) + 0.5) * 0.1)
    assert len(plane_heights(0.0, 1.0, 0.1)) == 10  # an exact multiple adds no extra layer


def test_plane_heights_refuse_non_positive_layer():
    """A zero or negative layer height is an input error, not an endless loop."""
    with pytest.raises(InputError):
        plane_heights(0.0, 1.0, 0.0)


def random_hull(seed: int) -> trimesh.Trimesh:
    points = np.random.default_rng(seed).normal(size=(40, 3)) * [3.0, 2.0, 4.0]
    return trimesh.convex.convex_hull(points)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), layer=st.floats(0.05, 2.0))
def test_intersection_filter_matches_brute_force(seed, layer):
    """Each triangle is paired with exactly the planes p with z_min < p <= z_max (paper's Table 2)."""
    mesh = random_hull(seed)
    vertices, faces = mesh.vertices, mesh.faces
    z = plane_heights(vertices[:, 2].min(), vertices[:, 2].max(), layer)
    sections = slice_mesh(vertices, faces, z)
    face_z = vertices[faces, 2]
    brute = {(f, k) for f in range(len(faces)) for k, p in enumerate(z)
             if face_z[f].min() < p <= face_z[f].max()}
    assert set(zip(sections.face.tolist(), sections.layer.tolist())) == brute
    assert np.all(np.diff(sections.layer) >= 0)
    for k in range(len(z)):
        assert np.all(sections.layer[sections.layer_slice(k)] == k)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_segments_lie_on_their_edges_and_follow_the_right_hand_rule(seed):
    """Segment ends are on the plane and on their mesh edges; direction is z x outward normal."""
    mesh = random_hull(seed)
    vertices, faces = mesh.vertices, mesh.faces
    z = plane_heights(vertices[:, 2].min(), vertices[:, 2].max(), 0.37)
    s = slice_mesh(vertices, faces, z)
    for edge, t, point in ((s.start_edge, s.start_t, s.start), (s.end_edge, s.end_t, s.end_points())):
        assert np.all((t >= 0) & (t <= 1))
        xyz = interpolate_at(vertices, edge, t)
        np.testing.assert_allclose(xyz[:, 2], z[s.layer], atol=1e-9)
        np.testing.assert_allclose(xyz[:, :2], point, atol=1e-12)
        # both vertices of the edge belong to the segment's face
        tri = faces[s.face]
        assert np.all((tri == edge[:, :1]).any(axis=1) & (tri == edge[:, 1:]).any(axis=1))
    direction = s.end_points() - s.start
    normal = mesh.face_normals[s.face]
    along = direction[:, 0] * -normal[:, 1] + direction[:, 1] * normal[:, 0]
    length = np.linalg.norm(direction, axis=1)
    assert np.all(along[length > 1e-9] > 0)


def segments_written_out(vertices: np.ndarray, faces: np.ndarray, z: np.ndarray) -> dict:
    """Test reference for the slicing rule, pair by pair in Python floats: every (face, plane) with
    z_min < plane <= z_max, grouped by plane in face order; the lone vertex is the corner alone on its side
    (below: z < plane); the segment runs from the edge (before, lone) to (lone, after) when it is below, the
    reverse when above; each edge is named lower vertex first, and its point is
    (v_high - v_low) t + v_low with t = (plane - z_low) / (z_high - z_low)."""
    n = len(vertices)
    rows = []
    for layer, plane in enumerate(z.tolist()):
        for face, corners in enumerate(faces.tolist()):
            heights = [vertices[c][2] for c in corners]
            if not min(heights) < plane <= max(heights):
                continue
            below = [h < plane for h in heights]
            lone = next(i for i in range(3) if below.count(below[i]) == 1)
            after, before = (lone + 1) % 3, (lone + 2) % 3
            ends = (before, after) if below[lone] else (after, before)
            row = {"layer": layer, "face": face}
            for name, other in zip(("start", "end"), ends):
                low, high = sorted((corners[lone], corners[other]))
                t = (plane - vertices[low][2]) / (vertices[high][2] - vertices[low][2])
                row[f"{name}_edge"], row[f"{name}_t"] = [low, high], t
                row[f"{name}_key"] = layer * n * n + low * n + high
                if name == "start":
                    row["start"] = [(vertices[high][axis] - vertices[low][axis]) * t + vertices[low][axis]
                                    for axis in range(2)]
            rows.append(row)
    return {name: np.array([row[name] for row in rows]) for name in rows[0]} if rows else {}


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), layer=st.floats(0.05, 2.0), on_vertices=st.booleans())
def test_segments_are_the_rule_written_out_bit_for_bit(seed, layer, on_vertices):
    """Every array of the sections (layers, faces, edges, keys, positions and points) equals the slicing rule
    written out pair by pair, bit for bit, also with planes exactly through vertices."""
    vertices, faces = random_hull(seed).vertices, random_hull(seed).faces
    if on_vertices:
        z = np.unique(np.round(vertices[:, 2], 1))
        vertices = vertices.copy()
        vertices[::3, 2] = np.round(vertices[::3, 2], 1)  # some corners exactly on the planes
    else:
        z = plane_heights(vertices[:, 2].min(), vertices[:, 2].max(), layer)
    sections = slice_mesh(vertices, faces, z)
    expected = segments_written_out(vertices, faces, z)
    assert len(sections.layer) == len(expected.get("layer", []))
    for name, values in expected.items():
        got = getattr(sections, name)
        np.testing.assert_array_equal(got, values.astype(got.dtype), err_msg=name)
        assert got.tobytes() == values.astype(got.dtype).tobytes(), name
    np.testing.assert_array_equal(sections.offsets, np.searchsorted(sections.layer, np.arange(len(z) + 1)))


def test_shared_edge_points_are_bit_identical():
    """The point where a plane cuts an edge is the same float in both triangles sharing the edge."""
    mesh = procedural.sphere(7.3, 3)
    s = slice_mesh(mesh.vertices, mesh.faces, plane_heights(-7.3, 7.3, 0.31))
    ends = s.end_points()
    by_key = dict(zip(s.start_key.tolist(), map(tuple, s.start.tolist())))
    assert all(by_key[key] == tuple(point) for key, point in zip(s.end_key.tolist(), ends.tolist()))


def test_vertex_on_plane_counts_as_above():
    """A box whose vertex rings lie exactly on planes still gives one segment pair per crossed side face."""
    box = procedural.box((4.0, 4.0, 4.0), z_cuts=(0.5, 1.5))
    z = plane_heights(0.0, 4.0, 0.5)  # 0.25, 0.75, ... never on a vertex ring
    z_on = np.array([0.5, 1.5, 2.0])  # exactly on the cut rings
    for planes in (z, z_on):
        s = slice_mesh(box.vertices, box.faces, planes)
        keys_start = np.sort(s.start_key)
        keys_end = np.sort(s.end_key)
        np.testing.assert_array_equal(keys_start, keys_end)  # every chain closes


def test_empty_when_no_plane_crosses():
    """Planes outside the mesh give no segments and empty layer ranges."""
    box = procedural.box((1.0, 1.0, 1.0))
    s = slice_mesh(box.vertices, box.faces, np.array([5.0, 6.0]))
    assert len(s.layer) == 0 and list(s.offsets) == [0, 0, 0]


def test_interpolate_at_is_linear_along_the_edge():
    """(1 - t) v_lo + t v_hi for scalar and vector attributes."""
    values = np.array([[0.0, 10.0], [4.0, 30.0]])
    edge = np.array([[0, 1], [0, 1]])
    np.testing.assert_allclose(interpolate_at(values, edge, np.array([0.25, 1.0])), [[1.0, 15.0], [4.0, 30.0]])
    np.testing.assert_allclose(interpolate_at(values[:, 0], edge, np.array([0.5, 0.0])), [2.0, 0.0])


@pytest.mark.parametrize("budget", [1, 5_000, 40_000, 10**9])
def test_plane_chunks_partition_the_planes_and_reproduce_the_whole(budget):
    """Slicing run by run gives exactly the segments of slicing everything at once, whatever the budget."""
    from heoslice.layers.slicing import plane_chunks, segments_per_plane, slice_planes

    mesh = procedural.vase()
    z = plane_heights(0.0, 60.0, 0.2)
    whole = slice_mesh(mesh.vertices, mesh.faces, z)
    assert segments_per_plane(mesh.vertices, mesh.faces, z).sum() == len(whole.layer)
    runs = plane_chunks(mesh.vertices, mesh.faces, z, budget)
    assert runs[0][0] == 0 and runs[-1][1] == len(z)
    assert all(a[1] == b[0] for a, b in zip(runs, runs[1:]))
    parts = [slice_planes(mesh.vertices, mesh.faces, z, start, stop) for start, stop in runs]
    np.testing.assert_array_equal(np.concatenate([p.start for p in parts]), whole.start)
    np.testing.assert_array_equal(np.concatenate([p.face for p in parts]), whole.face)
    np.testing.assert_array_equal(np.concatenate([p.layer + start for p, (start, _) in zip(parts, runs)]),
                                  whole.layer)
    if budget >= 40_000:
        per_run = [len(p.layer) for p in parts]
        assert max(per_run) <= budget
