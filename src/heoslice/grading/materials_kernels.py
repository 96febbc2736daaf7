"""Compiled loop of :mod:`heoslice.grading.materials`: the contour's values taken where points (the lattice
cells' nearest starting-ring points, or pixel centres) fall along their nearest edges, in one pass instead of
numpy's gathers and one ``np.interp`` per column.

Exact arithmetic (no fast-math): every value is the one numpy's expression and ``np.interp`` give, bit for bit.
"""

from __future__ import annotations

import numpy as np

from heoslice.grading.edges_kernels import edge_arrays
from heoslice.jit import EXACT, f64, i64, kernel


@kernel(EXACT)
def _values_at_points(x, y, edge, edges, ring, first_knot, knots, values):  # pragma: no cover - compiled
    """(n, c) values at n points along their edges (see :func:`values_at_points`); ``first_knot`` is the
    knot at each edge's start, the last one at or below every position along the edge."""
    last = knots.shape[0] - 1
    slopes = np.empty((max(last, 0), values.shape[1]))  # as np.interp computes them
    for j in range(last):
        for column in range(values.shape[1]):
            slopes[j, column] = (values[j + 1, column] - values[j, column]) / (knots[j + 1] - knots[j])
    out = np.empty((edge.shape[0], values.shape[1]))
    for n in range(edge.shape[0]):
        e = edge[n]
        t = ((x[n] - edges.x[e]) * edges.vx[e] + (y[n] - edges.y[e]) * edges.vy[e]) * edges.inv_len2[e]
        at = np.float64(e + ring[e]) + min(max(t, 0.0), 1.0)
        j = first_knot[e]
        while j < last and knots[j + 1] <= at:  # the knots an edge spans: few
            j += 1
        for column in range(values.shape[1]):
            # np.interp: the knot's own value on it (or at the last knot), else the slope from it times the
            # way from it, plus its value (from the next knot if that is NaN)
            if j == last or knots[j] == at:
                value = values[j, column]
            else:
                value = slopes[j, column] * (at - knots[j]) + values[j, column]
                if np.isnan(value):
                    value = slopes[j, column] * (at - knots[j + 1]) + values[j + 1, column]
                    if np.isnan(value) and values[j, column] == values[j + 1, column]:
                        value = values[j, column]
            out[n, column] = value
    return out


def values_at_points(points: np.ndarray, edge: np.ndarray, edges, values: np.ndarray) -> np.ndarray:
    """Per-knot values ((m, c) float, ``values[k]`` at ``edges.knots[k]``) where points ((2, ...) mm) fall
    along their edges (``edge``, the points' shape, into ``edges``, a :class:`heoslice.grading.edges.RingEdges`):
    each point's position along the knots (edge i + ring[i] + t, t the fraction of the edge at the point's
    projection, clipped to [0, 1]) interpolated between the knots either side, as ``np.interp`` does:
    (..., c) float."""
    shape = edge.shape
    ring, knots = i64(edges.ring), f64(edges.knots)
    first_knot = np.searchsorted(knots, np.arange(len(ring)) + ring)  # edge i starts at knot i + ring[i]
    out = _values_at_points(f64(points[0]).ravel(), f64(points[1]).ravel(), i64(edge).ravel(), edge_arrays(edges),
                            ring, i64(first_knot), knots, f64(values))
    return out.reshape(*shape, values.shape[1])
