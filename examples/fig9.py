"""The paper's Fig. 9: layer 83 of a 0.1 mm, 600 dpi stack of a liver phantom with a lesion, (a) without and
(b) with an internal material distribution.

Usage: python examples/fig9.py [OUT.png] [--layer-number 83] [--layer 0.1] [--scale 1] [--dpi 600] [--depth 8]
       [--size 480] [--small]

heoslice.procedural.liver_phantom gives the organ and a lesion shell inside it, the lesion
placed low (``lesion_height``) so that the chosen layer cuts both; the
organ's vertices carry a liver colour, the lesion's a dark purple (the PLY colour
information of Fig. 8b). Layer 83 of the stack (0.1 mm layers from the phantom's
lowest point) is rendered (a) as the plain slicer does (contour colours at the
boundary, base material inside: Fig. 9a) and (b) graded (heoslice.grading.render_graded:
linear from the organ's contour to a 'cells' material over --depth mm, the lesion
keeping its own material: Fig. 9b). ``--small`` renders a phantom at scale 0.3 at
150 dpi with 240 px panels (for CI).
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
from heoslice.layers.rasterising import (
    grid_for,
    paint_contour,
    render_layer,
    solid_mask,
)
from heoslice.material import Material, make_function

HERE = Path(__file__).resolve().parent
LIVER = Material("liver", (150, 60, 45), 1)
CELLS = Material("cells", (235, 190, 90), 2)
TUMOUR = Material("tumour", (90, 20, 110), 3)
LESION_RADIUS = 18.0  # mm at scale 1 (heoslice.procedural.liver_phantom)


def shown(rgba: np.ndarray, size: int) -> Image.Image:
    """An RGBA layer over white, reduced to ``size`` pixels wide."""
    rgba = rgba.astype(np.float32)
    alpha = rgba[..., 3:] / 255.0
    image = Image.fromarray(np.rint(rgba[..., :3] * alpha + 255 * (1 - alpha)).astype(np.uint8))
    return image.resize((size, round(size * image.size[1] / image.size[0])), Image.Resampling.BOX)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default=str(HERE / "fig9.png"))
    parser.add_argument("--layer-number", type=int, default=83, help="which layer (1 = the lowest)")
    parser.add_argument("--layer", type=float, default=0.1, help="layer height, mm")
    parser.add_argument("--scale", type=float, default=1.0, help="phantom scale (1 = about 160 x 165 mm)")
    parser.add_argument("--dpi", type=float, default=600.0)
    parser.add_argument("--depth", type=float, default=8.0, help="grading depth from the contour, mm")
    parser.add_argument("--size", type=int, default=480, help="panel width in pixels")
    parser.add_argument("--small", action="store_true", help="scale 0.3, 150 dpi, 240 px panels (a quick run)")
    args = parser.parse_args()
    if args.small:
        args.scale, args.dpi, args.size = 0.3, 150.0, 240

    organ, _ = procedural.liver_phantom(scale=args.scale)
    z = plane_heights(organ.vertices[:, 2].min(), organ.vertices[:, 2].max(), args.layer)[args.layer_number - 1]
    organ, lesion = procedural.liver_phantom(scale=args.scale, lesion_height=max(z, 1.25 * LESION_RADIUS * args.scale))
    mesh = procedural.concatenate(organ, lesion)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    shell = np.concatenate([np.zeros(len(organ.faces), np.int64), np.ones(len(lesion.faces), np.int64)])
    shade = 0.85 + 0.15 * np.sin(vertices[:, 0] / 7.0)[:, None]
    colors = np.where(np.arange(len(vertices))[:, None] < len(organ.vertices),
                      np.asarray(LIVER.color) * shade, np.asarray(TUMOUR.color, dtype=float))
    contours = build_contours(slice_mesh(vertices, faces, np.array([z])))
    points, offsets = contours.points, contours.offsets
    point_colors = interpolate_at(colors, contours.point_edge, contours.point_t)
    lesion_loops = int(np.count_nonzero(shell[contours.face] == 1))
    print(f"Fig. 9: layer {args.layer_number} of a {args.layer} mm, {args.dpi:g} dpi stack of the liver phantom "
          f"with a lesion (scale {args.scale:g}; z = {z:.2f} mm): {contours.loop_count} loops, "
          f"{contours.loop_count - lesion_loops} of the organ and {lesion_loops} of the lesion, "
          f"{len(points)} intersection points; (a) without, (b) with internal material distribution")
    if lesion_loops == 0:
        print(f"note: layer {args.layer_number} does not cut the lesion at this scale")

    grid = grid_for(np.array([points.min(axis=0), points.max(axis=0)]), (args.dpi, args.dpi), 1.0)
    plain, _ = render_layer(points, offsets, grid, point_colors=point_colors, base_color=(240, 240, 240))
    for start, stop in zip(offsets[:-1], offsets[1:]):  # every loop's contour, the lesion's included
        own = solid_mask(points[start:stop], np.array([0, stop - start]), grid)
        paint_contour(plain, own, points[start:stop], point_colors[start:stop], grid)
    spec = GradeSpec(RegionSpec(nozzle_mm=0.2, depth_mm=args.depth), make_function("linear"), CELLS, None,
                     LIVER, shells=((1, TUMOUR),))
    mask = solid_mask(points, offsets, grid)
    graded = render_graded(points, offsets, contours.area, contours.parent, shell[contours.face], mask, grid,
                           spec, 0, point_colors=point_colors)
    print(f"grading step: {1000 * graded.grading_seconds:.1f} ms CPU for {grid.width} x {grid.height} px")

    panels = [shown(plain, args.size), shown(graded.image, args.size)]
    captions = (f"(a) layer {args.layer_number}, without internal distribution", "(b) with internal distribution")
    height = max(p.size[1] for p in panels)
    sheet = Image.new("RGB", (2 * args.size + 30, height + 40), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for number, (panel, caption) in enumerate(zip(panels, captions)):
        sheet.paste(panel, (10 + number * (args.size + 10), 30))
        draw.text((10 + number * (args.size + 10), 8), caption, fill=(0, 0, 0))
    sheet.save(args.out)
    print(f"{args.out}: {sheet.size[0]} x {sheet.size[1]} px")


if __name__ == "__main__":
    main()
