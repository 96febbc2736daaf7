"""How the grading step scales with the number of pores and islands in a layer (porous scaffolds).

    python benchmarks/bench_pores.py             # plates with 9 / 36 / 100 pores, 100 / 400 / 1600 islands
    python benchmarks/bench_pores.py --quick     # 4 / 16 pores, 25 / 100 islands

Each case is one layer at 600 dpi, 0.2 mm nozzle, graded inwards, made here: a square
plate pierced by a grid of round pores (r = 1 mm, 3 mm apart: one family whose eq. 10
couples every pore to every pixel), or a grid of free discs of the same size (one
family each). The time is :func:`heoslice.grading.layer_regions` (CPU, best of
--repeats), per layer and per pore or island; the ratio is the per-pore cost against the
smallest case of the same kind in the same run (1.0: linear in the count).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from timing import best_of

PX = 25.4 / 600


def circle(radius: float, centre: tuple[float, float], clockwise: bool = False, count: int = 128) -> np.ndarray:
    """(count, 2) polygon of a circle, counter-clockwise unless ``clockwise`` (a hole)."""
    angle = np.linspace(0.0, 2 * np.pi, count, endpoint=False)
    ring = np.column_stack([centre[0] + radius * np.cos(angle), centre[1] + radius * np.sin(angle)])
    return ring[::-1] if clockwise else ring


def case(kind: str, count: int):
    """(points, offsets, area, parent, mask, grid) of one layer: ``count`` pores in a plate, or ``count`` islands."""
    from heoslice.layers.rasterising import Grid, solid_mask

    side = int(np.ceil(np.sqrt(count)))
    centres = [(3.0 * i, 3.0 * j) for i in range(side) for j in range(side)][:count]
    if kind == "islands":
        rings = [circle(1.0, c) for c in centres]
        parent = np.full(count, -1)
    else:
        far = 3.0 * side - 1.0
        rings = [np.array([[-2.0, -2.0], [far, -2.0], [far, far], [-2.0, far]])]
        rings += [circle(1.0, c, clockwise=True) for c in centres]
        parent = np.array([-1] + [0] * count)
    points = np.concatenate(rings)
    offsets = np.concatenate([[0], np.cumsum([len(ring) for ring in rings])])
    area = np.array([0.5 * np.sum(r[:, 0] * np.roll(r[:, 1], -1) - np.roll(r[:, 0], -1) * r[:, 1]) for r in rings])
    low, high = points.min(axis=0) - 1.0, points.max(axis=0) + 1.0
    grid = Grid(width=int((high[0] - low[0]) / PX) + 1, height=int((high[1] - low[1]) / PX) + 1,
                x_left=float(low[0]), y_top=float(high[1]), px=PX, py=PX)
    return points, offsets, area, parent, solid_mask(points, offsets, grid), grid


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer, smaller cases (a smoke test)")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per case [3]")
    args = parser.parse_args()
    from heoslice.grading import RegionSpec, layer_regions

    spec = RegionSpec(nozzle_mm=0.2)
    plan = {"pores": (4, 16) if args.quick else (9, 36, 100),
            "islands": (25, 100) if args.quick else (100, 400, 1600)}
    print(f"{'case':>8} {'count':>6} {'layer px':>12} {'ms/layer':>9} {'ms each':>8} {'ratio':>6}")
    for kind, counts in plan.items():
        first = None
        for count in counts:
            points, offsets, area, parent, mask, grid = case(kind, count)
            layer_regions(points, offsets, area, parent, mask, grid, spec)  # compiled kernels loaded, caches warm
            seconds, _ = best_of(args.repeats, layer_regions, points, offsets, area, parent, mask, grid, spec,
                                 clock=time.process_time)
            each = seconds / count
            first = first or each
            print(f"{kind:>8} {count:>6} {grid.width:>5} x {grid.height:<5} {1e3 * seconds:9.1f} {1e3 * each:8.2f} "
                  f"{each / first:6.2f}", flush=True)


if __name__ == "__main__":
    main()
