"""The paper's Fig. 9: a liver-like phantom with a lesion shell, one layer (a) without and (b) with an
internal material distribution, and (c) its droplet masks.

Usage: python examples/fig9.py [OUT.png] [--scale 0.5] [--dpi 600] [--depth 8] [--size 480]

heoslice.procedural.liver_phantom gives the organ and a lesion shell inside it; the
organ's vertices carry a liver colour, the lesion's a dark purple (the PLY colour
information of Fig. 8b). The layer through the lesion's centre is rendered (a) as the
plain slicer does (contour colours at the boundary, base material inside: Fig. 9a),
(b) graded (heoslice.grading.render_graded: linear from the organ's contour to a
'cells' material over --depth mm, the lesion keeping its own material: Fig. 9b) and
(c) as the droplet masks of a 3-material jetting head (one colour per material).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from heoslice import procedural
from heoslice.layers.contours import build_contours
from heoslice.material import make_function
from heoslice.material import Material
from heoslice.layers.rasterising import grid_for, paint_contour, render_layer, solid_mask
from heoslice.grading import GradeSpec, RegionSpec, render_graded
from heoslice.layers.slicing import interpolate_at, slice_mesh

HERE = Path(__file__).resolve().parent
LIVER = Material("liver", (150, 60, 45), 1)
CELLS = Material("cells", (235, 190, 90), 2)
TUMOUR = Material("tumour", (90, 20, 110), 3)


def shown(rgba: np.ndarray, size: int) -> Image.Image:
    """An RGBA layer over white, reduced to ``size`` pixels wide."""
    rgba = rgba.astype(np.float32)
    alpha = rgba[..., 3:] / 255.0
    image = Image.fromarray(np.rint(rgba[..., :3] * alpha + 255 * (1 - alpha)).astype(np.uint8))
    return image.resize((size, round(size * image.size[1] / image.size[0])), Image.Resampling.BOX)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default=str(HERE / "fig9.png"))
    parser.add_argument("--scale", type=float, default=0.5, help="phantom scale (1 = about 160 x 165 mm)")
    parser.add_argument("--dpi", type=float, default=600.0)
    parser.add_argument("--depth", type=float, default=8.0, help="grading depth from the contour, mm")
    parser.add_argument("--size", type=int, default=480, help="panel width in pixels")
    args = parser.parse_args()

    organ, lesion = procedural.liver_phantom(scale=args.scale)
    mesh = procedural.concatenate(organ, lesion)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    shell = np.concatenate([np.zeros(len(organ.faces), np.int64), np.ones(len(lesion.faces), np.int64)])
    shade = 0.85 + 0.15 * np.sin(vertices[:, 0] / 7.0)[:, None]
    colors = np.where(np.arange(len(vertices))[:, None] < len(organ.vertices),
                      np.asarray(LIVER.color) * shade, np.asarray(TUMOUR.color, dtype=float))
    z = float(np.asarray(lesion.vertices)[:, 2].mean())
    contours = build_contours(slice_mesh(vertices, faces, np.array([z])))
    points, offsets = contours.points, contours.offsets
    point_colors = interpolate_at(colors, contours.point_edge, contours.point_t)
    print(f"layer at z = {z:.2f} mm: {contours.loop_count} loops, {len(points)} intersection points")

    grid = grid_for(np.array([points.min(axis=0), points.max(axis=0)]), (args.dpi, args.dpi), 1.0)
    plain, _ = render_layer(points, offsets, grid, point_colors=point_colors, base_color=(240, 240, 240))
    for start, stop in zip(offsets[:-1], offsets[1:]):  # every loop's contour, the lesion's included
        own = solid_mask(points[start:stop], np.array([0, stop - start]), grid)
        paint_contour(plain, own, points[start:stop], point_colors[start:stop], grid)
    spec = GradeSpec(RegionSpec(nozzle_mm=0.2, depth_mm=args.depth), make_function("linear"), CELLS, None,
                     LIVER, shells=((1, TUMOUR),))
    mask = solid_mask(points, offsets, grid)
    graded = render_graded(points, offsets, contours.area, contours.parent, shell[contours.face], mask, grid,
                           spec, 0, point_colors=point_colors, channels=True)
    print(f"grading step: {1000 * graded.grading_seconds:.1f} ms CPU for {grid.width} x {grid.height} px")
    droplets = np.zeros((grid.height, grid.width, 4), dtype=np.uint8)
    for material, bits in zip(spec.channel_materials(), graded.masks):
        droplets[bits] = (*material.color, 255)

    panels = [shown(plain, args.size), shown(graded.image, args.size), shown(droplets, args.size)]
    captions = ("(a) without internal distribution", "(b) with internal distribution",
                "(c) droplet masks (liver, cells, tumour)")
    height = max(p.size[1] for p in panels)
    sheet = Image.new("RGB", (3 * args.size + 40, height + 40), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for number, (panel, caption) in enumerate(zip(panels, captions)):
        sheet.paste(panel, (10 + number * (args.size + 10), 30))
        draw.text((10 + number * (args.size + 10), 8), caption, fill=(0, 0, 0))
    sheet.save(args.out)
    rows, cols = np.nonzero(mask)
    edge = int(cols.min())  # a detail at the organ's left boundary, where the mix changes
    crop = Image.fromarray(droplets[..., :3]).crop((edge, grid.height // 2 - 100, edge + 200, grid.height // 2 + 100))
    crop.resize((400, 400), Image.Resampling.NEAREST).save(Path(args.out).with_name(Path(args.out).stem + "_droplets.png"))
    print(f"{args.out}: {sheet.size[0]} x {sheet.size[1]} px")


if __name__ == "__main__":
    main()
