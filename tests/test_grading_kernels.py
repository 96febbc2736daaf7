"""Tests of the grading kernels (heoslice.grading.*_kernels): the compiled loops against brute force
(every edge tried, float64 numpy) and against the plain formulas they implement."""

from __future__ import annotations

import os
import numba
import numpy as np
import pytest
import shapely
from helpers import brute_squared, random_ring_points, random_rings, ring_weights, tree_of
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from heoslice.grading.edges import ring_edges
from heoslice.grading.edges_kernels import straight_runs
from heoslice.grading.field_kernels import (
    CellPixels,
    band_field,
    curve_cells,
    expand_planes,
    label_target,
)
from heoslice.grading.labels_kernels import disc_winding
from heoslice.grading.lattice_kernels import (
    LatticeFrame,
    feet,
    inside_centres,
    signed_feet,
)
from heoslice.grading.materials_kernels import values_at_points
from heoslice.grading.refine_kernels import (
    CellField,
    FitTest,
    band_cells,
    hessian_of,
    refine_flags,
    ring_models,
)
from heoslice.grading.search_kernels import _INSERTION_SORT, _ascending, _candidates, edge_tree, nearest_in_groups


def halftone_bits(label, origin, packed, family_of_label, fraction, layout, mixes, target, tile, base_channel, planes,
                  table):
    """droplet_bits of the given arrays, grouped as it takes them."""
    from heoslice.grading.droplets_kernels import (
        Dither,
        LabelledLayer,
        LayerMixes,
        droplet_bits,
    )

    mixing = LayerMixes(family_of_label, fraction, layout, mixes, target)
    return droplet_bits(LabelledLayer(label, *origin, packed), mixing, Dither(tile, table, base_channel), planes)


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
    up to 0.1-8 mm from it, so that chunks are pruned per point and by the group's farthest point)."""
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
    order, NaN last), so the first of equally near edges stays the one found."""
    rng = np.random.default_rng(seed)
    values = rng.integers(0, distinct, count).astype(np.float64)
    if nans and count:
        values[rng.random(count) < 0.2] = np.nan
    order = _ascending(values, np.full(count, -1, dtype=np.int64))
    assert np.array_equal(order, _numba_argsort(values))


def test_nearest_in_groups_reports_no_edge_beyond_the_radius():
    """A group whose radius reaches no edge gets -1 and inf, not some edge."""
    edges = ring_edges(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]), np.array([0, 3]), [0])
    args = (np.array([50.0]), np.array([50.0]), np.array([1.0]), np.zeros(2), np.zeros(2),
            edges, tree_of(edges))
    assert (nearest_in_groups(*args) == -1).all()
    assert np.isinf(nearest_in_groups(*args, track=False)).all()


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(2, 16), st.booleans(), st.sampled_from([np.int8, np.int16, np.int32]))
def test_expand_planes_is_the_plane_formula(seed, cell, masked, label_dtype):
    """Each pixel gets clip(floor(s + gx x - gy y) + 1, 1, count) of its cell's plane (x, y its offset
    from the cell centre), except where s sits within float32 rounding of an integer; with a
    mask, 0 off its pixels; + base on the others; every pixel of an empty cell 0."""
    rng = np.random.default_rng(seed)
    rows, cols, count, base = int(rng.integers(1, 6)), int(rng.integers(1, 6)), int(rng.integers(1, 50)), 7
    s = rng.uniform(-3, count + 3, (rows, cols))
    gx, gy = rng.uniform(-3, 3, (rows, cols)), rng.uniform(-3, 3, (rows, cols))
    empty = rng.random((rows, cols)) < 0.3
    px, py = 0.04, 0.05
    shape = (rows * cell - int(rng.integers(0, cell)), cols * cell - int(rng.integers(0, cell)))
    mask = rng.random((shape[0] + 5, shape[1] + 4)) < 0.7 if masked else None
    out = expand_planes(s, gx, gy, CellPixels(cell, px, py), count,
                        label_target(np.full(shape, -5, label_dtype), mask, (3, 2), base), empty)
    r, c = np.indices(shape)
    i, j = r // cell, c // cell
    x = (c - j * cell + 0.5 - cell / 2) * px
    y = (r - i * cell + 0.5 - cell / 2) * py
    value = s[i, j] + gx[i, j] * x - gy[i, j] * y
    expected = np.clip(np.floor(value) + 1, 1, count)
    expected = expected + base
    if masked:
        expected = np.where(mask[3:3 + shape[0], 2:2 + shape[1]], expected, 0)
    expected = np.where(empty[i, j], 0, expected)
    clear = (np.abs(value - np.rint(value)) > 1e-3) | empty[i, j]
    assert np.array_equal(out[clear], expected[clear])


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(1, 5), st.booleans(), st.sampled_from([np.int8, np.int16, np.int32]))
def test_band_cells_is_eq10_of_modelled_or_measured_distances(seed, sets, masked, label_dtype):
    """band_cells writes, at every pixel of the given cells, clip(floor(s) + 1, 1, count) of s by eq. 10
    (s = (1 - w_start) count from helpers.ring_weights for two or more ring sets, d count / length for
    one) of each ring set's distance there: its quadratic where the cell's model is given, the measured
    value (from its slot in a packed array) where it is NaN; + base, and 0 off the mask's pixels;
    pixels past the image and other cells untouched."""

    rng = np.random.default_rng(seed)
    cell, rows, cols, count, length, base = 5, 4, 5, int(rng.integers(1, 40)), 3.0, 3
    px = py = 0.05
    index = np.full((rows * cell - 2, cols * cell - 1), -7, dtype=label_dtype)
    mask = rng.random(index.shape) < 0.6 if masked else None
    ci, cj = np.array([0, 3, 2, 3]), np.array([1, 4, 0, 0])
    models = np.column_stack([rng.uniform(0.2, 6.0, (sets, 4)).ravel()] + [rng.uniform(-1, 1, sets * 4)
                                                                          for _ in range(5)]).reshape(sets, 4, 6)
    models[rng.random((sets, 4)) < 0.4] = np.nan
    measured = rng.uniform(0.05, 6.0, (sets, 4, cell * cell)).astype(np.float32).astype(np.float64)
    # the measured rows are handed over packed, in a shuffled order, and found through their slots
    order = rng.permutation(sets * 4)
    slot = np.argsort(order).reshape(sets, 4)
    band_cells(label_target(index, mask, (0, 0), base), ci, cj, CellPixels(cell, px, py), models,
               measured.reshape(sets * 4, -1)[order], slot, count, length)
    v, u = np.divmod(np.arange(cell * cell), cell)
    x, y = (u + 0.5 - cell / 2) * px, -(v + 0.5 - cell / 2) * py
    m = models[..., None]
    quadratic = (m[..., 0, :] + m[..., 1, :] * x + m[..., 2, :] * y + 0.5 * (m[..., 3, :] * x * x + m[..., 5, :] * y * y)
                 + m[..., 4, :] * x * y)
    d = np.where(np.isnan(models[..., :1]), measured, quadratic)
    if sets == 1:
        s = d[0] * count / length
    else:
        s = (1.0 - ring_weights(np.moveaxis(d, 0, -1).reshape(-1, sets))[:, 0].reshape(d.shape[1:])) * count
    expected = np.clip(np.floor(s) + 1, 1, count)
    clear = np.abs(s - np.rint(s)) > 1e-9
    written = np.zeros(index.shape, dtype=bool)
    for n in range(len(ci)):
        for k in range(cell * cell):
            r, c = ci[n] * cell + v[k], cj[n] * cell + u[k]
            if r >= index.shape[0] or c >= index.shape[1]:
                continue
            written[r, c] = True
            want = expected[n, k] + base if mask is None or mask[r, c] else 0
            if clear[n, k]:
                assert index[r, c] == want, (n, k, s[n, k])
    assert (index[~written] == -7).all()


def sampled_field(function, rows: int = 12, cols: int = 14, step: float = 0.5):
    """s, its gradient ((rows, cols, 2), y up) and the Hessian from refine.cell_hessians ((3, rows, cols)) of
    ``function(x, y) -> (s, s_x, s_y)`` sampled at lattice centres ``step`` mm apart."""
    from heoslice.grading.lattice import Lattice
    from heoslice.grading.refine import cell_hessians as _hessian

    lattice = Lattice(row0=0, col0=0, cell=12, rows=rows, cols=cols, x0=0.0, y0=rows * step, dx=step, dy=step)
    x, y = lattice.centres()
    s, gx, gy = (np.broadcast_to(np.asarray(a, dtype=float), (rows, cols)) for a in function(x[None, :], y[:, None]))
    grad = np.stack([gx, gy], axis=-1)
    return s.copy(), grad, _hessian(grad, lattice), lattice


def flags_of(s, grad, hessian, lattice, known=None, side=None, tolerance=0.042, count=1000):
    """refine_flags over every inner cell (the border ring of cells is no candidate), all known and on side
    unless given; the tolerance one pixel of 0.042 mm; the turn limit of a 12-pixel cell."""
    candidate = np.zeros(s.shape, dtype=bool)
    candidate[1:-1, 1:-1] = True
    known = np.ones(s.shape, dtype=bool) if known is None else known
    side = np.ones(s.shape, dtype=bool) if side is None else side
    limit = np.sqrt(1.0 - (1.0 / 12) ** 2)
    return refine_flags(CellField(s, grad, known, side, candidate), FitTest(lattice.dx, lattice.dy, tolerance, limit,
                                                                             count), hessian)


def test_refine_flags_keeps_planes_and_quadratics_that_fit_and_refines_kinks():
    """A plane fits everywhere: nothing refined, every Hessian zeroed (the plane fits at least as well). A
    quadratic field the plane misses (by far more than the tolerance): nothing refined, its Hessian (exact:
    central differences of a quadratic's gradients) kept. A ridge
    (s = 40 - 8 |x - x0|, a medial axis): the cells within a cell of it are refined, the others not."""
    s, grad, hessian, lattice = sampled_field(lambda x, y: (3.0 + 5.0 * x - 2.0 * y, 5.0, -2.0))
    hessian[:] = 1.0
    assert not flags_of(s, grad, hessian, lattice).any()
    assert (hessian[:, 1:-1, 1:-1] == 0).all()

    s, grad, hessian, lattice = sampled_field(lambda x, y: (x * x + 3 * x * y + 20 * y, 2 * x + 3 * y, 3 * x + 20))
    exact = hessian.copy()
    assert not flags_of(s, grad, hessian, lattice, tolerance=1e-3).any()  # the plane misses by far more
    np.testing.assert_allclose(hessian[:, 1:-1, 1:-1], exact[:, 1:-1, 1:-1])
    np.testing.assert_allclose(exact[:, 1:-1, 1:-1], np.array([2.0, 3.0, 0.0])[:, None, None] * np.ones((1, 10, 12)),
                               atol=1e-9)

    x0 = 3.6
    s, grad, hessian, lattice = sampled_field(lambda x, y: (40.0 - 8.0 * np.abs(x - x0), -8.0 * np.sign(x - x0), 0.0))
    flags = flags_of(s, grad, hessian, lattice)
    x, _ = lattice.centres()
    beside = np.abs(x - x0) < lattice.dx  # the cell holding the kink and the one whose neighbour lies past it
    assert flags[1:-1, 1:-1][:, beside[1:-1]].all()
    assert not flags[1:-1, 1:-1][:, ~beside[1:-1]].any()


def test_refine_flags_checks_cells_next_to_unknown_or_off_side_neighbours():
    """A cell whose own s is unknown is refined; next to the outline (a neighbour off the family's side or
    with s unknown) a cell whose direction turns by more than the limit towards a neighbour is refined
    even where its plane fits the known centres, and one whose direction does not turn is not."""
    # a radial field about a point just off the lattice: the direction turns by ~0.2 rad per cell near it
    cx, cy = -0.1, 3.0
    def radial(x, y):
        r = np.hypot(x - cx, y - cy)
        return r, (x - cx) / r, (y - cy) / r
    s, grad, hessian, lattice = sampled_field(radial)
    side = np.ones(s.shape, dtype=bool)
    side[:, :2] = False
    flags = flags_of(s, grad, hessian.copy(), lattice, side=side, tolerance=1e6)
    assert flags[5:7, 2].all()  # beside the off-side columns, the turn is large: refined although planes "fit"
    assert not flags_of(s, grad, hessian.copy(), lattice, tolerance=1e6).any()  # all on side: the turn is not checked
    known = np.ones(s.shape, dtype=bool)
    known[6, 8] = False
    flags = flags_of(*sampled_field(lambda x, y: (x + y, 1.0, 1.0))[:3], lattice, known=known)
    assert flags[6, 8] and flags.sum() == 1  # a straight field: only the unknown cell itself


def test_refine_flags_lets_a_quadratic_explain_a_round_outlines_turn():
    """Beside the outline of a round hole 6 mm across (12 cells), the direction turns by ~5 degrees per cell,
    past a 12-pixel cell's limit: a plane is refined there, but the quadratic, whose gradient follows the
    turn to every neighbour, is kept (its Hessian too) and nothing is refined. With its Hessian's sign
    flipped (a quadratic turning the other way) the same cells are refined again."""
    cx, cy = -5.7, 3.0

    def around_hole(x, y):
        r = np.hypot(x - cx, y - cy)
        return r - 6.0, (x - cx) / r, (y - cy) / r

    s, grad, hessian, lattice = sampled_field(around_hole)
    side = np.ones(s.shape, dtype=bool)
    side[:, :1] = False
    beside = np.zeros(s.shape, dtype=bool)
    beside[1:-1, 1] = True
    planes = flags_of(s, grad, None, lattice, side=side)
    assert planes[beside].sum() >= 4  # the plane's direction misses the neighbours' by more than the limit
    kept = hessian.copy()
    assert not flags_of(s, grad, kept, lattice, side=side)[beside].any()
    np.testing.assert_allclose(kept[:, beside], hessian[:, beside])
    assert (flags_of(s, grad, -hessian, lattice, side=side) == planes)[beside].all()


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.booleans())
def test_signed_feet_are_the_distance_to_the_given_edge_signed_by_side(seed, encloses):
    """At each lattice centre, the foot and distance are those of its given edge (feet), the distance is
    negated where ``inside`` differs from ``encloses``, and the gradient is the unit vector from the foot
    to the centre times that sign."""
    rng = np.random.default_rng(seed)
    edges = random_rings(rng, int(rng.integers(1, 4)))
    rows, cols, dx, dy, x0, y0 = 7, 9, 0.7, 0.6, -3.0, 2.0
    edge = rng.integers(0, len(edges.x), (rows, cols))
    inside = rng.random((rows, cols)) < 0.5
    signed, gradient, foot = signed_feet(edge, LatticeFrame(x0, y0, dx, dy), edges, inside, encloses)
    qx = np.broadcast_to(x0 + (np.arange(cols) + 0.5) * dx, (rows, cols)).ravel()
    qy = np.broadcast_to((y0 - (np.arange(rows) + 0.5) * dy)[:, None], (rows, cols)).ravel()
    distance, fx, fy = feet(qx, qy, edge.ravel(), edges)
    sign = np.where(inside.ravel() == encloses, 1.0, -1.0)
    np.testing.assert_allclose(signed.ravel(), sign * distance, atol=1e-12)
    np.testing.assert_allclose(foot.reshape(2, -1), np.stack([fx, fy]), atol=1e-12)
    unit = np.stack([qx - fx, qy - fy], axis=1) / distance[:, None] * sign[:, None]
    np.testing.assert_allclose(gradient.reshape(-1, 2), unit, atol=1e-9)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(1, 4), st.booleans())
def test_inside_centres_is_the_solid_mask_of_disjoint_rings(seed, rings, clockwise):
    """For disjoint star-shaped rings of either orientation, the lattice centres inside them are the pixels
    rasterising.solid_mask fills on the same grid (an independent scanline rasteriser), centres on an
    edge aside."""
    from heoslice.layers.rasterising import Grid, solid_mask

    rng = np.random.default_rng(seed)
    loops = []
    for k in range(rings):
        count = int(rng.integers(5, 60))
        # angles a jittered step apart, so no gap reaches half a turn and the ring stays simple
        angle = (np.arange(count) + rng.uniform(0.0, 0.9, count)) * (2 * np.pi / count)
        radius = rng.uniform(0.5, 4.0) * rng.uniform(0.5, 1.0, count)
        loop = np.array([10.0 * k, 0.0]) + np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])
        loops.append(loop[::-1] if clockwise else loop)
    points = np.concatenate(loops)
    offsets = np.concatenate([[0], np.cumsum([len(loop) for loop in loops])])
    edges = ring_edges(points, offsets, list(range(rings)))
    grid = Grid(width=int(rng.integers(20, 120)), height=int(rng.integers(10, 60)), x_left=-5.0, y_top=5.0,
                px=float(rng.uniform(0.1, 0.6)), py=float(rng.uniform(0.1, 0.6)))
    inside = inside_centres(edges, LatticeFrame(grid.x_left, grid.y_top, grid.px, grid.py), grid.height, grid.width)
    forward = [loop if shapely.LinearRing(loop).is_ccw else loop[::-1] for loop in loops]
    expected = solid_mask(np.concatenate(forward), offsets, grid)
    x = grid.x_left + (np.arange(grid.width) + 0.5) * grid.px
    y = grid.y_top - (np.arange(grid.height) + 0.5) * grid.py
    near = shapely.distance(shapely.points(*np.meshgrid(x, y)), shapely.MultiLineString(
        [np.vstack([loop, loop[:1]]) for loop in loops])) < 1e-9
    assert np.array_equal(inside[~near], expected[~near])


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (6, 1), (2, 2), (30, 41)])
def test_hessian_of_is_numpys_gradient_of_the_gradients(shape):
    """s_xx, s_xy, s_yy are numpy.gradient's differences of the gradients (central inside, one-sided at the
    border, y up while rows go down; s_xy the mean of both cross differences), zero along an axis one cell
    wide, and all three zero at every cell where any is not finite (a NaN gradient beside it)."""
    rng = np.random.default_rng(sum(shape))
    grad = rng.normal(size=shape + (2,))
    grad[rng.random(shape) < 0.1] = np.nan
    dx, dy = 0.5, 0.4
    expected = np.zeros((3,) + shape)
    if shape[0] > 1:
        expected[2] = np.gradient(grad[..., 1], -dy, axis=0)
        expected[1] = np.gradient(grad[..., 0], -dy, axis=0)
    if shape[1] > 1:
        expected[0] = np.gradient(grad[..., 0], dx, axis=1)
        across = np.gradient(grad[..., 1], dx, axis=1)
        expected[1] = 0.5 * (expected[1] + across) if shape[0] > 1 else across
    expected[:, ~np.isfinite(expected).all(axis=0)] = 0.0
    np.testing.assert_allclose(hessian_of(grad, dx, dy), expected, rtol=1e-12, atol=1e-12)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(2, 6))
def test_band_field_is_eq10_and_its_gradient(seed, sets):
    """With distances to circles (signed, > 0 on the family's side: inside the first, outside the others),
    band_field's s is (1 - w_start) N_R of eq. 10 (helpers.ring_weights) wherever every distance is
    positive, its gradient matches central differences of s, and s is NaN where the continuation passes
    its pole (d_m + d_start A <= 0)."""

    rng = np.random.default_rng(seed)
    centres = np.vstack([[0.0, 0.0], rng.uniform(-5, 5, (sets - 1, 2))])
    radii = np.concatenate([[9.0], rng.uniform(0.3, 1.5, sets - 1)])
    count = int(rng.integers(2, 30))

    def field(x, y):
        rho = np.hypot(x[None] - centres[:, 0, None, None], y[None] - centres[:, 1, None, None])
        sign = np.where(np.arange(sets) == 0, -1.0, 1.0)[:, None, None]
        d = sign * (rho - radii[:, None, None])
        g = np.stack([x[None] - centres[:, 0, None, None], y[None] - centres[:, 1, None, None]], axis=-1)
        return d, g * (sign / rho)[..., None]

    x, y = np.meshgrid(np.linspace(-8, 8, 23), np.linspace(-8, 8, 19))
    with np.errstate(invalid="ignore", divide="ignore"):
        d, g = field(x, y)
    s, grad = band_field(d, g, count)
    positive = (d > 0).all(axis=0)
    expected = (1.0 - ring_weights(np.moveaxis(d, 0, -1)[positive])[:, 0]) * count
    np.testing.assert_allclose(s[positive], expected, rtol=1e-9)
    h = 1e-6
    numeric_x = (band_field(*field(x + h, y), count)[0] - band_field(*field(x - h, y), count)[0]) / (2 * h)
    numeric_y = (band_field(*field(x, y + h), count)[0] - band_field(*field(x, y - h), count)[0]) / (2 * h)
    smooth = positive & np.isfinite(g).all(axis=(0, 3))  # not at a circle's centre, where its gradient is 0 / 0
    np.testing.assert_allclose(grad[smooth, 0], numeric_x[smooth], rtol=1e-4, atol=1e-4 * count)
    np.testing.assert_allclose(grad[smooth, 1], numeric_y[smooth], rtol=1e-4, atol=1e-4 * count)
    far = np.full((sets, 1, 1), 1.0)
    far[0] = -50.0  # deep off the family's side: d_m + d_start A = 1 - 50 A < 0
    assert np.isnan(band_field(far, np.zeros((sets, 1, 1, 2)), count)[0]).all()


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(2, 6))
def test_band_sensitivities_are_the_partial_derivatives_of_eq10(seed, sets):
    """_band_sensitivities' ds/dd_j at a point (distances to the starting and each ending ring set, some
    near zero or negative) match central differences of band_field's s in each distance, and are all
    NaN where s is (past the continuation's pole)."""
    from heoslice.grading.refine_kernels import _band_sensitivities

    rng = np.random.default_rng(seed)
    count = float(rng.integers(1, 40))
    d = rng.uniform(-0.5, 8.0, sets) * rng.choice([1.0, 1e-3], sets, p=[0.8, 0.2])
    out = np.empty(sets)
    _band_sensitivities(d, sets, count, out)

    def s(values):
        return band_field(values[:, None, None], np.zeros((sets, 1, 1, 2)), count)[0][0, 0]

    if np.isnan(s(d)):
        assert np.isnan(out).all()
        return
    h = 1e-7
    for j in range(sets):
        step = np.zeros(sets)
        step[j] = h
        if np.isnan(s(d + step)) or np.isnan(s(d - step)) or min(abs(d[1:] - d[1:][:, None])[~np.eye(sets - 1, dtype=bool)],
                                                                 default=np.inf) < 2 * h:
            continue  # the nearest ending ring would change within the step
        numeric = (s(d + step) - s(d - step)) / (2 * h)
        assert out[j] == pytest.approx(numeric, rel=1e-4, abs=1e-4 * count)


def numpy_ring_models(d, g, grad, ci, cj, dx, dy, count, h, tolerance):
    """refine.fit_ring_models' choice written as numpy passes over all cells at once (the formulation the
    compiled kernel replaced): models (sets, n, 6), NaN rows where the ring set is measured."""
    steps = [(di, dj) for di in (-1, 0, 1) for dj in (-1, 0, 1)]
    ex = np.array([dj * dx for _, dj in steps])[:, None]
    ey = np.array([-di * dy for di, _ in steps])[:, None]
    near = [np.stack([dk[ci + di, cj + dj] for di, dj in steps]) for dk in d]
    models, misses = [], []
    for gk, around in zip(g, near):
        hxx = (gk[ci, cj + 1, 0] - gk[ci, cj - 1, 0]) / (2 * dx)
        hyy = (gk[ci - 1, cj, 1] - gk[ci + 1, cj, 1]) / (2 * dy)
        hxy = 0.5 * ((gk[ci - 1, cj, 0] - gk[ci + 1, cj, 0]) / (2 * dy) + (gk[ci, cj + 1, 1] - gk[ci, cj - 1, 1]) / (2 * dx))
        model = np.column_stack([around[4], gk[ci, cj, 0], gk[ci, cj, 1], hxx, hxy, hyy])
        guess = model[:, 0] + model[:, 1] * ex + model[:, 2] * ey + 0.5 * (hxx * ex * ex + hyy * ey * ey) + hxy * ex * ey
        misses.append(np.abs(guess - around).max(axis=0))
        models.append(model)
    stacked = np.stack(near)  # (sets, 9, n)
    ends = stacked[1:]
    nearest_end = np.argmin(np.abs(ends), axis=0)[None]
    dm = np.take_along_axis(ends, nearest_end, axis=0)[0]
    other = np.arange(len(ends))[:, None, None] != nearest_end
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = np.where(other, 1.0 / np.where(np.abs(ends) < 1e-12, 1e-12, ends), 0.0)
        a = 1.0 + dm * inverse.sum(axis=0)
        denominator = dm + stacked[0] * a
        scale = np.where(denominator > 0, count / np.where(denominator > 0, denominator, 1.0) ** 2, np.nan)
        ds = [a * dm * scale] + [np.where(other[k], -stacked[0] * dm * dm * inverse[k] ** 2, -stacked[0]) * scale
                                 for k in range(len(ends))]
        steepest = np.stack([np.abs(x).max(axis=0) for x in ds])
        centre = np.abs(stacked[:, 4])
        below = np.maximum(centre - h, 0.0)
        bound = count * np.concatenate([1.0 / (4.0 * below[:1]), (centre[1:].min(axis=0) + h) / (4.0 * below[1:] ** 2)])
        steepest = np.fmin(steepest, bound)
        cost = np.where(np.isfinite(steepest), steepest, np.inf) * np.stack(misses)
    cost = np.where(np.isfinite(cost) & np.stack([np.isfinite(m).all(axis=1) for m in models]), cost, np.inf)
    steepness = np.hypot(grad[..., 0], grad[..., 1])
    around = np.stack([steepness[ci + di, cj + dj] for di, dj in steps])
    weakest = np.where(np.isfinite(around), around, np.inf).min(axis=0)
    budget = np.where(np.isfinite(weakest), tolerance * weakest, 0.0)
    order = np.argsort(cost, axis=0, kind="stable")
    running = np.cumsum(np.take_along_axis(cost, order, axis=0), axis=0)
    modelled = np.zeros(cost.shape, dtype=bool)
    np.put_along_axis(modelled, order, running <= budget, axis=0)
    return np.stack([np.where(use[:, None], model, np.nan) for model, use in zip(models, modelled)])


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(2, 6), st.floats(0.0, 0.2))
def test_ring_models_is_the_numpy_formulation_on_any_fields(seed, sets, unknown):
    """On random distance fields (either sign, some near zero; a share ``unknown`` of the gradients NaN) the compiled ring_models and the numpy formulation model the same ring sets in the same cells
    with the same quadratics: every branch (bounds, poles, ties, NaN) as numpy's passes take it."""
    rng = np.random.default_rng(seed)
    rows, cols = int(rng.integers(3, 12)), int(rng.integers(3, 12))
    d = rng.uniform(-1.0, 6.0, (sets, rows, cols)) * rng.choice([1.0, 1e-3], (sets, rows, cols), p=[0.9, 0.1])
    g = rng.normal(size=(sets, rows, cols, 2))
    grad = rng.normal(size=(rows, cols, 2)) * rng.uniform(0.1, 30.0)
    for a in (g, grad):  # distances are always measured; a gradient is 0 / 0 on a ring, s's NaN past a pole
        a[rng.random(a.shape) < unknown] = np.nan
    ci, cj = (x.ravel() for x in np.meshgrid(np.arange(1, rows - 1), np.arange(1, cols - 1), indexing="ij"))
    dx, dy, count = rng.uniform(0.2, 0.7), rng.uniform(0.2, 0.7), float(rng.integers(1, 60))
    h = 0.5 * np.hypot(dx, dy)
    tolerance = rng.choice([0.02, 2.0, 200.0])
    expected = numpy_ring_models(d, g, grad, ci, cj, dx, dy, count, h, tolerance)
    models = ring_models(d, g, grad, ci, cj, dx, dy, count, h, tolerance)
    np.testing.assert_array_equal(np.isnan(models), np.isnan(expected))
    np.testing.assert_allclose(models, expected, rtol=1e-9, atol=1e-12)

