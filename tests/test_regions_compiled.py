"""Tests of heoslice.regions_compiled: the compiled kernels of the grading step against brute force
(every edge tried, float64 numpy) and against the plain formulas they implement."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.regions import ring_edges
from heoslice.regions_compiled import (
    _candidates,
    curve_cells,
    edge_tree,
    expand_planes,
    feet,
    nearest_in_groups,
    write_cells,
)


def random_rings(rng, rings: int):
    """Edges of ``rings`` random star-shaped rings (3 to 300 points each) in a 100 mm square."""
    points, sizes = [], []
    for _ in range(rings):
        count = int(rng.integers(3, 300))
        angle = np.sort(rng.uniform(0, 2 * np.pi, count))
        radius = rng.uniform(0.5, 30.0) * rng.uniform(0.6, 1.0, count)
        centre = rng.uniform(-50, 50, 2)
        points.append(centre + np.column_stack([radius * np.cos(angle), radius * np.sin(angle)]))
        sizes.append(count)
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    return ring_edges(np.concatenate(points), offsets, list(range(rings)))


def brute_squared(qx, qy, edges):
    """(n, e) squared distance from every point to every edge, float64."""
    rx = qx[:, None] - edges.x[None, :]
    ry = qy[:, None] - edges.y[None, :]
    t = np.clip((rx * edges.vx + ry * edges.vy) * edges.inv_len2, 0.0, 1.0)
    return (rx - t * edges.vx) ** 2 + (ry - t * edges.vy) ** 2


def tree_of(edges):
    return edge_tree(edges.x, edges.y, edges.x + edges.vx, edges.y + edges.vy)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(1, 4))
def test_candidates_are_exactly_the_edges_within_the_radius(seed, rings):
    """The hierarchy walk returns every edge within each point's radius, once, and no other
    (brute force over all edges; the hierarchy must not lose edges in any subtree)."""
    rng = np.random.default_rng(seed)
    edges = random_rings(rng, rings)
    qx, qy = rng.uniform(-80, 80, 40), rng.uniform(-80, 80, 40)
    radius = rng.uniform(0.0, 60.0, 40)
    start, found = _candidates(qx, qy, radius, edges.x, edges.y, edges.vx, edges.vy, edges.inv_len2, *tree_of(edges))
    within = brute_squared(qx, qy, edges) <= radius[:, None] ** 2
    for g in range(40):
        got = found[start[g]:start[g + 1]]
        assert len(got) == len(set(got.tolist()))
        # points exactly on the radius may go either way in rounding; the test radii are random
        assert set(got.tolist()) == set(np.nonzero(within[g])[0].tolist())


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2 ** 32 - 1))
def test_nearest_in_groups_matches_brute_force(seed):
    """With a radius that holds every point's nearest edge, the group kernel finds the nearest edge
    (within float32 rounding, 2e-5 mm) and its distance, for points around each group centre."""
    rng = np.random.default_rng(seed)
    edges = random_rings(rng, int(rng.integers(1, 4)))
    groups, points = 30, 16
    cx, cy = rng.uniform(-60, 60, groups), rng.uniform(-60, 60, groups)
    ox, oy = rng.uniform(-1.0, 1.0, points), rng.uniform(-1.0, 1.0, points)
    qx = (cx[:, None] + ox[None, :]).ravel()
    qy = (cy[:, None] + oy[None, :]).ravel()
    exact = np.sqrt(brute_squared(qx, qy, edges).min(axis=1)).reshape(groups, points)
    # the nearest edge of p is within d(p) + |p - c| of c
    radius = (exact + np.hypot(ox, oy)[None, :]).max(axis=1) + 1e-6
    tree = tree_of(edges)
    squared = nearest_in_groups(cx, cy, radius, ox, oy, edges.x, edges.y, edges.vx, edges.vy, edges.inv_len2,
                                tree, track=False)
    np.testing.assert_allclose(np.sqrt(squared), exact, atol=2e-5)
    edge = nearest_in_groups(cx, cy, radius, ox, oy, edges.x, edges.y, edges.vx, edges.vy, edges.inv_len2, tree)
    assert edge.min() >= 0
    distance, fx, fy = feet(qx, qy, edge.ravel(), edges.x, edges.y, edges.vx, edges.vy, edges.inv_len2)
    np.testing.assert_allclose(distance.reshape(groups, points), exact, atol=2e-5)
    np.testing.assert_allclose(np.hypot(qx - fx, qy - fy), distance, atol=1e-9)


def test_nearest_in_groups_reports_no_edge_beyond_the_radius():
    """A group whose radius reaches no edge gets -1 and inf, not some edge."""
    edges = ring_edges(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]), np.array([0, 3]), [0])
    args = (np.array([50.0]), np.array([50.0]), np.array([1.0]), np.zeros(2), np.zeros(2),
            edges.x, edges.y, edges.vx, edges.vy, edges.inv_len2, tree_of(edges))
    assert (nearest_in_groups(*args) == -1).all()
    assert np.isinf(nearest_in_groups(*args, track=False)).all()


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(2, 16), st.booleans())
def test_expand_planes_is_the_plane_formula(seed, cell, masked):
    """Each pixel gets clip(floor(s + gx x - gy y) + 1, 1, count) of its cell's plane (x, y its offset
    from the cell centre), except where s sits within float32 rounding of an integer; with a
    mask, + base on its pixels and 0 off them."""
    rng = np.random.default_rng(seed)
    rows, cols, count, base = int(rng.integers(1, 6)), int(rng.integers(1, 6)), int(rng.integers(1, 50)), 7
    s = rng.uniform(-3, count + 3, (rows, cols))
    gx, gy = rng.uniform(-3, 3, (rows, cols)), rng.uniform(-3, 3, (rows, cols))
    px, py = 0.04, 0.05
    shape = (rows * cell - int(rng.integers(0, cell)), cols * cell - int(rng.integers(0, cell)))
    mask = rng.random((shape[0] + 5, shape[1] + 4)) < 0.7 if masked else None
    out = expand_planes(s, gx, gy, cell, px, py, count, np.empty(shape, np.int16), mask, (3, 2), base)
    r, c = np.indices(shape)
    i, j = r // cell, c // cell
    x = (c - j * cell + 0.5 - cell / 2) * px
    y = (r - i * cell + 0.5 - cell / 2) * py
    value = s[i, j] + gx[i, j] * x - gy[i, j] * y
    expected = np.clip(np.floor(value) + 1, 1, count)
    if masked:
        expected = np.where(mask[3:3 + shape[0], 2:2 + shape[1]], expected + base, 0)
    clear = np.abs(value - np.rint(value)) > 1e-3
    assert np.array_equal(out[clear], expected[clear])


def test_write_cells_fills_whole_cells_inside_the_image():
    """write_cells sets every pixel of the given cells from its own s, clips to 1..count, skips pixels past
    the image's edge and leaves other cells alone."""
    cell = 3
    index = np.full((7, 8), -5, dtype=np.int32)
    ci, cj = np.array([0, 2]), np.array([1, 2])
    s = np.stack([np.arange(9.0) - 2.0, np.full(9, 99.0)])
    write_cells(index, ci, cj, cell, s, 5)
    assert np.array_equal(index[0:3, 3:6].ravel(), np.clip(np.floor(s[0]) + 1, 1, 5))
    assert (index[6, 6:8] == 5).all()  # cell (2, 2) covers rows 6..8 and columns 6..8: only (6, 6..7) exist
    untouched = np.ones(index.shape, dtype=bool)
    untouched[0:3, 3:6] = False
    untouched[6, 6:8] = False
    assert (index[untouched] == -5).all()


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.booleans())
def test_curve_cells_is_the_quadratic_formula(seed, masked):
    """curve_cells writes clip(floor(s + g.d + d.H.d / 2) + 1, 1, count) at every pixel of the given cells
    (d the pixel's offset from the cell centre, y up), + base on mask pixels and 0 off them, and
    leaves every other pixel alone."""
    rng = np.random.default_rng(seed)
    cell, rows, cols, count, base = 6, 4, 5, 30, 3
    s = rng.uniform(-2, count + 2, (rows, cols))
    grad = rng.uniform(-4, 4, (rows, cols, 2))
    hessian = rng.uniform(-9, 9, (rows, cols, 3))
    px = py = 0.05
    index = np.full((rows * cell - 2, cols * cell - 1), -7, dtype=np.int32)
    mask = rng.random(index.shape) < 0.6 if masked else None
    ci, cj = np.array([0, 3, 2]), np.array([1, 4, 0])
    curve_cells(index, ci, cj, cell, s, grad, hessian, px, py, count, mask, (0, 0), base)
    r, c = np.indices(index.shape)
    i, j = r // cell, c // cell
    x = (c - j * cell + 0.5 - cell / 2) * px
    y = -(r - i * cell + 0.5 - cell / 2) * py
    g, h = grad[i, j], hessian[i, j]
    value = s[i, j] + g[..., 0] * x + g[..., 1] * y + 0.5 * (h[..., 0] * x * x + h[..., 2] * y * y) + h[..., 1] * x * y
    expected = np.clip(np.floor(value) + 1, 1, count)
    if masked:
        expected = np.where(mask, expected + base, 0)
    chosen = np.zeros((rows, cols), bool)
    chosen[ci, cj] = True
    inside = chosen[i, j]
    clear = np.abs(value - np.rint(value)) > 1e-9
    assert np.array_equal(index[inside & clear], expected[inside & clear])
    assert (index[~inside] == -7).all()


@pytest.mark.parametrize("count", [1, 3, 8, 9, 64, 65, 513])
def test_edge_tree_keeps_every_edge_at_any_size(count):
    """However many edges (one level, an exact multiple of the fan-out, one more), a radius that reaches
    all of them from far away gathers each edge exactly once."""
    angle = np.linspace(0, 2 * np.pi, count + 1)
    x0, y0 = np.cos(angle[:-1]), np.sin(angle[:-1])
    x1, y1 = np.cos(angle[1:]), np.sin(angle[1:])
    boxes, level_start = edge_tree(x0, y0, x1, y1)
    assert level_start[-1] == len(boxes) and level_start[1] == count
    vx, vy = x1 - x0, y1 - y0
    length2 = vx * vx + vy * vy
    inv = np.divide(1.0, length2, out=np.zeros_like(length2), where=length2 > 0)
    start, found = _candidates(np.array([50.0]), np.array([0.0]), np.array([100.0]), x0, y0, vx, vy, inv, boxes,
                               level_start)
    assert sorted(found.tolist()) == list(range(count))
