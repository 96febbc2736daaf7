"""Tests of heoslice.grading.lattice_kernels: signed_feet's distances, feet and gradients against feet and
the side of each centre, and inside_centres against rasterising.solid_mask (an independent scanline
rasteriser), a vertex where an edge's end rounds off it included."""

from __future__ import annotations

import numpy as np
import shapely
from helpers import random_rings
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.grading.edges import ring_edges
from heoslice.grading.lattice_kernels import (
    LatticeFrame,
    feet,
    inside_centres,
    signed_feet,
)


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