@settings(max_examples=10, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(1, 5))
def test_ring_models_is_the_numpy_formulation(seed, holes):
    """On the lattices of plates with 1 to 5 random holes (graded to the holes, eq. 10), the compiled
    ring_models picks the same ring sets to model in the same cells as the numpy formulation, with the
    same quadratics."""
    from heoslice.grading import field as field_module
    from heoslice.grading.families import Family
    from heoslice.grading.refine import TOLERANCE_PX
    from heoslice.grading.spec import RegionSpec
    from heoslice.layers.rasterising import Grid

    rng = np.random.default_rng(seed)
    angle = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    radius = 9.0 + 0.8 * np.sin(3 * angle + rng.uniform(0, 6))
    rings = [np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])]
    for k in range(holes):
        centre = np.array([np.cos(2 * np.pi * k / holes), np.sin(2 * np.pi * k / holes)]) * (4.0 if holes > 1 else 0)
        r = rng.uniform(0.6, 1.6)
        a = np.linspace(0, 2 * np.pi, int(rng.integers(12, 200)), endpoint=False)[::-1]
        rings.append(centre + rng.uniform(-0.3, 0.3, 2) + np.column_stack([r * np.cos(a), r * np.sin(a)]))
    points = np.concatenate(rings)
    offsets = np.concatenate([[0], np.cumsum([len(r) for r in rings])])
    px = 25.4 / 600
    cells = int(np.ceil(21 / px))
    grid = Grid(width=cells, height=cells, x_left=-cells * px / 2, y_top=cells * px / 2, px=px, py=px)
    calls = []
    compiled = field_module.fit_ring_models

    def recorded(layout, d, g, grad, lattice, grid_, refined):
        models = compiled(layout, d, g, grad, lattice, grid_, refined)
        calls.append((layout, d, g, grad, lattice, refined, models))
        return models

    field_module.fit_ring_models = recorded
    try:
        family = Family(outer=0, holes=tuple(range(1, holes + 1)), nested=False, depth=0)
        field_module.family_field(points, offsets, family, grid, RegionSpec(nozzle_mm=0.2))
    finally:
        field_module.fit_ring_models = compiled
    assert calls
    layout, d, g, grad, lattice, (ci, cj), models = calls[0]
    assert len(ci)
    h = 0.5 * np.hypot(lattice.dx, lattice.dy)
    expected = numpy_ring_models(d, g, grad, ci, cj, lattice.dx, lattice.dy, layout.count, h,
                                 TOLERANCE_PX * px)
    np.testing.assert_array_equal(np.isnan(np.stack(models)[..., 0]), np.isnan(expected[..., 0]))
    np.testing.assert_allclose(np.stack(models), expected, rtol=1e-9, atol=1e-12)
    direct = ring_models(d, g, grad, ci, cj, lattice.dx, lattice.dy, layout.count, h, TOLERANCE_PX * px)
    np.testing.assert_array_equal(direct, np.stack(models))


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 2 ** 31), st.floats(-40.0, 40.0), st.floats(-40.0, 40.0), st.floats(0.0, 5.0),
       st.integers(1, 3), st.booleans())
