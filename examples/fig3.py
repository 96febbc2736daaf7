"""The paper's Fig. 3: (a) one vase layer's contour with its intersection points coloured; (b) the same
layer graded: the outer contour offset 200 times towards the inner one, linear, to (0, 255, 0).

Usage: python examples/fig3.py [OUT.png] [--z 30] [--dpi 600] [--size 560]

The vase (heoslice.procedural.vase, 90 sections: 360 intersection points per layer,
as in the paper's example) is coloured by a sine function of x (from red to blue,
heoslice.material), so that its contour points carry different colours. Panel (a)
draws the layer's loops and the intersection points in their interpolated colours
(Fig. 3a, 6); panel (b) is heoslice.grading.render_graded with 200 sub-regions from
the outer contour's colours to the target contour's (0, 255, 0) (Fig. 3b).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from heoslice import procedural
from heoslice.layers.contours import build_contours
from heoslice.material import evaluate, make_function, make_reference, normalise, reference_distance
from heoslice.material import DEFAULT_MATERIALS, Material, blend
from heoslice.layers.rasterising import grid_for, solid_mask
from heoslice.grading import GradeSpec, RegionSpec, render_graded
from heoslice.layers.slicing import interpolate_at, slice_mesh

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default=str(HERE / "fig3.png"))
    parser.add_argument("--z", type=float, default=30.0, help="layer height, mm")
    parser.add_argument("--dpi", type=float, default=600.0)
    parser.add_argument("--size", type=int, default=560, help="panel width in pixels")
    args = parser.parse_args()

    vertices, faces, colors = coloured_vase()
    contours = build_contours(slice_mesh(vertices, faces, np.array([args.z])))
    points, offsets = contours.points, contours.offsets
    point_colors = interpolate_at(colors, contours.point_edge, contours.point_t)
    print(f"layer at z = {args.z} mm: {len(points)} intersection points in {contours.loop_count} loops")

    grid = grid_for(np.array([points.min(axis=0), points.max(axis=0)]), (args.dpi, args.dpi), 1.0)
    mask = solid_mask(points, offsets, grid)
    spec = GradeSpec(RegionSpec(count=200), make_function("linear"), Material("target", (0, 255, 0)), None,
                     DEFAULT_MATERIALS["M1"])
    graded = render_graded(points, offsets, contours.area, contours.parent, None, mask, grid, spec, 0,
                           point_colors=point_colors)
    rgba = graded.image.astype(np.float32)
    alpha = rgba[..., 3:] / 255.0
    shown = Image.fromarray(np.rint(rgba[..., :3] * alpha + 255 * (1 - alpha)).astype(np.uint8))
    shown = shown.resize((args.size, round(args.size * grid.height / grid.width)), Image.Resampling.BOX)

    panels = [contour_panel(points, offsets, point_colors, args.size), shown]
    sheet = Image.new("RGB", (2 * args.size + 30, max(p.size[1] for p in panels) + 40), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for number, (panel, caption) in enumerate(zip(panels, ("(a) contour, intersection points coloured",
                                                           "(b) 200 offsets, linear, to (0, 255, 0)"))):
        sheet.paste(panel, (10 + number * (args.size + 10), 30))
        draw.text((10 + number * (args.size + 10), 8), caption, fill=(0, 0, 0))
    sheet.save(args.out)
    print(f"{args.out}: {sheet.size[0]} x {sheet.size[1]} px")


if __name__ == "__main__":
    main()
