"""The paper's Fig. 2: the vase coloured by linear, quadratic and sine functions about the X-Y plane.

Usage: .venv/bin/python examples/fig2.py [OUT.png] [--model examples/vase.ply] [--size 360]

Colours the example vase (made by examples/make_vase.py) with heoslice.material, from
M1 (light grey) at the bottom to M2 (green) at the top, and renders (a) the bare mesh,
(b) linear, (c) quadratic (nonlinear) and (d) sine (periodic) side by side. The render
is orthographic, Gouraud-shaded with a z-buffer, rasterised by the vectorised numpy
code below; Pillow writes the PNG.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

try:
    import numpy as np
    from PIL import Image, ImageDraw

    from heoslice.material import ColorSpec, color_mesh, make_function
    from heoslice.mesh import load_mesh
except ImportError as missing:
    sys.exit(f"fig2.py: error: cannot import {missing.name or missing}: run it with the Python that heoslice "
             "is installed in, e.g. .venv/bin/python examples/fig2.py")

HERE = Path(__file__).resolve().parent


def view_rotation(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """(3, 3) rotation taking model coordinates (z up) to view coordinates (x right, y up, z toward the viewer)."""
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    spin = np.array([[np.cos(az), -np.sin(az), 0.0], [np.sin(az), np.cos(az), 0.0], [0.0, 0.0, 1.0]])
    # look along -y after the spin, tilted down by the elevation
    look = np.array([[1.0, 0.0, 0.0],
                     [0.0, np.sin(el), np.cos(el)],
                     [0.0, -np.cos(el), np.sin(el)]])
    return look @ spin


def render(vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray, width: int, height: int,
           elevation: float = 25.0, azimuth: float = 30.0, background=(255, 255, 255),
           wire: bool = False) -> np.ndarray:
    """Orthographic render (height, width, 3) uint8 of a vertex-coloured mesh.

    Every triangle's pixel bounding box is expanded into candidate pixels at once;
    barycentric coordinates keep the pixels inside, the nearest depth per pixel wins
    (z-buffer by sorting), colours are interpolated and shaded by the interpolated
    vertex normal against a light from the viewer's upper left (two-sided). ``wire``
    darkens pixels within half a pixel of a triangle edge.
    """
    view = vertices @ view_rotation(elevation, azimuth).T
    low, high = view[:, :2].min(axis=0), view[:, :2].max(axis=0)
    scale = 0.92 * min(width / (high[0] - low[0]), height / (high[1] - low[1]))
    centre = (low + high) / 2.0
    px = (view[:, 0] - centre[0]) * scale + width / 2.0
    py = height / 2.0 - (view[:, 1] - centre[1]) * scale
    depth = view[:, 2]

    corner = view[faces]
    face_normal = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    vertex_normal = np.zeros_like(view)
    np.add.at(vertex_normal, faces.ravel(), np.repeat(face_normal, 3, axis=0))
    vertex_normal /= np.maximum(np.linalg.norm(vertex_normal, axis=1, keepdims=True), 1e-12)
    light = np.array([-0.4, 0.5, 0.77])
    light /= np.linalg.norm(light)
    shade = 0.3 + 0.7 * np.abs(vertex_normal @ light)

    x, y = px[faces], py[faces]
    x0 = np.clip(np.floor(x.min(axis=1)).astype(np.int64), 0, width - 1)
    x1 = np.clip(np.ceil(x.max(axis=1)).astype(np.int64), 0, width - 1)
    y0 = np.clip(np.floor(y.min(axis=1)).astype(np.int64), 0, height - 1)
    y1 = np.clip(np.ceil(y.max(axis=1)).astype(np.int64), 0, height - 1)
    box_w, box_h = x1 - x0 + 1, y1 - y0 + 1
    counts = box_w * box_h
    tri = np.repeat(np.arange(len(faces)), counts)
    local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    cx = x0[tri] + local % box_w[tri] + 0.5
    cy = y0[tri] + local // box_w[tri] + 0.5

    xa, xb, xc = x[tri, 0], x[tri, 1], x[tri, 2]
    ya, yb, yc = y[tri, 0], y[tri, 1], y[tri, 2]
    area = (xb - xa) * (yc - ya) - (xc - xa) * (yb - ya)
    with np.errstate(divide="ignore", invalid="ignore"):
        wa = ((xb - cx) * (yc - cy) - (xc - cx) * (yb - cy)) / area
        wb = ((xc - cx) * (ya - cy) - (xa - cx) * (yc - cy)) / area
    wc = 1.0 - wa - wb
    inside = (area != 0) & (wa >= 0) & (wb >= 0) & (wc >= 0)
    tri, cx, cy, wa, wb, wc = tri[inside], cx[inside], cy[inside], wa[inside], wb[inside], wc[inside]
    weights = np.stack([wa, wb, wc], axis=1)
    corners = faces[tri]
    z = np.einsum("ij,ij->i", weights, depth[corners])
    pixel = (cy - 0.5).astype(np.int64) * width + (cx - 0.5).astype(np.int64)
    order = np.lexsort((-z, pixel))  # per pixel, nearest (largest z toward the viewer) first
    pixel, first = np.unique(pixel[order], return_index=True)
    keep = order[first]
    rgb = np.einsum("ij,ijk->ik", weights[keep], colors[corners[keep]].astype(np.float64))
    light_level = np.einsum("ij,ij->i", weights[keep], shade[corners[keep]])
    if wire:
        edge_px = np.linalg.norm(np.stack([np.stack([x[:, (i + 2) % 3] - x[:, (i + 1) % 3],
                                                     y[:, (i + 2) % 3] - y[:, (i + 1) % 3]], axis=1)
                                           for i in range(3)], axis=1), axis=2)
        height_px = np.abs(area[inside][keep])[:, None] / np.maximum(edge_px[tri[keep]], 1e-12)
        near_edge = (weights[keep] * height_px).min(axis=1) < 0.5
        light_level[near_edge] *= 0.35
    image = np.empty((height * width, 3), dtype=np.uint8)
    image[:] = background
    image[pixel] = np.clip(rgb * light_level[:, None], 0, 255).astype(np.uint8)
    return image.reshape(height, width, 3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default=str(HERE / "fig2.png"))
    parser.add_argument("--model", default=str(HERE / "vase.ply"))
    parser.add_argument("--size", type=int, default=360, help="panel width in pixels")
    args = parser.parse_args()

    mesh = load_mesh(args.model)
    width, height = args.size, int(args.size * 1.4)
    panels = [("(a) triangle mesh", np.full((len(mesh.vertices), 3), 200, dtype=np.uint8))]
    for label, function in (("(b) linear", make_function("linear")),
                            ("(c) quadratic", make_function("quadratic")),
                            ("(d) sine, 3 periods", make_function("sine", periods=3))):
        colored = color_mesh(mesh, ColorSpec(function=function))  # X-Y plane through the lowest point
        panels.append((label, colored.colors))
    sheet = Image.new("RGB", (width * len(panels), height + 30), "white")
    draw = ImageDraw.Draw(sheet)
    for i, (label, colors) in enumerate(panels):
        picture = render(mesh.vertices, mesh.faces, colors, width, height, wire=i == 0)
        sheet.paste(Image.fromarray(picture), (i * width, 0))
        draw.text((i * width + width // 2, height + 12), label, fill="black", anchor="mm")
    sheet.save(args.out)
    print(f"{args.out}: {sheet.width}x{sheet.height} px, {len(panels)} vases from {args.model}")


if __name__ == "__main__":
    main()
