"""Ring sets and the exact nearest-edge search over them: the nearest edge to groups of points, the distance
between two ring sets (L_S of eq. 8)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from heoslice.grading.cache import RingMemo
from heoslice.grading.edges import RingEdges
from heoslice.grading.search_kernels import (
    edge_sets_apart,
    edge_tree,
    nearest_in_groups,
)


@dataclass(frozen=True)
class RingSet:
    """Rings whose nearest one gives a distance: loops (within the layer), their edges, and whether
    the family's region is inside them (an outer ring) or outside (holes); ``lazy_tree`` makes their
    :func:`ring_tree` when first asked for (:attr:`tree`: a family that measures no distance needs none);
    ``key`` (encloses and the edges as bytes, made by :func:`family_field`) finds what another layer measured
    of the same rings."""

    loops: tuple[int, ...]
    edges: RingEdges
    encloses: bool
    lazy_tree: LazyTree = field(repr=False, compare=False)
    key: tuple = ()

    @property
    def tree(self) -> tuple:
        """The edges' bounding-box hierarchy (:func:`ring_tree`), made once (by :attr:`lazy_tree`)."""
        return self.lazy_tree()


class LazyTree:
    """The :func:`ring_tree` of some edges, made on the first call and kept: what a layer's ring memo holds for
    a ring set's key, so that the next layer's ring set of the same edges takes the tree if one was made,
    and no tree is made for rings no distance is measured to. It holds the edges only (not the memo)."""

    __slots__ = ("edges", "made")

    def __init__(self, edges: RingEdges):
        self.edges, self.made = edges, None

    def __call__(self) -> tuple:
        if self.made is None:
            self.made = ring_tree(self.edges)
        return self.made


def ring_tree(edges: RingEdges) -> tuple:
    """A bounding-box hierarchy over the edges (ring order), for :func:`nearest_edges`."""
    return edge_tree(edges.x, edges.y, edges.x + edges.vx, edges.y + edges.vy)


def nearest_edges(cx: np.ndarray, cy: np.ndarray, radius: np.ndarray, ox: np.ndarray, oy: np.ndarray,
                  edges: RingEdges, tree: tuple, track: bool = True) -> np.ndarray:
    """The nearest edge ((g, k) int, -1: none), or without ``track`` the squared distance to it ((g, k)
    mm^2), of the points (cx + ox[k], cy + oy[k]) ((g,), (k,) mm) among the edges within radius[g]
    of (cx[g], cy[g]) (compiled, :func:`heoslice.grading.search_kernels.nearest_in_groups`)."""
    return nearest_in_groups(cx, cy, radius, ox, oy, edges, tree, track)


def rings_apart(first: RingSet, second: RingSet) -> float:
    """Shortest distance (mm) between two sets of rings that do not cross.

    It is reached at a vertex of one set (the nearest point of the other can be anywhere
    on an edge), so it is the least vertex-to-edge distance both ways; the nearest pair
    among a sample of vertices bounds it, so only chunks of edges that close are measured
    (:func:`heoslice.grading.search_kernels.edge_sets_apart`).
    """
    a = np.column_stack([first.edges.x, first.edges.y, first.edges.vx, first.edges.vy, first.edges.inv_len2])
    b = np.column_stack([second.edges.x, second.edges.y, second.edges.vx, second.edges.vy, second.edges.inv_len2])
    sample_a, sample_b = a[::max(1, len(a) // 64)], b[::max(1, len(b) // 1024)]
    across = sample_a[:, 0, None] - sample_b[None, :, 0]
    along = sample_a[:, 1, None] - sample_b[None, :, 1]
    bound = float(np.sqrt((across * across + along * along).min())) * (1 + 1e-12) + 1e-12
    return edge_sets_apart(a, first.tree, b, second.tree, bound)


def rings_apart_kept(first: RingSet, second: RingSet, memo: RingMemo) -> float:
    """:func:`rings_apart`, recalled from ``memo`` (by the two sets' keys) when the last layer or this one
    measured it, and kept there."""
    return memo.recall(("apart", first.key, second.key), lambda: rings_apart(first, second))
