"""The paper's Fig. 3: (a) the 360th layer of the vase, its intersection points coloured; (b) the same
layer graded: the outer contour offset 200 times towards the inner one, linear, to (0, 255, 0); (c) an
irregular region (a bumpy outline with an off-centre hole) graded the same way, eq. 9-10 weighting both rings.

Usage: python examples/fig3.py [OUT.png] [--layer-number 360] [--layer 0.1] [--dpi 600] [--size 560] [--small]

The vase (heoslice.procedural.vase, 90 sections: 360 intersection points per layer,
as in the paper's example) is sliced at 0.1 mm layers and coloured by a sine function
of x (from red to blue, heoslice.material), so that its contour points carry
different colours. Panel (a) draws the 360th layer's loops and the intersection points
in their interpolated colours (Fig. 3a, 6); panel (b) is heoslice.grading.render_graded
with 200 sub-regions from the outer contour's colours to the target contour's
(0, 255, 0) (Fig. 3b); panel (c) the same for an irregular region. ``--small`` renders
at 150 dpi and 240 px panels (for CI).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from heoslice import procedural
from heoslice.grading import GradeSpec, RegionSpec, render_graded
from heoslice.layers import interpolate_at, plane_heights, slice_mesh
from heoslice.layers.contours import build_contours
from heoslice.layers.rasterising import grid_for, solid_mask
from heoslice.material import (
    DEFAULT_MATERIALS,
    Material,
    blend,
    evaluate,
    make_function,
    make_reference,
    normalise,
    reference_distance,
)

HERE = Path(__file__).resolve().parent


def coloured_vase():
    """(vertices, faces, colours (n, 3) float) of the vase, coloured red -> blue by a sine of x."""
    mesh = procedural.vase(sections=90)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    reference = make_reference("plane", vertices, faces, normal=(1.0, 0.0, 0.0))
    r = normalise(reference_distance(reference, vertices))
    f = evaluate(make_function("sine", periods=1.0), r)
    return vertices, faces, blend((230, 40, 40), (40, 60, 230), f)


def contour_panel(points, offsets, colors, size: int) -> Image.Image:
    """Panel (a): the loops in grey, each intersection point a dot in its colour."""
    low, high = points.min(axis=0), points.max(axis=0)
    scale = (size - 40) / float(np.max(high - low))
    xy = np.column_stack([20 + (points[:, 0] - low[0]) * scale, size - 20 - (points[:, 1] - low[1]) * scale])
    image = Image.new("RGB", (size, size), (255, 255, 255))
    draw = ImageDraw.Draw(image)
    for start, stop in zip(offsets[:-1], offsets[1:]):
        loop = [tuple(p) for p in xy[start:stop]] + [tuple(xy[start])]
        draw.line(loop, fill=(150, 150, 150), width=1)
    for (x, y), color in zip(xy, np.clip(np.rint(colors), 0, 255).astype(int)):
        draw.ellipse((x - 3, y - 3, x + 3, y + 3), fill=tuple(color))
    return image


def irregular_region() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(points, offsets, area, parent, colours) of an irregular region: a bumpy outline (r = 20 + 3 sin 5t
    + 1.5 cos 3t mm) with an off-centre elliptical hole, its points coloured red -> blue along x."""
    t = np.linspace(0.0, 2 * np.pi, 400, endpoint=False)
    radius = 20.0 + 3.0 * np.sin(5 * t) + 1.5 * np.cos(3 * t)
    outer = np.column_stack([radius * np.cos(t), radius * np.sin(t)])
    hole = np.column_stack([5.0 + 6.0 * np.cos(-t), -3.0 + 4.0 * np.sin(-t)])[:160:2]
    points = np.concatenate([outer, hole])
    offsets = np.array([0, len(outer), len(points)])
    shoelace = [0.5 * float(np.sum(r[:, 0] * np.roll(r[:, 1], -1) - np.roll(r[:, 0], -1) * r[:, 1])) for r in (outer, hole)]
    x = (points[:, 0] - points[:, 0].min()) / np.ptp(points[:, 0])
    return points, offsets, np.array(shoelace), np.array([-1, 0]), blend((230, 40, 40), (40, 60, 230), x)


def graded_panel(points, offsets, area, parent, point_colors, dpi: float, size: int) -> Image.Image:
    """A layer graded with 200 offsets, linear, from its outer contour's colours to (0, 255, 0), over white."""
    grid = grid_for(np.array([points.min(axis=0), points.max(axis=0)]), (dpi, dpi), 1.0)
    mask = solid_mask(points, offsets, grid)
    spec = GradeSpec(RegionSpec(count=200), make_function("linear"), Material("target", (0, 255, 0)), None,
                     DEFAULT_MATERIALS["M1"])
    graded = render_graded(points, offsets, area, parent, None, mask, grid, spec, 0, point_colors=point_colors)
    rgba = graded.image.astype(np.float32)
    alpha = rgba[..., 3:] / 255.0
    shown = Image.fromarray(np.rint(rgba[..., :3] * alpha + 255 * (1 - alpha)).astype(np.uint8))
    return shown.resize((size, round(size * grid.height / grid.width)), Image.Resampling.BOX)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default=str(HERE / "fig3.png"))
    parser.add_argument("--layer-number", type=int, default=360, help="which layer (1 = the lowest)")
    parser.add_argument("--layer", type=float, default=0.1, help="layer height, mm")
    parser.add_argument("--dpi", type=float, default=600.0)
    parser.add_argument("--size", type=int, default=560, help="panel width in pixels")
    parser.add_argument("--small", action="store_true", help="150 dpi, 240 px panels (a quick run)")
    args = parser.parse_args()
    if args.small:
        args.dpi, args.size = 150.0, 240

    vertices, faces, colors = coloured_vase()
    z = plane_heights(vertices[:, 2].min(), vertices[:, 2].max(), args.layer)[args.layer_number - 1]
    contours = build_contours(slice_mesh(vertices, faces, np.array([z])))
    points, offsets = contours.points, contours.offsets
    point_colors = interpolate_at(colors, contours.point_edge, contours.point_t)
    print(f"Fig. 3 (a, b): layer {args.layer_number} of the vase at {args.layer} mm layers (z = {z:.2f} mm): "
          f"{len(points)} intersection points in {contours.loop_count} loops (the paper: 360), 200 offsets to "
          f"(0, 255, 0); Fig. 3 (c): an irregular region with a hole, the same grading")

    panels = [contour_panel(points, offsets, point_colors, args.size),
              graded_panel(points, offsets, contours.area, contours.parent, point_colors, args.dpi, args.size),
              graded_panel(*irregular_region(), args.dpi, args.size)]
    captions = (f"(a) layer {args.layer_number}: {len(points)} intersection points", "(b) 200 offsets, linear, to "
                "(0, 255, 0)", "(c) an irregular region, 200 offsets")
    sheet = Image.new("RGB", (3 * args.size + 40, max(p.size[1] for p in panels) + 40), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for number, (panel, caption) in enumerate(zip(panels, captions)):
        sheet.paste(panel, (10 + number * (args.size + 10), 30))
        draw.text((10 + number * (args.size + 10), 8), caption, fill=(0, 0, 0))
    sheet.save(args.out)
    print(f"{args.out}: {sheet.size[0]} x {sheet.size[1]} px")


if __name__ == "__main__":
    main()
