"""Tests of heoslice.grading.lattice: block bounds, blocks off a family left unmeasured, measures kept a layer."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import (
    brute_squared,
    circle,
    grid_around,
    layer,
    random_rings,
    rough_outline,
    tree_of,
)
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.grading import (
    GradeSpec,
    GradingCache,
    RegionSpec,
    family_field,
    layer_families,
    layer_regions,
)
from heoslice.grading import field as field_module
from heoslice.grading import lattice as lattice_module
from heoslice.grading.cache import RingMemo
from heoslice.layers.rasterising import solid_mask
from heoslice.material import DEFAULT_MATERIALS, Material, make_function

pytestmark = pytest.mark.usefixtures("lattice_fit_for_every_family")  # conftest.py: small families on the lattice too


def _labels_culled_and_full(points, offsets, area, parent, grid, spec):
    """A layer's labels with the blocks off the family's side skipped and with every block measured, and
    whether any block was skipped."""
    from unittest import mock

    mask = solid_mask(points, offsets, grid)
    culled = layer_regions(points, offsets, area, parent, mask, grid, spec)
    passes, skipped = lattice_module.block_passes, []

    def never_far(*args):
        edge, upper, inside, far = passes(*args)
        skipped.append(bool(far.any()))
        return edge, upper, inside, np.zeros_like(far)

    with mock.patch.object(lattice_module, "block_passes", never_far):
        full = layer_regions(points, offsets, area, parent, mask, grid, spec)
    return culled.label, full.label, any(skipped)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.sampled_from(["in", "out"]))
def test_skipping_blocks_off_the_family_changes_no_label(seed, direction):
    """Lattice blocks judged wholly off the family's side are not measured; labelling with every block
    measured gives the same labels at every pixel (random bumpy outlines with one or two holes)."""
    rng = np.random.default_rng(seed)
    outer = rough_outline(int(rng.integers(0, 2 ** 31)), count=400, radius=9.0)
    holes = [circle(float(rng.uniform(0.5, 2.0)), 120, (float(x), float(y)), clockwise=True)
             for x, y in ((-3.5, rng.uniform(-2, 2)), (3.5, rng.uniform(-2, 2)))[: int(rng.integers(1, 3))]]
    culled, full, _ = _labels_culled_and_full(*layer(outer, *holes), grid_around(11.0),
                                              RegionSpec(nozzle_mm=0.25, direction=direction))
    assert np.array_equal(culled, full)


@pytest.mark.parametrize("direction", ["in", "out"])
def test_blocks_inside_a_wide_hole_and_outside_the_outline_are_skipped_without_changing_a_label(direction):
    """A ring with a wide hole, on a grid with room around it: blocks deep in the hole and outside the
    outline are skipped, and the labels are those measured with every block."""
    culled, full, skipped = _labels_culled_and_full(*layer(circle(12.0, 300), circle(7.0, 200, clockwise=True)),
                                                    grid_around(24.0), RegionSpec(nozzle_mm=0.25, direction=direction))
    assert skipped and np.array_equal(culled, full)


def test_a_one_subregion_family_measures_its_lattice_only_when_its_nearest_points_are_asked_for():
    """With one sub-region (k = 1 throughout) a lattice family's field measures nothing of its rings until
    ``nearest()`` is called; then what it gives is the eagerly measured field's of a two-sub-region spec on
    the same lattice (the same starting rings' feet and edges), and the measures are kept for the next layer."""
    ring = circle(4.0, 211)
    points, offsets, area, parent = layer(ring)
    family, grid = layer_families(area, parent)[0], grid_around(4.5)
    memo = RingMemo()
    lazy = family_field(points, offsets, family, grid, RegionSpec(count=1), memo=memo)
    assert lazy.layout.count == 1 and (lazy.index == 1).all()
    measured_before = [key for key in memo.now if len(key) == 2 and isinstance(key[1], lattice_module.Lattice)]
    assert measured_before == []
    foot, edge = lazy.nearest()
    assert any(len(key) == 2 and isinstance(key[1], lattice_module.Lattice) for key in memo.now)
    eager = family_field(points, offsets, family, grid, RegionSpec(count=2))
    assert eager.lattice == lazy.lattice
    eager_foot, eager_edge = eager.nearest()
    np.testing.assert_array_equal(foot, eager_foot)
    np.testing.assert_array_equal(edge, eager_edge)


def test_rings_that_stay_give_their_last_centres_only_for_the_same_blocks_wanted(monkeypatch):
    """Through a cavity (one hole of a plate growing and shrinking from layer to layer, the other hole staying),
    the plate's field measured with what the last layer measured equals the field measured afresh; the rings
    that stay have their centres measured again only when the blocks wanted change (the big hole's deep
    inside drops blocks), and not at all on a layer like the last."""
    from heoslice.grading import lattice as compiled

    measured = []
    original = compiled.signed_feet
    monkeypatch.setattr(compiled, "signed_feet", lambda *args: measured.append(1) or original(*args))
    plate = np.array([[-12.0, -9.0], [12.0, -9.0], [12.0, 9.0], [-12.0, 9.0]])
    stay = circle(2.0, 96, (-7.0, 0.0), clockwise=True)
    grid = grid_around(12.5)
    spec = RegionSpec(nozzle_mm=0.3)
    before: dict = {}
    counts = []
    for radius in [1.0, 2.0, 6.5, 5.5, 2.0, 2.0]:
        points, offsets, area, parent = layer(plate, stay, circle(radius, 128, (4.0, 0.0), clockwise=True))
        family = layer_families(area, parent)[0]
        memo = RingMemo(before=before)
        start = len(measured)
        kept = family_field(points, offsets, family, grid, spec, memo=memo)
        counts.append(len(measured) - start)
        assert np.array_equal(kept.index, family_field(points, offsets, family, grid, spec).index)
        before = memo.now
    assert counts == [3, 1, 3, 3, 1, 0]


def test_holes_that_stay_while_another_shrinks_are_measured_once(monkeypatch):
    """A plate whose big hole shrinks layer by layer (more of the lattice is wanted each time) while its outline
    and small hole stay: only the shrinking hole's lattice passes are made again, the others' are taken from
    the layer before and completed where newly wanted, and the droplet masks equal those measured afresh."""
    from heoslice.grading import droplet_planes

    plate = np.array([[-20.0, -14.0], [20.0, -14.0], [20.0, 14.0], [-20.0, 14.0]])
    small = circle(1.5, 64, (14.0, 8.0), clockwise=True)
    grid = grid_around(20.5)
    spec = GradeSpec(RegionSpec(nozzle_mm=0.3), make_function("linear"), Material("green", (0, 255, 0)),
                     None, DEFAULT_MATERIALS["M1"], DEFAULT_MATERIALS["M2"])
    passes = []
    ring_measures = field_module.ring_measures
    monkeypatch.setattr(field_module, "ring_measures", lambda *args: passes.append(1) or ring_measures(*args))
    cache = GradingCache()
    for index, radius in enumerate([11.0, 10.0, 8.5, 7.0]):
        points, offsets, area, parent = layer(plate, circle(radius, 200, (-6.0, 0.0), clockwise=True), small)
        packed = np.packbits(solid_mask(points, offsets, grid), axis=1)
        args = (points, offsets, area, parent, None, None, grid, spec, index)
        before = len(passes)
        kept = droplet_planes(*args, packed=packed, cache=cache)
        assert len(passes) - before == (3 if index == 0 else 1)
        assert np.array_equal(kept, droplet_planes(*args, packed=packed))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(1, 4))
