"""A graded layer rendered as an RGBA image (Fig. 9b), optionally with its droplet masks."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from heoslice.grading.cache import GradingCache
from heoslice.grading.droplets import labelled_droplet_planes
from heoslice.grading.edges import ring_edges
from heoslice.grading.labels import LayerRegions, layer_regions
from heoslice.grading.materials import pixel_start_colors, target_fractions
from heoslice.grading.search import nearest_edges, ring_tree
from heoslice.grading.spec import GradeSpec
from heoslice.layers.rasterising import Grid, contour_pixels


@dataclass(frozen=True)
class GradedLayer:
    """A rendered graded layer: RGBA image ((h, w, 4) uint8), solid pixel count, and the
    droplet masks ((K, h, w) bool, one per :meth:`GradeSpec.channel_materials`) or None."""

    image: np.ndarray
    solid: int
    masks: np.ndarray | None
    grading_seconds: float


def render_graded(points: np.ndarray, offsets: np.ndarray, area: np.ndarray, parent: np.ndarray,
                  loop_shell: np.ndarray | None, mask: np.ndarray, grid: Grid, spec: GradeSpec, layer: int, *,
                  point_colors: np.ndarray | None = None, point_material: np.ndarray | None = None,
                  channels: bool = False, cache: GradingCache | None = None) -> GradedLayer:
    """Render one graded layer (Fig. 9b): sub-regions by :func:`layer_regions`, each family's
    interior blended from its contour's material to the target by eq. 1, contour pixels
    in the contour's colours, and optionally the droplet masks (:mod:`heoslice.grading.halftone`).

    points (p, 2) mm, offsets (l+1,), area/parent/loop_shell (l,) of the layer's loops;
    mask (h, w) bool its solid pixels; point_colors (p, 3) float 0..255 and point_material (a
    fraction (p,) in [0, 1] or a mix (p, K) over the channel materials,
    :func:`heoslice.grading.materials.point_mixes`) the attributes interpolated at the contour points;
    ``cache`` as :func:`layer_regions`.
    """
    started = time.process_time()
    regions = layer_regions(points, offsets, area, parent, mask, grid, spec.regions, cache=cache)
    grading_seconds = time.process_time() - started
    solid = int(np.count_nonzero(mask))
    image = np.zeros((grid.height, grid.width, 4), dtype=np.uint8)
    masks = None
    if channels:
        planes = labelled_droplet_planes(regions, spec, loop_shell, point_material, np.packbits(mask, axis=1), grid, layer)
        masks = np.unpackbits(planes, axis=2, count=grid.width).view(bool)
    if not regions.fields:
        return GradedLayer(image, solid, masks, grading_seconds)

    fractions = target_fractions(regions, spec)
    b = regions.box
    label = regions.label
    inside = label > 0
    stray = mask[b[0]:b[1], b[2]:b[3]] & ~inside
    color = pixel_start_colors(regions, spec, loop_shell, point_colors, point_material, grid)
    if spec.target is not None:
        # eq. 1 in float64: start + (target - start) f reaches the target at f = 1 and the start at f = 0 exactly
        weight = np.take(fractions, label)[..., None]
        color = color + (np.asarray(spec.target.color, dtype=np.float64) - color) * weight
    view = image[b[0]:b[1], b[2]:b[3]]
    view[..., :3] = np.clip(np.rint(color), 0, 255).astype(np.uint8)
    view[..., 3] = inside.view(np.uint8) * np.uint8(255)
    view[stray] = (*spec.base.color, 255)
    if point_colors is not None:
        _paint_start_contours(image, mask, points, offsets, point_colors, grid, _contour_loops(regions, spec))
    return GradedLayer(image, solid, masks, grading_seconds)


def _contour_loops(regions: LayerRegions, spec: GradeSpec) -> set[int]:
    """The loops whose pixels take the contour's own colours: every loop of a family without a gradient or
    of a nested shell (its region keeps its material), else only the rings the grading starts from (the
    inner rings, graded outwards, carry the start; the outer ring's pixels, in the last band, the target)."""
    graded = spec.target is not None and spec.function is not None
    loops = set()
    for family, field in zip(regions.families, regions.fields):
        if graded and not family.nested:
            loops.update(field.layout.start)
        else:
            loops.update((family.outer, *family.holes))
    return loops


def _paint_start_contours(image: np.ndarray, mask: np.ndarray, points: np.ndarray, offsets: np.ndarray,
                          point_colors: np.ndarray, grid: Grid, loops: set[int]) -> None:
    """Colour each contour pixel (:func:`contour_pixels`) whose nearest contour edge lies on one of ``loops``
    with the colour at that edge's nearest point (interpolated between the layer's points, (p, 3) float
    0..255); the others keep their graded colour. The nearest edge is searched within the distance to the
    nearest point (its edge is at most that far, plus the straight points' 1e-5 mm)."""
    from scipy.spatial import cKDTree  # here, not at the top: only contours painted in given colours need it

    pixels = contour_pixels(mask)
    if len(pixels) == 0 or len(points) == 0 or not loops:
        return
    x = grid.x_left + (pixels[:, 1] + 0.5) * grid.px
    y = grid.y_top - (pixels[:, 0] + 0.5) * grid.py
    bound, _ = cKDTree(points).query(np.column_stack([x, y]), k=1)
    edges = ring_edges(points, offsets, range(len(offsets) - 1))
    zero = np.zeros(1)
    edge = nearest_edges(x, y, bound + 1e-4, zero, zero, edges, ring_tree(edges))[:, 0].astype(np.int64)
    keep = (edge >= 0) & np.isin(edges.ring[np.maximum(edge, 0)], np.fromiter(loops, dtype=np.int64))
    edge = edge[keep]
    t = ((x[keep] - edges.x[edge]) * edges.vx[edge] + (y[keep] - edges.y[edge]) * edges.vy[edge]) * edges.inv_len2[edge]
    at = edge + edges.ring[edge] + np.clip(t, 0.0, 1.0)
    values = np.asarray(point_colors, dtype=np.float64)[edges.knot_point]
    colors = np.stack([np.interp(at, edges.knots, column) for column in values.T], axis=-1)
    image[pixels[keep, 0], pixels[keep, 1], :3] = np.clip(np.rint(colors), 0, 255).astype(np.uint8)
