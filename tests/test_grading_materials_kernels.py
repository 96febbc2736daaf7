"""Tests of heoslice.grading.materials_kernels: values_at_points against numpy's own interpolation along the
knots, bit for bit."""

from __future__ import annotations

import numpy as np
from helpers import random_ring_points
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.grading.edges import ring_edges
from heoslice.grading.materials_kernels import values_at_points


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
