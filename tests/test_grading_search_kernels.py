"""Tests of heoslice.grading.search_kernels: the edge tree's chunks and capsules, the hierarchy walk that
gathers the chunks within a radius and the nearest-edge search over groups of points against brute force (every
edge tried, float64 numpy), and the chunk order sorted without allocating against numba's np.argsort."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from helpers import brute_squared, random_rings, tree_of
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.grading.edges import ring_edges
from heoslice.grading.lattice_kernels import feet
from heoslice.grading.search_kernels import _INSERTION_SORT, _ascending, _candidates, edge_tree, nearest_in_groups


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(1, 4))
def test_candidates_are_exactly_the_chunks_within_the_radius(seed, rings):
    """The hierarchy walk returns, once each, exactly the chunks (runs of eight edges) whose bounding box
    comes within each point's radius, so every edge within the radius is in one of them (brute force over
    all edges; the hierarchy must not lose edges in any subtree)."""
    rng = np.random.default_rng(seed)
    edges = random_rings(rng, rings)
    qx, qy = rng.uniform(-80, 80, 40), rng.uniform(-80, 80, 40)
    radius = rng.uniform(0.0, 60.0, 40)
    boxes, level_start, _ = tree_of(edges)
    start, found = _candidates(qx, qy, radius, boxes, level_start)
    chunk = np.arange(len(edges.x)) // 8
    first = np.arange(0, len(edges.x), 8)
    x0, x1 = np.minimum(edges.x, edges.x + edges.vx), np.maximum(edges.x, edges.x + edges.vx)
    y0, y1 = np.minimum(edges.y, edges.y + edges.vy), np.maximum(edges.y, edges.y + edges.vy)
    low = np.column_stack([np.minimum.reduceat(x0, first), np.minimum.reduceat(y0, first)])
    high = np.column_stack([np.maximum.reduceat(x1, first), np.maximum.reduceat(y1, first)])
    within = brute_squared(qx, qy, edges) <= radius[:, None] ** 2
    for g in range(40):
        got = found[start[g]:start[g + 1]]
        assert len(got) == len(set(got.tolist()))
        gap = np.maximum(np.maximum(low - [qx[g], qy[g]], [qx[g], qy[g]] - high), 0.0)
        # points exactly on the radius may go either way in rounding; the test radii are random
        assert set(got.tolist()) == set(np.nonzero(np.hypot(gap[:, 0], gap[:, 1]) <= radius[g])[0].tolist())
        assert set(chunk[within[g]].tolist()) <= set(got.tolist())


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(1, 5))
def test_chunk_capsules_hold_their_edges(seed, rings):
    """Every point of every edge lies within its chunk's capsule: within the radius of the chord from the
    chunk's first edge's start to its last edge's end (the lower bound the nearest-edge search prunes by)."""
    rng = np.random.default_rng(seed)
    edges = random_rings(rng, rings)
    capsules = tree_of(edges)[2]
    assert len(capsules) == -(-len(edges.x) // 8)
    t = np.linspace(0.0, 1.0, 7)
    px = (edges.x[:, None] + t * edges.vx[:, None]).ravel()
    py = (edges.y[:, None] + t * edges.vy[:, None]).ravel()
    c = capsules[np.repeat(np.arange(len(edges.x)) // 8, len(t))]
    u = np.clip(((px - c[:, 0]) * c[:, 2] + (py - c[:, 1]) * c[:, 3]) * c[:, 4], 0.0, 1.0)
    gap = np.hypot(px - c[:, 0] - u * c[:, 2], py - c[:, 1] - u * c[:, 3])
    assert (gap <= c[:, 5]).all()


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2 ** 32 - 1))
def test_nearest_in_groups_matches_brute_force(seed):
    """With a radius that holds every point's nearest edge, the group kernel finds the nearest edge
    (within float32 rounding, 2e-5 mm) and its distance, for points around each group centre (spread
    up to 0.1-8 mm from it, so that chunks are pruned per point and by the group's farthest point, and
    the squared search's edges by their distance from the centre: with that bound at the centre's nearest
    edge plus one reach, not two, some point's nearest edge is lost here)."""
    rng = np.random.default_rng(seed)
    edges = random_rings(rng, int(rng.integers(1, 4)))
    groups, points = 30, 64
    cx, cy = rng.uniform(-60, 60, groups), rng.uniform(-60, 60, groups)
    spread = rng.choice([0.1, 1.0, 8.0])
    ox, oy = rng.uniform(-spread, spread, points), rng.uniform(-spread, spread, points)
    qx = (cx[:, None] + ox[None, :]).ravel()
    qy = (cy[:, None] + oy[None, :]).ravel()
    exact = np.sqrt(brute_squared(qx, qy, edges).min(axis=1)).reshape(groups, points)
    # the nearest edge of p is within d(p) + |p - c| of c
    radius = (exact + np.hypot(ox, oy)[None, :]).max(axis=1) + 1e-6
    tree = tree_of(edges)
    squared = nearest_in_groups(cx, cy, radius, ox, oy, edges, tree, track=False)
    np.testing.assert_allclose(np.sqrt(squared), exact, atol=2e-5)
    edge = nearest_in_groups(cx, cy, radius, ox, oy, edges, tree)
    assert edge.min() >= 0
    distance, fx, fy = feet(qx, qy, edge.ravel(), edges)
    np.testing.assert_allclose(distance.reshape(groups, points), exact, atol=2e-5)
    np.testing.assert_allclose(np.hypot(qx - fx, qy - fy), distance, atol=1e-9)


@numba.njit
def _numba_argsort(values):
    """numba's own np.argsort, the order :func:`_ascending` must give."""
    return np.argsort(values)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(0, _INSERTION_SORT), st.sampled_from([2, 5, 1000]), st.booleans())
