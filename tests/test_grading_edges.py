"""Tests of heoslice.grading.edges: whether rings turn one way only."""

from __future__ import annotations

import numpy as np
import shapely
from helpers import circle, random_ring_points
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.grading.edges import convex_rings, following_edges, ring_edges


def _convex_reference(edges) -> bool:
    """convex_rings written out in numpy: the sign of each edge's cross product with the next, where the
    turn's sine exceeds 1e-9, is one sign round each ring."""
    following = following_edges(edges)
    cross = edges.vx * edges.vy[following] - edges.vy * edges.vx[following]
    sine = cross * np.sqrt(edges.inv_len2 * edges.inv_len2[following])
    turn = np.sign(np.where(np.abs(sine) > 1e-9, cross, 0.0))
    return not any({-1.0, 1.0} <= set(turn[edges.ring == ring].tolist()) for ring in np.unique(edges.ring))


def _edges_of(rings: list[np.ndarray]):
    offsets = np.concatenate([[0], np.cumsum([len(ring) for ring in rings])])
    return ring_edges(np.concatenate(rings), offsets, list(range(len(rings))))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(1, 4), st.booleans())
def test_convex_rings_agrees_with_the_turns_written_out(seed, rings, hulls):
    """On random star-shaped rings (mostly reflex somewhere), and on their convex hulls (convex, collinear
    points included where the hull keeps them), convex_rings is the numpy reference's answer; a convex
    hull is convex, either way round."""
    rng = np.random.default_rng(seed)
    points = random_ring_points(rng, rings)
    if hulls:
        points = [np.asarray(shapely.convex_hull(shapely.MultiPoint(ring)).exterior.coords)[:-1] for ring in points]
        points = [ring[::-1] if rng.integers(2) else ring for ring in points]
    edges = _edges_of(points)
    assert convex_rings(edges) == _convex_reference(edges)
    if hulls:
        assert convex_rings(edges)


def test_one_reflex_vertex_in_any_ring_makes_the_rings_not_convex():
    """A disc and a square are convex; a notch in the square (one reflex vertex), or a disc beside a
    notched square, is not."""
    square = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]])
    notched = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [2.0, 3.0], [0.0, 4.0]])
    disc = circle(1.0, 64, (10.0, 0.0))
    assert convex_rings(_edges_of([square])) and convex_rings(_edges_of([disc, square]))
    assert not convex_rings(_edges_of([notched])) and not convex_rings(_edges_of([disc, notched]))
