"""Topology: edge groups and shells against independent references (scipy, sets of sorted edges)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice import procedural


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 100_000), shells=st.integers(1, 6), shuffle=st.booleans())
def test_shell_labels_match_scipy_connected_components(seed, shells, shuffle):
    """Shells are scipy's connected components of the face graph (faces joined by shared edges),
    numbered alike (by first face), for several touching-at-a-vertex or separate shells in any face order."""
    import scipy.sparse
    import scipy.sparse.csgraph

    from heoslice.mesh import edge_groups, shell_labels

    rng = np.random.default_rng(seed)
    parts, offset = [], 0
    for _ in range(shells):
        sphere = procedural.sphere(1.0, int(rng.integers(0, 3)))
        parts.append(sphere.faces + offset)
        offset += len(sphere.vertices) - int(rng.integers(0, 2))  # shells may share one vertex, never an edge
    faces = np.concatenate(parts)
    if shuffle:
        faces = faces[rng.permutation(len(faces))]
    groups = edge_groups(faces)
    same = np.ones(len(groups.order), dtype=bool)
    same[groups.starts] = False
    owner = groups.order // 3
    graph = scipy.sparse.coo_matrix((np.ones(int(same[1:].sum())), (owner[:-1][same[1:]], owner[1:][same[1:]])),
                                    shape=(len(faces), len(faces)))
    expected = scipy.sparse.csgraph.connected_components(graph, directed=False)[1]
    np.testing.assert_array_equal(shell_labels(faces), expected)
    assert shell_labels(faces).max() + 1 == shells


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 100_000), offset=st.sampled_from([0, 2**31 - 64]))
def test_edge_groups_group_every_undirected_edge_in_index_order(seed, offset):
    """Each group is one undirected edge, every face edge is in exactly one group, groups are in order of
    (lower, higher) vertex, within a group the entries are in index order, and ``forward`` says which walk
    their edge from lower to higher (vertex indices far beyond the faces' count, renumbered first, alike)."""
    from heoslice.mesh import edge_groups

    rng = np.random.default_rng(seed)
    faces = offset + rng.integers(0, int(rng.integers(3, 40)), (int(rng.integers(2, 60)), 3))
    groups = edge_groups(faces)
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)[groups.order]
    run = np.cumsum(np.isin(np.arange(len(edges)), groups.starts)) - 1
    assert np.array_equal(np.sort(groups.order), np.arange(3 * len(faces)))
    assert all((edges[run == g] == edges[groups.starts[g]]).all() for g in range(len(groups.starts)))
    assert len({tuple(e) for e in edges[groups.starts]}) == len(groups.starts)
    assert np.all(np.diff(groups.order)[np.diff(run) == 0] > 0)
    first = edges[groups.starts]
    np.testing.assert_array_equal(np.lexsort((first[:, 1], first[:, 0])), np.arange(len(first)))  # by (low, high)
    walked = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)[groups.order]
    np.testing.assert_array_equal(groups.forward, walked[:, 0] < walked[:, 1])



def test_edge_groups_of_a_fan_around_one_vertex_are_the_reference_sort():
    """200,000 triangles fanned round one vertex whose edges arrive in no order (a fan-triangulated CAD face;
    a sort within each vertex's edges would be quadratic in the 400,000 at its hub): grouped exactly as a
    lexsort of (lower, higher, index) groups them."""
    from heoslice.mesh import edge_groups

    rim = np.random.default_rng(3).permutation(np.arange(1, 200_001))
    faces = np.column_stack([np.zeros(len(rim), dtype=np.int64), rim, np.roll(rim, -1)])
    groups = edge_groups(faces)
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    expected = np.lexsort((np.arange(len(edges)), edges[:, 1], edges[:, 0]))
    np.testing.assert_array_equal(groups.order, expected)
