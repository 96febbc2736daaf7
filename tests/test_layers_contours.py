"""Tests of contours.py: loops chained through shared edges, orientation, hierarchy, open meshes."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
import trimesh
from helpers import contours_of, manifold_areas
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice import procedural
from heoslice.layers import plane_heights, slice_mesh
from heoslice.layers.contours import build_contours
from heoslice.layers.contours_kernels import loops_by_keys

REFERENCE_MESHES = {
    "sphere": lambda: procedural.sphere(25.0, 5),
    "torus": lambda: procedural.torus(20.0, 6.0),
    "vase": lambda: procedural.vase(),
    "box on planes": lambda: procedural.box((10.0, 8.0, 6.0), z_cuts=(0.25, 0.75, 3.0)),
    "shell with island": lambda: procedural.shell_with_island(),
}


@pytest.mark.parametrize("name", REFERENCE_MESHES)
def test_layer_areas_match_manifold3d(name):
    """Per-layer contour area within 1e-5 relative of manifold3d's slice at the same z."""
    mesh = REFERENCE_MESHES[name]()
    z, contours = contours_of(mesh, 0.25)
    reference = manifold_areas(mesh.vertices, mesh.faces, z)
    ours = contours.layer_area()
    solid = reference > 1e-9
    np.testing.assert_allclose(ours[solid], reference[solid], rtol=1e-5)
    assert np.all(np.abs(ours[~solid]) < 1e-9)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 100_000), layer=st.floats(0.05, 1.0))
def test_random_convex_solids_match_manifold3d(seed, layer):
    """Any convex hull: one counter-clockwise loop per crossed layer, area as manifold3d's slice."""
    points = np.random.default_rng(seed).normal(size=(60, 3)) * [5.0, 3.0, 4.0]
    mesh = trimesh.convex.convex_hull(points)
    z, contours = contours_of(mesh, layer)
    reference = manifold_areas(mesh.vertices, mesh.faces, z)
    np.testing.assert_allclose(contours.layer_area(), reference, rtol=1e-5, atol=1e-9)
    assert np.all(contours.area > 0) and not contours.closed_by_join.any()
    # a plane above the top (the last layer centre can be) crosses nothing
    expected = (z < mesh.vertices[:, 2].max()).astype(int)
    np.testing.assert_array_equal(np.bincount(contours.layer, minlength=len(z)), expected)


def test_loops_are_simple_closed_polygons_through_shared_edges():
    """Consecutive loop points are joined by one triangle, and every loop is a simple polygon."""
    mesh = procedural.torus(20.0, 6.0)
    _, contours = contours_of(mesh, 0.5)
    for loop in range(contours.loop_count):
        ring = contours.loop_points(loop)
        assert shapely.LinearRing(ring).is_simple
        edges = contours.point_edge[contours.offsets[loop]:contours.offsets[loop + 1]]
        following = np.roll(edges, -1, axis=0)
        # consecutive intersection edges share a vertex (they bound the same triangle)
        shares = (edges[:, :1] == following).any(axis=1) | (edges[:, 1:] == following).any(axis=1)
        assert shares.all()


def test_torus_layers_have_an_outer_ring_and_a_hole():
    """Outer rings run counter-clockwise, holes clockwise, and a hole's family is its outer ring."""
    _, contours = contours_of(procedural.torus(20.0, 6.0), 0.5)
    for layer in range(len(contours.layer_offsets) - 1):
        loops = np.arange(contours.layer_offsets[layer], contours.layer_offsets[layer + 1])
        assert len(loops) == 2
        outer, hole = loops[np.argsort(-contours.area[loops])]
        assert contours.area[outer] > 0 > contours.area[hole]
        assert contours.parent[hole] == outer and contours.family[hole] == outer
        assert contours.parent[outer] == -1 and contours.family[outer] == outer


