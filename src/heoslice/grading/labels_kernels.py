"""Compiled loop of :mod:`heoslice.grading.labels`: the winding number of a layer's loops around a disc."""

from __future__ import annotations

import numpy as np

from heoslice.grading.edges_kernels import point_to_edge
from heoslice.jit import EXACT, f64, i64, kernel


@kernel(EXACT)
def _disc_winding(points, offsets, loops, cx, cy, reach):  # pragma: no cover - compiled
    """The winding number of the loops around the point (cx, cy), or None when an edge comes within
    ``reach`` of it."""
    winding = 0
    for loop in loops:
        first, last = offsets[loop], offsets[loop + 1]
        for i in range(first, last):
            j = i + 1 if i + 1 < last else first
            ax, ay = points[i, 0] - cx, points[i, 1] - cy
            bx, by = points[j, 0] - cx, points[j, 1] - cy
            vx, vy = bx - ax, by - ay
            length2 = vx * vx + vy * vy
            if point_to_edge(0.0, 0.0, ax, ay, vx, vy, 1.0 / length2 if length2 > 0.0 else 0.0) <= reach:
                return None
            left = ax * by - bx * ay
            if ay <= 0.0 < by and left > 0.0:
                winding += 1
            elif by <= 0.0 < ay and left < 0.0:
                winding -= 1
    return winding


def disc_winding(points: np.ndarray, offsets: np.ndarray, loops: np.ndarray, centre: np.ndarray,
                 reach: float) -> int | None:
    """How many times the given loops (indices into ``offsets``, of points (p, 2) mm) wind around a disc
    (``centre`` (2,), radius ``reach``, mm), counter-clockwise positive: the same at every point of it,
    since None is returned when any of their edges comes within ``reach`` of the centre (compiled)."""
    return _disc_winding(f64(points), i64(offsets),
                         i64(loops), float(centre[0]), float(centre[1]), float(reach))
