"""A graded layer rendered as an RGBA image (Fig. 9b), optionally with its droplet masks."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from heoslice.grading.cache import GradingCache
from heoslice.grading.droplets import labelled_droplet_planes
from heoslice.grading.labels import layer_regions
from heoslice.grading.materials import family_starts, paint_cells, target_fractions
from heoslice.grading.spec import GradeSpec
from heoslice.layers.rasterising import Grid, paint_contour


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
    mask (h, w) bool its solid pixels; point_colors (p, 3) float 0..255 and
    point_material (p,) in [0, 1] the attributes interpolated at the contour points; ``cache``
    as :func:`layer_regions`.
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
    colors, _ = family_starts(regions, spec, loop_shell, point_colors, point_material)
    b = regions.box
    label = regions.label
    inside = label > 0
    solid_box = mask[b[0]:b[1], b[2]:b[3]]
    stray = solid_box & ~inside
    weight = np.rint(fractions * 255).astype(np.int16)
    g = np.take(weight, label)
    start_color = paint_cells(regions, colors, dtype=np.int16)
    view = image[b[0]:b[1], b[2]:b[3]]
    target = spec.target.color if spec.target is not None else (0, 0, 0)
    for channel in range(3):
        value = start_color[..., channel]
        if spec.target is not None:
            value = value + ((target[channel] - value) * g + 127) // 255
        view[..., channel] = value
    view[..., 3] = inside.view(np.uint8) * np.uint8(255)
    view[stray] = (*spec.base.color, 255)
    if point_colors is not None:
        paint_contour(image, mask, points, point_colors, grid)
    return GradedLayer(image, solid, masks, grading_seconds)