def test_block_bounds_are_the_distances_to_the_edges_nearest_the_block_centres(seed, rings):
    """Each block's bound is the exact distance to its edge, and that edge is the nearest to the block's centre
    (within float32 rounding of the search): never below the true distance, so every radius built on it holds
    the nearest edge, and never more than 1e-4 mm above it."""
    rng = np.random.default_rng(seed)
    edges = random_rings(rng, rings)
    lattice = lattice_module.Lattice(row0=0, col0=0, cell=8, rows=int(rng.integers(1, 120)), cols=int(rng.integers(1, 120)),
                              x0=-70.0, y0=70.0, dx=float(rng.uniform(0.3, 1.5)), dy=float(rng.uniform(0.3, 1.5)))
    bounds = lattice_module.block_bounds(edges, lattice, tree_of(edges))
    x, y = bounds.blocks.centres()
    cx, cy = np.meshgrid(x, y)
    squared = brute_squared(cx.ravel(), cy.ravel(), edges)
    exact = np.sqrt(squared.min(axis=1))
    of_edge = np.sqrt(squared[np.arange(len(exact)), bounds.edge.ravel()])
    np.testing.assert_allclose(bounds.upper.ravel(), of_edge, rtol=0, atol=1e-9)
    assert np.all(bounds.upper.ravel() >= exact - 1e-9) and np.all(bounds.upper.ravel() <= exact + 1e-4)


