"""Tests of heoslice.grading.refine_kernels: which cells refine_flags refines (planes and quadratics that
fit, kinks, turns beside the outline), hessian_of against numpy.gradient, band_cells against eq. 10 of modelled
or measured distances, the sensitivities of eq. 10 against central differences, and the compiled ring_models
against the numpy formulation it replaced, measured_cells against the two steps it fuses, and vertices_by_cell
against a stable sort of the vertices by cell."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import ring_weights
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.grading.edges_kernels import EdgeArrays
from heoslice.grading.field import LABEL_TYPES
from heoslice.grading.field_kernels import CellPixels, band_field, label_target
from heoslice.grading.refine_kernels import (
    CellField,
    FitTest,
    band_cells,
    hessian_of,
    measured_cells,
    refine_flags,
    ring_models,
    vertices_by_cell,
)
from heoslice.grading.search_kernels import edge_tree, nearest_in_groups


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(1, 5), st.booleans(), st.sampled_from(LABEL_TYPES))
def test_band_cells_is_eq10_of_modelled_or_measured_distances(seed, sets, masked, label_dtype):
    """band_cells writes, at every pixel of the given cells, clip(floor(s) + 1, 1, count) of s by eq. 10
    (s = (1 - w_start) count from helpers.ring_weights for two or more ring sets, d count / length for
    one) of each ring set's distance there: its quadratic where the cell's model is given, the measured
    value (from its slot in a packed array) where it is NaN; + base (labels past 127 too, in uint8), and 0
    off the mask's pixels; pixels past the image and other cells untouched."""

    rng = np.random.default_rng(seed)
    cell, rows, cols, count, length, base = 5, 4, 5, int(rng.integers(1, 40)), 3.0, int(rng.integers(0, 210))
    px = py = 0.05
    index = np.full((rows * cell - 2, cols * cell - 1), 255, dtype=label_dtype)
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
    assert (index[~written] == 255).all()


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.booleans(), st.sampled_from(LABEL_TYPES), st.integers(3, 12))
def test_measured_cells_equal_the_search_then_band_cells(seed, masked, label_dtype, cell):
    """measured_cells writes, bit for bit, what refine_cells' two steps write for one ring set without a
    model: the squared distances of nearest_in_groups, their float32 roots, then band_cells; every pixel
    of the given cells written (+ base, 0 off the mask), every other one untouched."""
    rng = np.random.default_rng(seed)
    # a star-shaped ring of 40 vertices, radius 2-5 mm round the origin
    angle = np.sort(rng.uniform(0, 2 * np.pi, 40))
    radius = rng.uniform(2.0, 5.0, 40)
    x, y = radius * np.cos(angle), radius * np.sin(angle)
    vx, vy = np.roll(x, -1) - x, np.roll(y, -1) - y
    edges = EdgeArrays(x, y, vx, vy, 1.0 / (vx * vx + vy * vy))
    tree = edge_tree(x, y, x + vx, y + vy)
    px, py = 0.042, 0.05
    rows, cols, count, base = 9, 11, int(rng.integers(2, 60)), int(rng.integers(0, 190))
    length = float(rng.uniform(1.0, 5.0))
    frame = (-5.5, 5.0, cell * px, cell * py)  # lattice x0, y0 (top left) and cell size, mm
    shape = (rows * cell - int(rng.integers(0, cell)), cols * cell - int(rng.integers(0, cell)))
    mask = rng.random(shape) < 0.7 if masked else None
    n = int(rng.integers(1, 30))
    ci, cj = rng.integers(0, rows, n), rng.integers(0, cols, n)
    ci, cj = np.unique(np.column_stack([ci, cj]), axis=0).T
    v, u = np.divmod(np.arange(cell * cell), cell)
    ox = ((u + 0.5 - 0.5 * cell) * px).astype(np.float32)
    oy = (-(v + 0.5 - 0.5 * cell) * py).astype(np.float32)
    reach = rng.uniform(8.0, 12.0, len(ci))  # past every edge: all are candidates
    pixels = CellPixels(cell, px, py)
    cx, cy = frame[0] + (cj + 0.5) * frame[2], frame[1] - (ci + 0.5) * frame[3]
    squared = nearest_in_groups(cx, cy, reach, ox, oy, edges, tree, False)
    two_steps = np.full(shape, 255, dtype=label_dtype)
    band_cells(label_target(two_steps, mask, (0, 0), base), ci, cj, pixels, np.full((1, len(ci), 6), np.nan),
               np.sqrt(squared), np.arange(len(ci))[None], count, length)
    fused = np.full(shape, 255, dtype=label_dtype)
    measured_cells(label_target(fused, mask, (0, 0), base), ci, cj, pixels, frame, reach, ox, oy, edges, tree,
                   count, length)
    assert np.array_equal(fused, two_steps)
    chosen = np.zeros((rows, cols), bool)
    chosen[ci, cj] = True
    r, c = np.indices(shape)
    assert (fused[~chosen[r // cell, c // cell]] == 255).all()
    assert (fused[chosen[r // cell, c // cell]] != 255).all()


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


def vertices_sorted_by_cell(x, y, s, x0, y0, dx, dy, rows, cols):
    """The reference: each vertex's cell from floor((x - x0) / dx) and floor((y0 - y) / dy), vertices off the
    lattice dropped, the rest in np.argsort(kind="stable") order of their cell, and the cells' CSR start."""
    col = np.floor((x - x0) / dx).astype(np.int64)
    row = np.floor((y0 - y) / dy).astype(np.int64)
    keep = (col >= 0) & (col < cols) & (row >= 0) & (row < rows)
    key = (row * cols + col)[keep]
    order = np.argsort(key, kind="stable")
    start = np.concatenate([[0], np.cumsum(np.bincount(key, minlength=rows * cols))])
    return start, x[keep][order], y[keep][order], s[keep][order]


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), rows=st.integers(1, 9), cols=st.integers(1, 9), cell=st.floats(0.1, 0.7))
def test_vertices_by_cell_is_a_stable_sort_by_cell(seed, rows, cols, cell):
    """vertices_by_cell groups vertices inside, on the edges of and outside a lattice by their cell: the CSR
    start, x, y and s of a stable sort by cell, bit for bit, vertices off the lattice left out."""
    rng = np.random.default_rng(seed)
    x0, y0, count = -1.0, 2.0, int(rng.integers(1, 60))
    x = x0 + rng.uniform(-0.3, 1.3, count) * cols * cell
    y = y0 - rng.uniform(-0.3, 1.3, count) * rows * cell
    x[: count // 4] = x0 + rng.integers(0, cols + 1, count // 4) * cell  # on the cells' edges
    s = rng.integers(0, 3, count).astype(np.float64)  # ring sets' exact s: 0 on the starting rings, N_R on the ends
    found = vertices_by_cell(x, y, s, x0, y0, cell, cell, rows, cols)
    expected = vertices_sorted_by_cell(x, y, s, x0, y0, cell, cell, rows, cols)
    assert (found.x0, found.y0) == (x0, y0)
    for got, wanted in zip(found[:4], expected):
        assert np.array_equal(got, wanted)
