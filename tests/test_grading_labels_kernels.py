"""Tests of heoslice.grading.labels_kernels: disc_winding against shapely's distances and point-in-polygon
tests, for rings traversed several times, either way round."""

from __future__ import annotations

import numpy as np
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.grading.labels_kernels import disc_winding


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