def test_disc_winding_is_the_turns_around_a_disc_no_edge_enters(seed, x, y, reach, turns, reverse):
    """disc_winding of rings (one traversed ``turns`` times, reversed or not, beside another) is None where
    an edge comes within ``reach`` of the centre (shapely's distance), else the sum of their turns around
    it: ``turns`` (minus that reversed) inside the first ring (shapely), 1 inside the other."""
    rng = np.random.default_rng(seed)
    count = int(rng.integers(5, 300))
    angle = (np.arange(count) + rng.uniform(0.0, 0.9, count)) * (2 * np.pi / count)  # simple: gaps < half a turn
    radius = rng.uniform(3.0, 30.0) * rng.uniform(0.6, 1.0, count)
    ring = np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])
    other = np.column_stack([25.0 + 4.0 * np.cos(angle), 4.0 * np.sin(angle)])
    first = ring[::-1] if reverse else ring
    points = np.concatenate([np.tile(first, (turns, 1)), other])
    offsets = np.array([0, turns * count, (turns + 1) * count])
    rings = shapely.LinearRing(ring), shapely.LinearRing(other)
    gap = min(shapely.distance(shapely.Point(x, y), r) for r in rings)
    if abs(gap - reach) < 1e-9:
        return
    got = disc_winding(points, offsets, np.array([0, 1]), np.array([x, y]), reach)
    if gap <= reach:
        assert got is None
        return
    inside = [bool(shapely.contains_xy(shapely.Polygon(r), x, y)) for r in (ring, other)]
    assert got == (-turns if reverse else turns) * inside[0] + inside[1]
    assert disc_winding(points, offsets, np.array([1]), np.array([x, y]), reach) == inside[1]