def test_island_inside_a_hole_is_a_family_of_its_own():
    """Outer ring + cavity form one family; the island floating in the cavity is a second family."""
    mesh = procedural.shell_with_island(outer=20.0, cavity=12.0, island=5.0)
    z, contours = contours_of(mesh, 1.0)
    middle = int(np.argmin(np.abs(z - z.mean())))
    loops = np.arange(contours.layer_offsets[middle], contours.layer_offsets[middle + 1])
    assert len(loops) == 3
    outer, island, hole = loops[np.argsort(-contours.area[loops])]
    assert contours.area[hole] < 0 < contours.area[island]
    assert contours.family[hole] == outer
    assert contours.parent[island] == hole and contours.family[island] == island
    assert len(np.unique(contours.family[loops])) == 2


def test_nested_shell_is_not_a_hole():
    """A lesion shell inside an organ gives a second counter-clockwise loop whose parent is the organ."""
    mesh = procedural.nested_shells(outer=20.0, inner=6.0, offset=(4.0, 0.0, 0.0))
    z, contours = contours_of(mesh, 1.0)
    middle = int(np.argmin(np.abs(z)))
    loops = np.arange(contours.layer_offsets[middle], contours.layer_offsets[middle + 1])
    organ, lesion = loops[np.argsort(-contours.area[loops])]
    assert contours.area[lesion] > 0
    assert contours.parent[lesion] == organ and contours.family[lesion] == lesion
    shell = np.concatenate([np.zeros(1280 * 4, int), np.ones(1280 * 4, int)])  # icosphere(4) has 5120 faces
    assert shell[contours.face[organ]] != shell[contours.face[lesion]]


def test_open_mesh_chains_are_closed_and_reported():
    """Removing the top and one side of a box leaves open chains, closed by joining their ends."""
    box = procedural.box((10.0, 10.0, 10.0))
    keep = np.ones(len(box.faces), dtype=bool)
    keep[[2, 3]] = False  # one side face pair
    z = plane_heights(0.0, 10.0, 1.0)
    contours = build_contours(slice_mesh(box.vertices, box.faces[keep], z))
    assert contours.closed_by_join.all() and contours.loop_count == len(z)
    np.testing.assert_allclose(contours.layer_area(), 100.0)


def test_vertices_on_planes_give_no_duplicate_points():
    """A box cut exactly through its vertex rings yields 4-point loops with the exact square area."""
    box = procedural.box((4.0, 3.0, 2.0), z_cuts=(0.5, 1.0, 1.5))
    contours = build_contours(slice_mesh(box.vertices, box.faces, np.array([0.5, 1.0, 1.5])))
    assert contours.loop_count == 3
    assert np.all(np.diff(contours.offsets) == 4)
    np.testing.assert_allclose(contours.area, 12.0)


