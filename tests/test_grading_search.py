"""Tests of heoslice.grading.search: L_S of eq. 8, the distance between ring sets, exact and kept a layer."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from helpers import circle, grid_around, layer, ring_set, rough_outline
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.grading import RegionSpec, family_field, layer_families, search
from heoslice.grading.cache import RingMemo

pytestmark = pytest.mark.usefixtures("lattice_fit_for_every_family")  # conftest.py: small families on the lattice too


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2 ** 32 - 1))
def test_rings_apart_is_shapely_distance(seed):
    """L_S between an outer ring and the holes inside it is shapely's distance between the rings (to float32
    rounding of a few hundredths of a micrometre), wherever the closest pair lies (vertex or edge)."""
    from heoslice.grading.search import rings_apart

    rng = np.random.default_rng(seed)
    outer = rough_outline(int(rng.integers(0, 2 ** 31)), count=int(rng.integers(20, 400)), radius=10.0)
    holes = [circle(float(rng.uniform(0.3, 1.5)), int(rng.integers(3, 60)), center=tuple(rng.uniform(-3, 3, 2)),
                    clockwise=True) for _ in range(int(rng.integers(1, 3)))]
    holes = [h for i, h in enumerate(holes)
             if all(shapely.Polygon(h).disjoint(shapely.Polygon(other)) for other in holes[:i])]
    points, offsets, _, _ = layer(outer, *holes)
    expected = shapely.distance(shapely.LinearRing(outer), shapely.MultiLineString([np.vstack([h, h[:1]]) for h in holes]))
    outer_set, holes_set = ring_set(points, offsets, (0,), True), ring_set(points, offsets, range(1, len(holes) + 1), False)
    assert rings_apart(outer_set, holes_set) == pytest.approx(expected, abs=1e-5)


def test_the_distance_from_the_outer_ring_to_its_holes_is_the_least_hole_by_hole_and_kept_a_layer(monkeypatch):
    """L_S of a plate with holes, taken hole by hole, is exactly rings_apart of the outer ring and all its holes
    at once; through a cavity (one hole changing) only the changed hole's distance is measured again."""
    rng = np.random.default_rng(3)
    plate = np.array([[-12.0, -9.0], [12.0, -9.0], [12.0, 9.0], [-12.0, 9.0]])
    centres = [(-7.0, -4.0), (-7.0, 4.0), (0.0, -4.0), (0.0, 4.0)]
    holes = [circle(float(rng.uniform(1.0, 2.5)), int(rng.integers(12, 200)), c, clockwise=True) for c in centres]
    counted = []
    original = search.rings_apart
    monkeypatch.setattr(search, "rings_apart", lambda *a: counted.append(1) or original(*a))
    grid = grid_around(12.5)
    spec = RegionSpec(nozzle_mm=0.05)
    before: dict = {}
    measured = []
    for radius in [2.0, 2.6, 2.6]:
        rings = [plate, *holes, circle(radius, 96, (7.0, 0.0), clockwise=True)]
        points, offsets, area, parent = layer(*rings)
        family = layer_families(area, parent)[0]
        outer = ring_set(points, offsets, (family.outer,), True)
        everything = original(outer, ring_set(points, offsets, family.holes, False))
        memo = RingMemo(before=before)
        start = len(counted)
        field = family_field(points, offsets, family, grid, spec, memo=memo)
        assert field.layout.length_mm == everything
        measured.append(len(counted) - start)
        before = memo.now
    assert measured == [len(holes) + 1, 1, 0]


def test_the_nearest_edges_of_many_groups_are_found_batch_by_batch_as_each_group_alone():
    """Groups whose candidate pairs exceed one batch (a zigzag ring of 200,000 edges: fewer than 400 groups a
    batch) get, searched together, the nearest edges and distances each gets searched alone."""
    from heoslice.grading.search_kernels import _PAIRS, FAN

    angle = np.linspace(0.0, 2 * np.pi, 200_000, endpoint=False)
    radius = 40.0 + 0.01 * (np.arange(len(angle)) % 2)  # no point on the line between its neighbours
    points, offsets, _, _ = layer(np.column_stack([radius * np.cos(angle), radius * np.sin(angle)]))
    rings = ring_set(points, offsets, [0], True)
    groups = 1000
    assert groups > _PAIRS // -(-len(rings.edges.x) // FAN)  # more groups than one batch holds
    rng = np.random.default_rng(3)
    angle, radius = rng.uniform(0, 2 * np.pi, groups), rng.uniform(0.0, 39.0, groups)
    cx, cy = radius * np.cos(angle), radius * np.sin(angle)
    reach = 40.0 - radius + 0.5
    ox, oy = np.array([0.0, 0.1]), np.array([0.0, -0.1])
    together = search.nearest_edges(cx, cy, reach, ox, oy, rings.edges, rings.tree)
    squared = search.nearest_edges(cx, cy, reach, ox, oy, rings.edges, rings.tree, track=False)
    for g in range(0, groups, 97):
        alone = slice(g, g + 1)
        assert np.array_equal(together[alone], search.nearest_edges(cx[alone], cy[alone], reach[alone], ox, oy,
                                                                    rings.edges, rings.tree))
        assert np.array_equal(squared[alone], search.nearest_edges(cx[alone], cy[alone], reach[alone], ox, oy,
                                                                   rings.edges, rings.tree, track=False))
    assert (together >= 0).all()