@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.booleans(), st.sampled_from([np.int8, np.int16, np.int32]))
def test_curve_cells_is_the_quadratic_formula(seed, masked, label_dtype):
    """curve_cells writes clip(floor(s + g.d + d.H.d / 2) + 1, 1, count) at every pixel of the given cells
    (d the pixel's offset from the cell centre, y up), + base, and 0 off the mask's pixels, and
    leaves every other pixel alone."""
    rng = np.random.default_rng(seed)
    cell, rows, cols, count, base = 6, 4, 5, 30, 3
    s = rng.uniform(-2, count + 2, (rows, cols))
    grad = rng.uniform(-4, 4, (rows, cols, 2))
    hessian = rng.uniform(-9, 9, (3, rows, cols))
    px = py = 0.05
    index = np.full((rows * cell - 2, cols * cell - 1), -7, dtype=label_dtype)
    mask = rng.random(index.shape) < 0.6 if masked else None
    ci, cj = np.array([0, 3, 2]), np.array([1, 4, 0])
    curve_cells(label_target(index, mask, (0, 0), base), ci, cj, CellPixels(cell, px, py), s, grad, hessian, count)
    r, c = np.indices(index.shape)
    i, j = r // cell, c // cell
    x = (c - j * cell + 0.5 - cell / 2) * px
    y = -(r - i * cell + 0.5 - cell / 2) * py
    g, h = grad[i, j], hessian[:, i, j]
    value = s[i, j] + g[..., 0] * x + g[..., 1] * y + 0.5 * (h[0] * x * x + h[2] * y * y) + h[1] * x * y
    expected = np.clip(np.floor(value) + 1, 1, count) + base
    if masked:
        expected = np.where(mask, expected, 0)
    chosen = np.zeros((rows, cols), bool)
    chosen[ci, cj] = True
    inside = chosen[i, j]
    clear = np.abs(value - np.rint(value)) > 1e-9
    assert np.array_equal(index[inside & clear], expected[inside & clear])
    assert (index[~inside] == -7).all()


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