def walked_loops(start_key: np.ndarray, end_key: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Test reference for the chaining: each end, in index order, takes the next unused start of its key (a
    brute-force pass over the keys); then every chain is walked node by node, a cycle from its smallest
    segment and an open chain from its head, and the loops are sorted by their smallest segment."""
    following = np.full(len(start_key), -1)
    for key in set(end_key.tolist()):
        enders, starters = np.flatnonzero(end_key == key), np.flatnonzero(start_key == key)
        for k in range(min(len(enders), len(starters))):
            following[enders[k]] = starters[k]
    heads = set(range(len(start_key))) - set(following.tolist())
    loops, seen = [], set()
    for head in sorted(heads):
        loop = [head]
        while following[loop[-1]] >= 0:
            loop.append(int(following[loop[-1]]))
        loops.append((min(loop), loop, True))
        seen.update(loop)
    for root in range(len(start_key)):
        if root not in seen:
            loop = [root]
            while following[loop[-1]] != root:
                loop.append(int(following[loop[-1]]))
            loops.append((root, loop, False))
            seen.update(loop)
    loops.sort()
    order = np.array([node for _, loop, _ in loops for node in loop], dtype=np.int64)
    offsets = np.cumsum([0] + [len(loop) for _, loop, _ in loops])
    return order, offsets, np.array([is_open for _, _, is_open in loops], dtype=bool)


def test_chaining_links_matching_keys_and_keeps_dangling_ends_open():
    """Each segment is followed by the one starting on its end edge; a chain with an unmatched end is open."""
    start = np.array([10, 20, 30, 40, 50])
    end = np.array([20, 30, 10, 99, 40])
    order, offsets, open_chain = loops_by_keys(start, end)
    np.testing.assert_array_equal(order, [0, 1, 2, 4, 3])
    np.testing.assert_array_equal(offsets, [0, 3, 5])
    np.testing.assert_array_equal(open_chain, [False, True])


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 100_000), size=st.integers(0, 60), distinct=st.integers(1, 15))
def test_chaining_matches_walking_the_kth_end_to_the_kth_start(seed, size, distinct):
    """With repeated keys (non-manifold edges) the k-th segment (in index order) ending on a key is followed
    by the k-th starting on it, and the loops, their order and their open flags are those of the brute-force
    walk; small and huge keys alike (keys of different layers are ~2^62 apart)."""
    rng = np.random.default_rng(seed)
    scale = int(rng.choice([1, 10**17]))
    start = rng.integers(0, distinct, size) * scale
    end = rng.integers(0, distinct, size) * scale
    for got, expected in zip(loops_by_keys(start, end), walked_loops(start, end)):
        np.testing.assert_array_equal(got, expected)


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 100_000), size=st.integers(1, 200))
def test_chaining_walks_disjoint_cycles_and_paths_from_their_smallest_node_and_head(seed, size):
    """Random disjoint cycles and paths (each segment's end key the next one's start key, a cycle's last
    back to its first) chain into exactly those loops, as the brute-force walk finds them."""
    rng = np.random.default_rng(seed)
    nodes = rng.permutation(size)
    start, end = np.arange(size) * 7, np.arange(size) * 7 + 3  # unmatched unless linked below
    cuts = np.sort(rng.choice(np.arange(1, size), size=min(size - 1, int(rng.integers(0, 8))), replace=False))
    for chain in np.split(nodes, cuts):
        end[chain[:-1]] = start[chain[1:]]
        if rng.random() < 0.5:
            end[chain[-1]] = start[chain[0]]  # a cycle (a single node may be its own successor)
    for got, expected in zip(loops_by_keys(start, end), walked_loops(start, end)):
        np.testing.assert_array_equal(got, expected)


def test_contours_without_hierarchy_are_the_same_loops():
    """hierarchy=False gives the same loops, points and areas, and leaves parent and family out."""
    mesh = procedural.shell_with_island()
    z = plane_heights(mesh.vertices[:, 2].min(), mesh.vertices[:, 2].max(), 0.5)
    sections = slice_mesh(mesh.vertices, mesh.faces, z)
    full, plain = build_contours(sections), build_contours(sections, hierarchy=False)
    assert plain.parent is None and plain.family is None and (full.parent >= 0).any()
    for name in ("points", "point_edge", "point_t", "offsets", "layer", "area", "closed_by_join", "face",
                 "layer_offsets"):
        np.testing.assert_array_equal(getattr(plain, name), getattr(full, name))


def test_overlapping_loops_of_a_broken_mesh_get_parents_that_end():
    """Two loops that cross (a self-intersecting mesh), each holding the other's first vertex: only the larger
    can be the smaller's parent, so the parents form no cycle (they did, and grading hung following them)."""
    from heoslice.layers.contours import loop_parents

    small = np.array([[10.0, 10.0], [0.0, 10.0], [0.0, 0.0], [10.0, 0.0]])
    large = np.array([[0.5, 0.5], [10.7, 0.5], [10.7, 10.7], [0.5, 10.7]])
    points = np.concatenate([small, large])
    area = np.array([shapely.Polygon(small).area, shapely.Polygon(large).area])
    parent = loop_parents(points, np.array([0, 4, 8]), np.array([0, 0]), area)
    assert list(parent) == [1, -1]


def _pyramid(apex_up: bool = True) -> trimesh.Trimesh:
    """A square pyramid, base 4 x 4 mm at z = 0, apex at z = 2 (or upside down: base at 2, apex at 0)."""
    vertices = np.array([[-2.0, -2.0, 0.0], [2.0, -2.0, 0.0], [2.0, 2.0, 0.0], [-2.0, 2.0, 0.0], [0.0, 0.0, 2.0]])
    faces = np.array([[0, 2, 1], [0, 3, 2], [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    if not apex_up:
        vertices[:, 2] = 2.0 - vertices[:, 2]
        faces = faces[:, ::-1]
    return trimesh.Trimesh(vertices, faces, process=False)


def _step(overhang: bool) -> trimesh.Trimesh:
    """One closed solid of two blocks: a 6 x 6 x 1 mm slab with a 2 x 2 x 1 mm block on it (or, as an
    overhang, the block under the slab); the step's horizontal face lies at z = 1."""
    import manifold3d

    slab, block = manifold3d.Manifold.cube([6.0, 6.0, 1.0]), manifold3d.Manifold.cube([2.0, 2.0, 1.0])
    part = (slab.translate([0.0, 0.0, 1.0]) + block.translate([2.0, 2.0, 0.0]) if overhang
            else slab + block.translate([2.0, 2.0, 1.0]))
    mesh = part.to_mesh()
    return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts), process=False)


def _closed_loops(contours) -> bool:
    return not contours.closed_by_join.any() and bool(np.all(np.diff(contours.offsets) >= 3))


def test_an_apex_on_a_plane_gives_no_loop():
    """Singular point, apex: a pyramid's apex pointing up exactly on a plane leaves no loop in that layer (the
    section just below it shrinks to the apex), not a one-point loop of zero area; one pointing down exactly on
    a plane touches nothing; the layer below is the exact square section."""
    for apex_up, planes in ((True, [1.0, 2.0]), (False, [0.0, 1.0])):
        mesh = _pyramid(apex_up)
        contours = build_contours(slice_mesh(mesh.vertices, mesh.faces, np.array(planes)))
        at_apex = 1 if apex_up else 0
        assert contours.layer_offsets[at_apex + 1] - contours.layer_offsets[at_apex] == 0
        assert contours.loop_count == 1 and _closed_loops(contours)
        np.testing.assert_allclose(contours.layer_area()[1 - at_apex], 4.0)


@pytest.mark.parametrize("overhang", [False, True])
def test_a_face_on_a_plane_belongs_to_the_section_just_below(overhang):
    """Singular points, face: a horizontal face exactly on a plane gives closed loops with the area of the
    section just below the plane (the symbolic rule moves the plane down): the slab's 36 mm^2 under a block
    standing on it, the block's 4 mm^2 under an overhanging slab."""
    mesh = _step(overhang)
    exact = build_contours(slice_mesh(mesh.vertices, mesh.faces, np.array([1.0])))
    below = build_contours(slice_mesh(mesh.vertices, mesh.faces, np.array([1.0 - 1e-7])))
    assert _closed_loops(exact)
    np.testing.assert_allclose(exact.layer_area(), 4.0 if overhang else 36.0)
    np.testing.assert_allclose(exact.layer_area(), below.layer_area(), rtol=1e-6)


def test_an_edge_on_a_plane_gives_closed_loops_with_the_section_area():
    """Singular points, edges: a plane through a ring of a box's vertices (every side's edge on it) and
    through a tilted box's single edge gives closed loops with the area of the section just below; a ridge (the
    tilted box's top edge) on a plane leaves only a loop of zero area along it."""
    box = procedural.box((4.0, 3.0, 2.0), z_cuts=(1.0,))
    tilted = trimesh.creation.box((2.0, 2.0, 2.0))
    tilted.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 4, [1.0, 0.0, 0.0]))
    edge_z = float(tilted.vertices[:, 2].max())  # an edge of the rotated cube is its top
    for mesh, plane in ((box, 1.0), (tilted, 0.0), (tilted, edge_z - 1e-3)):
        exact = build_contours(slice_mesh(mesh.vertices, mesh.faces, np.array([plane])))
        below = build_contours(slice_mesh(mesh.vertices, mesh.faces, np.array([plane - 1e-9])))
        assert _closed_loops(exact)
        np.testing.assert_allclose(exact.layer_area(), below.layer_area(), rtol=1e-6)
    on_top_edge = build_contours(slice_mesh(tilted.vertices, tilted.faces, np.array([edge_z])))
    np.testing.assert_allclose(on_top_edge.layer_area(), 0.0, atol=1e-12)
