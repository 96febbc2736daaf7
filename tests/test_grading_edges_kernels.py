"""Tests of heoslice.grading.edges_kernels: the points straight_runs leaves out (those on a polygon's edges,
within its tolerance) and keeps, the knots placing each point on its kept edge, and the same edges for rings that
differ only in their straight points."""

from __future__ import annotations

import numpy as np
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.grading.edges import ring_edges
from heoslice.grading.edges_kernels import straight_runs


def polygon_with_points_on_its_edges(rng, count: int, extra: int):
    """(ring (n, 2), original (n,) bool): a convex polygon whose vertices turn by at least 0.05 rad (each
    lies >= 1e-3 mm off its neighbours' chord) with ``extra`` points put on random edges (at most three
    per edge, some of them repeats of a vertex)."""
    gaps = rng.uniform(0.05, 1.0, count)
    angle = np.cumsum(gaps / gaps.sum() * 2 * np.pi * 0.999)
    radius = rng.uniform(1.0, 30.0)
    vertices = radius * np.column_stack([np.cos(angle), np.sin(angle)]) + rng.uniform(-50, 50, 2)
    ring, original = [], []
    per_edge = np.bincount(rng.integers(0, count, extra), minlength=count).clip(0, 3)
    for i in range(count):
        ring.append(vertices[i])
        original.append(True)
        following = vertices[(i + 1) % count]
        for t in np.sort(rng.choice([0.0, *rng.uniform(0.01, 0.99, 3)], per_edge[i], replace=False)):
            ring.append(vertices[i] + t * (following - vertices[i]))
            original.append(False)
    return np.array(ring), np.array(original)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(3, 60), st.integers(0, 80))
def test_straight_runs_leave_out_exactly_the_points_on_the_polygons_edges(seed, count, extra):
    """Points put on a polygon's edges (and repeated vertices) are left out and its vertices kept, so the
    edges are the polygon's own; each point's knot places it on the kept edge it lies on, in ring order."""
    rng = np.random.default_rng(seed)
    rings = [polygon_with_points_on_its_edges(rng, count, extra), polygon_with_points_on_its_edges(rng, 5, 9)]
    points = np.concatenate([ring for ring, _ in rings])
    offsets = np.concatenate([[0], np.cumsum([len(ring) for ring, _ in rings])])
    keep, order, _, _ = straight_runs(points[:, 0], points[:, 1], np.diff(offsets), 1e-5)
    # a repeated vertex may stand for the vertex: the same place
    assert np.array_equal(points[keep], points[np.concatenate([original for _, original in rings])])
    edges = ring_edges(points, offsets, [0, 1])
    assert np.array_equal(edges.first, order[keep[order]])
    for k in (0, 1):  # each ring's edges start at its lowest point in x, then y
        lowest = np.lexsort((rings[k][0][:, 1], rings[k][0][:, 0]))[0]
        assert np.array_equal(points[edges.first[np.flatnonzero(edges.ring == k)[0]]], rings[k][0][lowest])
    assert np.all(np.diff(edges.knots) >= 0)
    assert np.array_equal(np.sort(edges.knot_point[np.diff(np.r_[edges.knots, np.inf]) >= 0]),
                          np.sort(edges.knot_point))
    ring = np.repeat([0, 1], [len(rings[0][0]) + 1, len(rings[1][0]) + 1])
    last_edge = np.array([np.flatnonzero(edges.ring == k)[-1] for k in (0, 1)])
    on = np.minimum(np.floor(edges.knots - ring), last_edge[ring]).astype(np.int64)  # a point may end its edge
    t = edges.knots - ring - on
    place = np.column_stack([edges.x[on] + t * edges.vx[on], edges.y[on] + t * edges.vy[on]])
    inner = np.ones(len(edges.knots), dtype=bool)
    inner[[len(rings[0][0]), -1]] = False  # each ring's closing knot: its first kept point again
    np.testing.assert_allclose(place[~inner], points[edges.first[[0, np.flatnonzero(edges.ring == 1)[0]]]],
                               atol=1e-9)
    np.testing.assert_allclose(place[inner], points[edges.knot_point[inner]], atol=1e-9)


def test_straight_runs_keep_every_point_of_a_fine_curve_and_only_the_ends_of_straight_sides():
    """A circle's points (each 2.3 micrometres off its neighbours' chord) are all kept; a straight side of 40
    points keeps only its ends however long (an extruded wall's many vertices and crossings alike go, so
    its layers keep the same points); a polygon of 20 000 points bending 0.04 micrometres at each, whose runs
    stop where the bend adds up, keeps points within the tolerance of its edges."""
    angle = np.linspace(0, 2 * np.pi, 513)[:-1]
    fine = 30.0 * np.column_stack([np.cos(angle), np.sin(angle)])
    keep, _, _, _ = straight_runs(fine[:, 0], fine[:, 1], np.array([len(fine)]), 1e-5)
    assert keep.all()
    side = np.column_stack([np.linspace(0.0, 39.0, 40), np.zeros(40)])
    square = np.concatenate([side, [[40.0, 0.0], [40.0, 40.0], [0.0, 40.0]]])
    keep, _, _, _ = straight_runs(square[:, 0], square[:, 1], np.array([len(square)]), 1e-5)
    assert np.array_equal(np.flatnonzero(keep), [0, 40, 41, 42])
    angle = np.linspace(0, 2 * np.pi, 20_001)[:-1]
    slow = 30.0 * np.column_stack([np.cos(angle), np.sin(angle)])
    keep, _, _, _ = straight_runs(slow[:, 0], slow[:, 1], np.array([len(slow)]), 1e-5)
    kept = slow[keep]
    assert 100 < len(kept) < len(slow) / 4
    assert shapely.distance(shapely.points(slow), shapely.LinearRing(kept)).max() <= 1e-5 * (1 + 1e-9)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(3, 40))
def test_rings_differing_only_in_their_straight_points_have_the_same_edges(seed, count):
    """Two slices of an extruded wall: the same vertices with points on every edge at other places (a plane
    crossing each quad's diagonal at another height), each ring starting anywhere: the same edges, value
    for value (what lets a layer reuse the one below it)."""
    rng = np.random.default_rng(seed)
    vertices, _ = polygon_with_points_on_its_edges(rng, count, 0)
    rings = []
    for _ in range(2):
        following = np.roll(vertices, -1, axis=0)
        between = vertices + rng.uniform(0.01, 0.99, (count, 1)) * (following - vertices)
        ring = np.column_stack([vertices, between]).reshape(-1, 2)
        rings.append(np.roll(ring, int(rng.integers(0, 2 * count)), axis=0))  # starts anywhere
    first, second = (ring_edges(ring, np.array([0, len(ring)]), [0]) for ring in rings)
    assert len(first.x) == count
    for name in ("x", "y", "vx", "vy"):
        assert np.array_equal(getattr(first, name), getattr(second, name)), name