# --- The lattice passes written out in numpy (as they were before they were compiled) -------------------

def _far_reference(rings, inside, bounds, lattice):
    """The blocks off the family's side, judged at one cell each: off the family's side by more than the way
    to the block's farthest cell centre plus a cell's diagonal and a half, measured exactly."""
    from heoslice.grading.search import nearest_edges

    b = lattice_module.BLOCK
    first_r, first_c = np.arange(bounds.blocks.rows) * b, np.arange(bounds.blocks.cols) * b
    rep_r = np.minimum(first_r + b // 2, lattice.rows - 1)
    rep_c = np.minimum(first_c + b // 2, lattice.cols - 1)
    span_r = np.maximum(rep_r - first_r, np.minimum(first_r + b - 1, lattice.rows - 1) - rep_r) * lattice.dy
    span_c = np.maximum(rep_c - first_c, np.minimum(first_c + b - 1, lattice.cols - 1) - rep_c) * lattice.dx
    margin = np.hypot(span_r[:, None], span_c[None, :]) + 1.5 * np.hypot(lattice.dx, lattice.dy)
    x, y = lattice.centres()
    bx, by = bounds.blocks.centres()
    reach = bounds.upper + np.hypot((x[rep_c] - bx)[None, :], (y[rep_r] - by)[:, None])
    far = (inside[np.ix_(rep_r, rep_c)] != rings.encloses) & (reach > margin)
    if far.any():
        rows, cols = np.nonzero(far)
        squared = nearest_edges(x[rep_c[cols]], y[rep_r[rows]], reach[far] * (1 + 1e-9) + 1e-9, np.zeros(1),
                                np.zeros(1), rings.edges, rings.tree, track=False)
        far[rows, cols] = squared.ravel() > margin[far] ** 2
    return far


def _edges_reference(rings, lattice, bounds, wanted):
    """Every cell centre's nearest edge in the wanted blocks (candidates within U + 2 max a of the block's
    centre), the block's edge elsewhere."""
    from heoslice.grading.search import nearest_edges

    blocks, b = bounds.blocks, lattice_module.BLOCK
    edge = np.repeat(bounds.edge[:, :, None], b * b, axis=2)
    chosen = np.nonzero(wanted)
    if len(chosen[0]):
        x, y = blocks.centres()
        v, u = (a.ravel() for a in np.meshgrid(np.arange(b), np.arange(b), indexing="ij"))
        ox, oy = (u + 0.5 - 0.5 * b) * lattice.dx, -(v + 0.5 - 0.5 * b) * lattice.dy
        edge[chosen] = nearest_edges(x[chosen[1]], y[chosen[0]], bounds.upper[chosen] + 2.0 * np.hypot(ox, oy).max(),
                                     ox, oy, rings.edges, rings.tree)
    edge = edge.reshape(blocks.rows, blocks.cols, b, b).transpose(0, 2, 1, 3).reshape(blocks.rows * b, blocks.cols * b)
    return edge[:lattice.rows, :lattice.cols]


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(1, 3), st.booleans())
def test_the_compiled_lattice_passes_are_the_numpy_passes_bit_for_bit(seed, rings, encloses):
    """On random rings and lattices of 1 to 40 cells a side (blocks cut short at the edges), the compiled
    passes give the blocks off the family's side, and the wanted blocks' nearest edges, of the numpy passes
    written out above from the same block bounds and centres inside, value for value."""
    from heoslice.grading.search import LazyTree, RingSet

    rng = np.random.default_rng(seed)
    edges = random_rings(rng, rings)
    ring_set = RingSet(tuple(range(rings)), edges, encloses, LazyTree(edges))
    lattice = lattice_module.Lattice(row0=0, col0=0, cell=8, rows=int(rng.integers(1, 41)),
                                     cols=int(rng.integers(1, 41)), x0=float(rng.uniform(-80, -40)),
                                     y0=float(rng.uniform(40, 80)), dx=float(rng.uniform(0.5, 3.0)),
                                     dy=float(rng.uniform(0.5, 3.0)))
    measures = lattice_module.ring_measures(ring_set, lattice)
    assert np.array_equal(measures.far, _far_reference(ring_set, measures.inside, measures.bounds, lattice))
    wanted = rng.random(measures.far.shape) < 0.7
    assert np.array_equal(lattice_module.lattice_edges(edges, lattice, ring_set.tree, measures.bounds, wanted),
                          _edges_reference(ring_set, lattice, measures.bounds, wanted))