def test_ascending_is_numbas_argsort_ties_and_nans_included(seed, count, distinct, nans):
    """The chunk order of the nearest-edge search, sorted without allocating up to _INSERTION_SORT values
    (above, it is np.argsort itself), is numba's np.argsort's index for index (equal bounds keep their
    order, NaN last), so the first of equally near edges stays the one found; it reads the first ``count``
    values of a longer array and writes the first ``count`` places of the order, no more."""
    rng = np.random.default_rng(seed)
    values = rng.integers(0, distinct, count).astype(np.float64)
    if nans and count:
        values[rng.random(count) < 0.2] = np.nan
    order = np.full(count + 3, -1, dtype=np.int64)
    _ascending(np.concatenate([values, [-1.0, np.nan, -2.0]]), count, order)
    assert np.array_equal(order[:count], _numba_argsort(values)) and (order[count:] == -1).all()


def test_nearest_in_groups_reports_no_edge_beyond_the_radius():
    """A group whose radius reaches no edge gets -1 and inf, not some edge."""
    edges = ring_edges(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]), np.array([0, 3]), [0])
    args = (np.array([50.0]), np.array([50.0]), np.array([1.0]), np.zeros(2), np.zeros(2),
            edges, tree_of(edges))
    assert (nearest_in_groups(*args) == -1).all()
    assert np.isinf(nearest_in_groups(*args, track=False)).all()


@pytest.mark.parametrize("count", [1, 3, 8, 9, 64, 65, 513])
def test_edge_tree_keeps_every_edge_at_any_size(count):
    """However many edges (fewer than the fan-out, an exact multiple of it, one more), a radius that reaches
    all of them from far away gathers each chunk exactly once, and the chunks hold every edge once."""
    angle = np.linspace(0, 2 * np.pi, count + 1)
    x0, y0 = np.cos(angle[:-1]), np.sin(angle[:-1])
    x1, y1 = np.cos(angle[1:]), np.sin(angle[1:])
    boxes, level_start, capsules = edge_tree(x0, y0, x1, y1)
    assert level_start[-1] == len(boxes) and level_start[1] == count
    assert level_start[2] - level_start[1] == len(capsules)
    start, found = _candidates(np.array([50.0]), np.array([0.0]), np.array([100.0]), boxes, level_start)
    assert sorted(found.tolist()) == list(range(-(-count // 8)))
