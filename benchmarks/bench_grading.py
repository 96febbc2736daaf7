"""Benchmark of the grading step (heoslice.grading.layer_regions) against a naive baseline, same run.

    python benchmarks/bench_grading.py             # liver phantom ~160 x 165 mm, 600 dpi (~15 MP/layer)
    python benchmarks/bench_grading.py --quick     # a smaller part, for a smoke test
    python benchmarks/bench_grading.py --stages    # and CPU ms per stage (a separate, instrumented pass)

The grading step is everything :func:`heoslice.grading.layer_regions` does for one
layer: from the layer's loops and its solid mask (made by the rasteriser, which the
ungraded path runs too, so not counted) to the sub-region label of every pixel: the
families, exact ring distances on the coarse lattice, the per-cell planes, the
per-pixel expansion and refinement, and the labelled image. It runs in one process;
CPU time (time.process_time), best of --repeats per layer, median over the layers.

The baseline is the straightforward way: for each sub-region boundary k, shapely's
round-join offset buffer(-k w) of the family's polygon, rasterised with heoslice's own
scanline rasteriser and summed (k = number of offsets containing the pixel). It is
timed on --baseline-layers layers; its labels are compared with the fast ones
(pixels that differ, and how far from an offset boundary they lie, in pixels).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import statistics
import time

import numpy as np
from timing import best_of


def part_layers(scale: float, count: int):
    """(contours, planes) of the liver phantom with its lesion, ``count`` layers around the widest section."""
    from heoslice import procedural
    from heoslice.layers.contours import build_contours
    from heoslice.layers.slicing import slice_mesh

    organ, lesion = procedural.liver_phantom(scale=scale)
    mesh = procedural.concatenate(organ, lesion)
    centre = float(np.asarray(lesion.vertices)[:, 2].mean())
    z = centre + np.linspace(-5.0, 5.0, count) * scale
    return build_contours(slice_mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), z)), z


def layer_inputs(contours, index: int):
    """points, offsets, area, parent (within the layer) of one layer."""
    first, last = contours.layer_offsets[index], contours.layer_offsets[index + 1]
    start, stop = contours.offsets[first], contours.offsets[last]
    parent = contours.parent[first:last]
    return (contours.points[start:stop], contours.offsets[first:last + 1] - start, contours.area[first:last],
            np.where(parent >= 0, parent - first, -1))


#: (module, name) of each stage timed: the module whose functions call it by that name.
STAGES = (("field", "ring_measures"), ("lattice", "lattice_edges"), ("field", "cells_to_refine"),
          ("field", "_expand_planes"), ("field", "refine_cells"), ("labels", "_family_mask"))


@contextlib.contextmanager
def stage_timers(totals: dict):
    """Within the block, CPU seconds spent in each of STAGES (and shapely.maximum_inscribed_circle)
    add up in ``totals``."""
    import importlib

    import shapely

    def timed(name, function):
        @functools.wraps(function)
        def wrapper(*args, **kwargs):
            started = time.process_time()
            try:
                return function(*args, **kwargs)
            finally:
                totals[name] = totals.get(name, 0.0) + time.process_time() - started
        return wrapper

    modules = [importlib.import_module(f"heoslice.grading.{module}") for module, _ in STAGES]
    patched = [(module, name, getattr(module, name)) for module, (_, name) in zip(modules, STAGES)]
    patched.append((shapely, "maximum_inscribed_circle", shapely.maximum_inscribed_circle))
    try:
        for module, name, function in patched:
            setattr(module, name, timed(name, function))
        yield totals
    finally:
        for module, name, function in patched:
            setattr(module, name, function)


def stage_table(inputs, spec, repeats: int) -> dict:
    """Median over layers (best of ``repeats`` per layer, by total) of CPU ms per stage of layer_regions."""
    from heoslice.grading import layer_regions

    rows = {}
    for points, offsets, area, parent, mask, grid in inputs:
        best = None
        for _ in range(repeats):
            totals = {}
            with stage_timers(totals):
                started = time.process_time()
                layer_regions(points, offsets, area, parent, mask, grid, spec)
                total = time.process_time() - started
            if best is None or total < best[0]:
                best = (total, totals)
        total, totals = best
        totals["rest (families, seeds, signs, labels)"] = total - sum(totals.values())
        totals["total"] = total
        for name, seconds in totals.items():
            rows.setdefault(name, []).append(1000 * seconds)
    return {name: statistics.median(values) for name, values in rows.items()}


def naive_labels(points, offsets, area, parent, mask, grid, spec, regions):
    """The baseline: per family, sum over k of the rasterised round-join buffer(-k w) (shapely); nested
    shells painted after their host, as layer_regions does."""
    import shapely

    from heoslice.layers.rasterising import solid_mask

    b = regions.box
    label = np.zeros((b[1] - b[0], b[3] - b[2]), dtype=np.int32)
    for number, (family, field) in enumerate(zip(regions.families, regions.fields)):
        rings = [points[offsets[loop]:offsets[loop + 1]] for loop in (family.outer, *family.holes)]
        polygon = shapely.Polygon(rings[0], rings[1:])
        count = field.layout.count
        width = field.layout.length_mm / count
        own = solid_mask(rings[0], np.array([0, len(rings[0])]), grid)[b[0]:b[1], b[2]:b[3]] & \
            mask[b[0]:b[1], b[2]:b[3]]
        if family.nested:
            label[own] = regions.base[number]
            continue
        k = np.ones(own.shape, dtype=np.int32)
        for offset in range(1, count):
            inner = shapely.orient_polygons(polygon.buffer(-offset * width, join_style="round", quad_segs=16))
            if inner.is_empty:
                break
            parts = [inner] if inner.geom_type == "Polygon" else list(inner.geoms)
            loops = [np.asarray(ring.coords)[:-1] for part in parts
                     for ring in (part.exterior, *part.interiors)]
            sizes = np.array([len(loop) for loop in loops])
            inside = solid_mask(np.concatenate(loops), np.concatenate([[0], np.cumsum(sizes)]), grid)
            k += inside[b[0]:b[1], b[2]:b[3]]
        label[own] = (regions.base[number] + k)[own]
    return label


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.35, help="liver phantom scale (1.35: ~160 x 165 mm)")
    parser.add_argument("--dpi", type=float, default=600.0)
    parser.add_argument("--nozzle", type=float, default=0.2, help="D_N, mm")
    parser.add_argument("--depth", type=float, default=None, help="grade to this depth (mm) instead of the centre")
    parser.add_argument("--layers", type=int, default=7)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--baseline-layers", type=int, default=1)
    parser.add_argument("--quick", action="store_true", help="scale 0.4, 3 layers")
    parser.add_argument("--stages", action="store_true", help="also CPU ms per stage (an instrumented pass)")
    args = parser.parse_args()
    if args.quick:
        args.scale, args.layers = 0.4, 3

    from heoslice.grading import RegionSpec, layer_regions
    from heoslice.layers.rasterising import grid_for, solid_mask

    contours, z = part_layers(args.scale, args.layers)
    spec = RegionSpec(nozzle_mm=args.nozzle, depth_mm=args.depth)
    times, pixels, ratios, inputs = [], [], [], []
    print(f"liver phantom x{args.scale}, {args.dpi:g} dpi, nozzle {args.nozzle} mm, "
          f"depth {args.depth or 'to the centre'}; CPU ms, best of {args.repeats}")
    for index in range(args.layers):
        points, offsets, area, parent = layer_inputs(contours, index)
        low, high = points.min(axis=0), points.max(axis=0)
        grid = grid_for(np.array([low, high]), (args.dpi, args.dpi), 1.0)
        mask = solid_mask(points, offsets, grid)
        if args.stages:
            inputs.append((points, offsets, area, parent, mask, grid))
        seconds, regions = best_of(args.repeats, layer_regions, points, offsets, area, parent, mask, grid, spec, clock=time.process_time)
        megapixels = grid.width * grid.height / 1e6
        counts = [f.layout.count for f, fam in zip(regions.fields, regions.families) if not fam.nested]
        line = (f"layer z={z[index]:7.2f} mm  {high[0] - low[0]:5.1f} x {high[1] - low[1]:5.1f} mm  "
                f"{megapixels:5.2f} MP  N_R={counts}  grading {1000 * seconds:7.1f} ms")
        if index < args.baseline_layers:
            base_seconds, naive = best_of(1, naive_labels, points, offsets, area, parent, mask, grid, spec, regions, clock=time.process_time)
            differ = naive != regions.label
            ratios.append(base_seconds / seconds)
            line += (f"  baseline {1000 * base_seconds:8.1f} ms  ratio {base_seconds / seconds:6.1f}x  "
                     f"pixels differing {int(differ.sum())} ({100 * differ.mean():.3f} %)")
        print(line, flush=True)
        times.append(seconds)
        pixels.append(megapixels)
    median = statistics.median(times)
    print(f"grading step: median {1000 * median:.1f} ms/layer over {len(times)} layers "
          f"(median {statistics.median(pixels):.1f} MP; {1000 * median / statistics.median(pixels):.2f} ms/MP); "
          f"target <= 30 ms per ~14 MP layer")
    if ratios:
        print(f"speed-up over the naive shapely-buffer-per-band baseline: {statistics.median(ratios):.0f}x")
    if args.stages:
        print(f"stages (CPU ms, instrumented pass, median over {len(inputs)} layers):")
        for name, ms in stage_table(inputs, spec, args.repeats).items():
            print(f"  {name:40s} {ms:7.1f}")


if __name__ == "__main__":
    main()