def random_halftone_case(rng, channels: int, height: int, width: int, label_dtype):
    """A random droplet_bits input: solid pixels in runs, a label box that covers only part of them (offset,
    clipped), a few families of random per-cell start mixes, and a choice table whose entries are a
    random channel or -1 (per pixel mix) per label and level, row 0 the base channel."""
    solid = np.repeat(rng.random((height, -(-width // 3))) < 0.7, 3, axis=1)[:, :width]
    r0, c0 = int(rng.integers(0, height)), int(rng.integers(0, width))
    rows, cols = int(rng.integers(0, height - r0 + 1)), int(rng.integers(0, width - c0 + 1))
    families, per_family = int(rng.integers(1, 4)), int(rng.integers(1, 6))
    count = 1 + families * per_family
    label = np.repeat(rng.integers(0, count, (rows, -(-cols // 4))), 4, axis=1)[:, :cols].astype(label_dtype)
    family_of_label = np.concatenate([[0], np.repeat(np.arange(families), per_family)]).astype(np.int64)
    layout, mixes = [], []
    for _ in range(families):
        cell = int(rng.integers(1, 9))
        grid_rows, grid_cols = -(-max(rows, 1) // cell), -(-max(cols, 1) // cell)
        mix = rng.random((grid_rows * grid_cols, channels)) * (rng.random((grid_rows * grid_cols, channels)) < 0.8)
        layout.append((r0, c0, cell, grid_cols, sum(m.size for m in mixes)))
        mixes.append(mix.ravel())
    base = int(rng.integers(0, channels))
    table = rng.integers(0, channels, (count, 256)).astype(np.int8)
    per_pixel = rng.random(count) < 0.4
    table[per_pixel] = -1
    table[rng.random((count, 256)) < 0.1] = -1
    table[0] = base
    return dict(solid=solid, label=label, origin=(r0, c0), family_of_label=family_of_label,
                fraction=rng.random(count).astype(np.float32), layout=np.array(layout, dtype=np.int64),
                mixes=np.concatenate(mixes).astype(np.float32),
                target=np.eye(channels, dtype=np.float32)[int(rng.integers(0, channels))], base=base, table=table)


def assert_droplet_bits_are_the_per_pixel_choice(rng, case: dict, channels: int, tile: np.ndarray, level: np.ndarray,
                                                 layer: int) -> None:
    """droplet_bits on ``case`` equals np.packbits of the brute-force per-pixel choice (the table entry at the
    pixel's dither ``level``, choose_materials of its eq. 1 mix where that is -1, the base channel outside
    the labels and on label 0), and it leaves every byte without a solid pixel as it was."""
    from helpers import choose_materials

    solid, label, (r0, c0), table = case["solid"], case["label"], case["origin"], case["table"]
    size = level.shape[0]
    rows, cols = label.shape
    r, c = np.indices(solid.shape)
    inside = (r >= r0) & (r < r0 + rows) & (c >= c0) & (c < c0 + cols)
    number = np.zeros(solid.shape, dtype=np.int64)
    number[inside] = label[r[inside] - r0, c[inside] - c0]
    entry = table[number, level[r % size, c % size]].astype(np.int64)
    family = case["family_of_label"][number]
    cell_row, cell_col, cell, per_row, start = np.moveaxis(case["layout"][family], -1, 0)
    first = start + (((r - cell_row) // cell) * per_row + (c - cell_col) // cell) * channels
    start_mix = case["mixes"][np.where(inside & (entry < 0), first, 0)[None] + np.arange(channels)[:, None, None]]
    f = case["fraction"][number][None]
    mix = start_mix + f * (case["target"][:, None, None] - start_mix)
    chosen = np.where(inside & (entry >= 0), entry, case["base"])
    chosen = np.where(inside & (entry < 0), choose_materials(mix, solid, layer), chosen)
    expected = np.packbits((chosen[None] == np.arange(channels)[:, None, None]) & solid[None], axis=2)

    args = (label, (r0, c0), np.packbits(solid, axis=1), case["family_of_label"], case["fraction"], case["layout"],
            case["mixes"], case["target"], tile, case["base"])
    assert np.array_equal(halftone_bits(*args, np.zeros_like(expected), table), expected)
    junk = rng.integers(0, 256, expected.shape, dtype=np.uint8)
    got = halftone_bits(*args, junk.copy(), table)
    written = np.packbits(solid, axis=1).astype(bool)[None].repeat(channels, axis=0)
    assert np.array_equal(got[written], expected[written])
    assert np.array_equal(got[~written], junk[~written])


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.sampled_from([1, 2, 3, 4, 5, 9]), st.integers(1, 40), st.integers(1, 70),
       st.sampled_from([np.int8, np.int16, np.int32]))
def test_droplet_bits_is_the_per_pixel_choice_packed(seed, channels, height, width, label_dtype):
    """droplet_bits equals np.packbits of the brute-force per-pixel choice: outside the label box and on
    label 0 the base channel, else the table entry at the pixel's dither level, else (entry -1)
    choose_materials of the pixel's eq. 1 mix; for any number of channels (one to nine, over one
    pattern word or several), widths not a multiple of 8 or 16, label boxes covering part of the solid;
    and it writes only the bytes that hold a solid pixel."""
    from heoslice.grading.halftone import layer_tile

    rng = np.random.default_rng(seed)
    case = random_halftone_case(rng, channels, height, width, label_dtype)
    layer = int(rng.integers(0, 1000))
    tile = layer_tile(layer)
    level = np.rint(tile * 256 - 0.5).astype(np.int64)
    assert_droplet_bits_are_the_per_pixel_choice(rng, case, channels, tile, level, layer)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.sampled_from([1, 2, 3, 4]), st.integers(1, 30), st.integers(40, 200))
def test_droplet_bits_of_one_label_everywhere_is_the_per_pixel_choice(seed, channels, height, width):
    """One label at every pixel of the box (a coloured layer of one family), its table entries nearly all
    set: the chunks taken as that label's whole pattern word give the brute-force per-pixel choice."""
    from heoslice.grading.halftone import layer_tile

    rng = np.random.default_rng(seed)
    for _ in range(50):  # a box of whole chunks, drawn again rather than filtered (hypothesis's health check)
        case = random_halftone_case(rng, channels, height, width, np.int16)
        rows, cols = case["label"].shape
        if rows > 0 and cols >= 32:
            break
    assume(rows > 0 and cols >= 32)
    value = int(rng.integers(1, len(case["table"])))
    case["table"][value] = rng.integers(0, channels, 256)
    case["table"][value, rng.random(256) < 0.02] = -1
    case["label"] = np.broadcast_to(np.int16(value), (rows, cols))
    layer = int(rng.integers(0, 1000))
    tile = layer_tile(layer)
    assert_droplet_bits_are_the_per_pixel_choice(rng, case, channels, tile, np.rint(tile * 256 - 0.5).astype(np.int64),
                                                 layer)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.sampled_from([1, 2, 3, 5]), st.integers(2, 30), st.integers(1, 70))
def test_droplet_bits_reads_labels_broadcast_down_their_box_as_their_copy(seed, channels, height, width):
    """Labels that are one value, or one row, seen at every row of the box (a layer of one family of one
    sub-region: no array of the box) make the same masks as the same labels written out row by row."""
    from heoslice.grading.halftone import layer_tile

    rng = np.random.default_rng(seed)
    for _ in range(50):  # a box of two rows or more, drawn again rather than filtered (hypothesis's health check)
        case = random_halftone_case(rng, channels, height, width, np.int16)
        rows, cols = case["label"].shape
        if rows > 1 and cols > 0:
            break
    assume(rows > 1 and cols > 0)
    tile = layer_tile(int(rng.integers(0, 1000)))
    args = (np.packbits(case["solid"], axis=1), case["family_of_label"], case["fraction"], case["layout"],
            case["mixes"], case["target"], tile, case["base"])
    value = np.int16(rng.integers(0, len(case["table"])))
    for label in (np.broadcast_to(value, (rows, cols)), np.broadcast_to(case["label"][:1], (rows, cols))):
        assert label.strides[0] == 0
        planes = np.zeros((channels, height, -(-width // 8)), np.uint8)
        expected = halftone_bits(label.copy(), case["origin"], *args, planes.copy(), case["table"])
        assert np.array_equal(halftone_bits(label, case["origin"], *args, planes, case["table"]), expected)


@pytest.mark.parametrize("size", [1, 2, 4, 8, 16, 32, 64])
def test_droplet_bits_follows_a_dither_tile_of_any_size(size):
    """With an ordered-dither tile of any power-of-two size n (smaller than the 16-pixel pattern block,
    or larger: several blocks per tile row), each labelled pixel jets table[label, level] at its level
    bayer[row % n, col % n] (levels (k + 1/2) / n^2), exactly as a per-pixel look-up."""
    from heoslice.grading.halftone import bayer_matrix

    rng = np.random.default_rng(size)
    channels, height, width = 3, 70, 133
    solid = rng.random((height, width)) < 0.9
    label = rng.integers(0, 20, (height - 5, width - 9)).astype(np.int16)
    table = rng.integers(0, channels, (20, size * size)).astype(np.int8)
    table[0] = 1
    bayer = bayer_matrix(size)
    r, c = np.indices(solid.shape)
    number = np.zeros(solid.shape, dtype=np.int64)
    number[2:2 + label.shape[0], 7:7 + label.shape[1]] = label
    chosen = table[number, bayer[r % size, c % size]]
    expected = np.packbits((chosen[None] == np.arange(channels)[:, None, None]) & solid[None], axis=2)
    planes = np.zeros_like(expected)
    got = halftone_bits(label, (2, 7), np.packbits(solid, axis=1), np.zeros(20, np.int64), np.zeros(20),
                       np.zeros((1, 5), np.int64), np.zeros(channels), np.zeros(channels),
                       (bayer + 0.5) / (size * size), 1, planes, table)
    assert np.array_equal(got, expected)


def test_droplet_bits_takes_every_layers_tile_through_one_compiled_signature():
    """Tiles of layers under every symmetry (transposed ones are Fortran-ordered) reach the kernel as the same
    C-ordered argument types: the compiled kernel (which checks its arguments in the tests) takes them all;
    compiled just in time, numba makes one version, not one per layout."""
    from heoslice.grading.droplets_kernels import _droplet_bits
    from heoslice.grading.halftone import layer_tile
    from heoslice.jit import CHECK_VARIABLE, compiled_module

    label = np.ones((4, 16), np.int16)
    table = np.ones((2, 256), np.int8)
    for layer in range(8):
        halftone_bits(label, (0, 0), np.full((4, 2), 255, np.uint8), np.zeros(2, np.int64), np.zeros(2),
                     np.zeros((1, 5), np.int64), np.zeros(2), np.zeros(2), layer_tile(layer), 0,
                     np.zeros((2, 4, 2), np.uint8), table)
    assert {layer_tile(layer).flags.f_contiguous for layer in range(8)} == {True, False}
    if compiled_module() is not None:
        assert os.environ.get(CHECK_VARIABLE) == "1"  # so each call above checked its arrays were C-ordered
    else:
        layouts = {array.layout for signature in _droplet_bits.overloads for array in signature[2].types[:3]}
        assert layouts == {"C"}


def wide_halftone_case(rng, channels: int, missing: str, entries: int):
    """A droplet_bits input with rows of many 16-pixel chunks inside the labels: label bands of 1-12 pixels,
    solid pixels with empty stretches (whole empty bytes and chunks), the label box a little inside the
    solid; the table ((labels, entries) int8) has no -1 ('none'), all -1 for one family's labels as a
    family of per-cell mixes gets ('labels'), or -1 at scattered entries ('entries')."""
    height, width = 12, 16 * 23 + 5
    solid = rng.random((height, width)) < 0.95
    for start in rng.integers(0, width, 6):
        solid[:, start:start + int(rng.integers(8, 40))] = False
    r0, c0 = int(rng.integers(0, 3)), int(rng.integers(0, 20))
    rows, cols = height - r0 - int(rng.integers(0, 3)), width - c0 - int(rng.integers(0, 20))
    families, per_family = 3, 4
    count = 1 + families * per_family
    runs = rng.integers(1, 13, cols)
    label = np.repeat(rng.integers(0, count, (rows, cols)), runs, axis=1)[:, :cols].astype(np.int16)
    family_of_label = np.concatenate([[0], np.repeat(np.arange(families), per_family)]).astype(np.int64)
    layout, mixes = [], []
    for _ in range(families):
        cell = int(rng.integers(1, 9))
        grid_rows, grid_cols = -(-rows // cell), -(-cols // cell)
        layout.append((r0, c0, cell, grid_cols, sum(m.size for m in mixes)))
        mixes.append(rng.random(grid_rows * grid_cols * channels))
    base = int(rng.integers(0, channels))
    table = rng.integers(0, channels, (count, entries)).astype(np.int8)
    if missing == "labels":
        table[family_of_label == int(rng.integers(0, families))] = -1
    elif missing == "entries":
        table[rng.random((count, entries)) < 0.02] = -1
    table[0] = base
    return dict(solid=solid, label=label, origin=(r0, c0), family_of_label=family_of_label,
                fraction=rng.random(count).astype(np.float32), layout=np.array(layout, dtype=np.int64),
                mixes=np.concatenate(mixes).astype(np.float32),
                target=np.eye(channels, dtype=np.float32)[int(rng.integers(0, channels))], base=base, table=table)


@pytest.mark.parametrize("channels", [1, 2, 3, 4, 5])
@pytest.mark.parametrize("size", [4, 16, 32])
@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), missing=st.sampled_from(["none", "labels", "entries"]))
def test_droplet_bits_is_the_per_pixel_choice_along_wide_rows(channels, size, seed, missing):
    """Along rows of many 16-pixel chunks inside the labels, droplet_bits is the brute-force per-pixel choice
    (the table entry at the pixel's level of the n x n dither tile, choose_materials of the eq. 1 mix
    where it is -1, the base channel outside the labels) for one to five channels (two, the last
    plane the solid less the first; up to four, one pattern word), whether no label lacks an entry,
    a whole family does (stretches of per-pixel mixes between table look-ups) or scattered entries
    do (with the 16 x 16 tile of choose_materials; other tile sizes without -1 entries, several pattern
    blocks per tile row at 32); bytes without a solid pixel are left as they were."""
    from heoslice.grading.halftone import bayer_matrix, layer_tile

    rng = np.random.default_rng(seed)
    layer = int(rng.integers(0, 1000))
    if size != 16:
        missing = "none"
    tile = layer_tile(layer) if size == 16 else (bayer_matrix(size) + 0.5) / (size * size)
    level = np.rint(tile * size * size - 0.5).astype(np.int64)
    case = wide_halftone_case(rng, channels, missing, size * size)
    assert_droplet_bits_are_the_per_pixel_choice(rng, case, channels, tile, level, layer)


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


def test_inside_centres_counts_a_vertex_once_where_an_edges_end_rounds_off_it():
    """A ring vertex V at a tiny height after an edge from far below it: that edge's start plus its vector
    rounds to another height than V (a symmetric vase's contour on its axis). A row of centres between
    the two heights crosses the ring once at V, as solid_mask says, not zero times (the whole row left
    of the opposite side taken as outside)."""
    from heoslice.layers.rasterising import Grid, solid_mask

    low, tiny = -1.5100663520656847, 1.8867087487162623e-15
    loop = np.array([[-15.40614612290143, tiny], [-14.0, -low], [14.0, -low], [15.4, 0.0], [14.0, low],
                     [-14.0, low]])
    edges = ring_edges(loop, np.array([0, len(loop)]), [0])
    arrived = low + (tiny - low)  # where the edge from (-14, low) ends: not tiny
    assert arrived != tiny
    gap = 0.5 * (arrived + tiny)
    grid = Grid(width=70, height=4, x_left=-17.5, y_top=0.25 + gap, px=0.5, py=0.5)
    row_height = grid.y_top - 0.5 * grid.py
    assert min(arrived, tiny) <= row_height < max(arrived, tiny)
    inside = inside_centres(edges, LatticeFrame(grid.x_left, grid.y_top, grid.px, grid.py), grid.height, grid.width)
    expected = solid_mask(loop[::-1] if not shapely.LinearRing(loop).is_ccw else loop, np.array([0, len(loop)]), grid)
    assert expected[0].sum() > 50
    assert np.array_equal(inside, expected)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(1, 3))
def test_values_at_points_are_numpys_interpolation_bit_for_bit(seed, columns):
    """values_at_points equals numpy's own: t of each point's projection on its edge, clipped, its position
    edge + ring + t along the knots, and np.interp there, bit for bit; for edges spanning several knots
    (points on the straight line between their neighbours), points beyond their edge's ends, points
    exactly on an edge's first knot, and one to three columns."""
    rng = np.random.default_rng(seed)
    rings = []
    for corners in random_ring_points(rng, int(rng.integers(1, 4))):
        ring = []
        for i, corner in enumerate(corners):  # points put on the edges: left out of them, kept as knots
            following = corners[(i + 1) % len(corners)]
            spanned = rng.uniform(0.01, 0.99, int(rng.integers(1 if i == 0 else 0, 3)))
            ring += [corner] + [corner + t * (following - corner) for t in np.sort(spanned)]
        rings.append(np.array(ring))
    edges = ring_edges(np.concatenate(rings), np.cumsum([0] + [len(ring) for ring in rings]), range(len(rings)))
    assert len(edges.knots) > len(edges.x) + len(rings)  # some edge spans several knots
    values = rng.uniform(-1.0, 2.0, (len(edges.knots), columns))
    count = 300
    edge = rng.integers(0, len(edges.x), count)
    t = np.where(rng.random(count) < 0.2, rng.choice([0.0, 1.0, -0.5, 1.5], count), rng.uniform(0.0, 1.0, count))
    near = np.stack([edges.x[edge] + t * edges.vx[edge] + rng.normal(0, 0.01, count) * edges.vy[edge],
                     edges.y[edge] + t * edges.vy[edge] - rng.normal(0, 0.01, count) * edges.vx[edge]])
    along = ((near[0] - edges.x[edge]) * edges.vx[edge] + (near[1] - edges.y[edge]) * edges.vy[edge]) * edges.inv_len2[edge]
    at = edge + edges.ring[edge] + np.clip(along, 0.0, 1.0)
    expected = np.stack([np.interp(at, edges.knots, values[:, c]) for c in range(columns)], axis=-1)
    got = values_at_points(near.reshape(2, 15, 20), edge.reshape(15, 20), edges, values)
    assert got.shape == (15, 20, columns)
    assert got.reshape(count, columns).tobytes() == expected.tobytes()
