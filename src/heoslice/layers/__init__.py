"""Layers: where a mesh is cut (plane heights), the cut itself (Table 2), the cut's loops, and their pixels.

planes -> slicing (triangle-plane intersections, paper section IV.A-B) -> contours (segments chained
into oriented loops and profile families) -> rasterising (loops -> solid pixels, layer images).
"""

from heoslice.layers.contours import Contours, build_contours
from heoslice.layers.planes import LAYER_COUNT_TOLERANCE, layer_count, plane_heights
from heoslice.layers.rasterising import (
    MM_PER_INCH,
    Grid,
    contour_pixels,
    count_solid,
    grid_for,
    packed_mask,
    packed_mask_and_count,
    paint_contour,
    render_layer,
    solid_mask,
)
from heoslice.layers.slicing import (
    Sections,
    face_z_range,
    interpolate_at,
    plane_chunks,
    segments_per_plane,
    slice_mesh,
    slice_planes,
)

__all__ = [
    "LAYER_COUNT_TOLERANCE", "MM_PER_INCH", "Contours", "Grid", "Sections", "build_contours", "contour_pixels",
    "count_solid", "face_z_range", "grid_for", "interpolate_at", "layer_count", "packed_mask", "packed_mask_and_count",
    "paint_contour", "plane_chunks", "plane_heights", "render_layer", "segments_per_plane", "slice_mesh",
    "slice_planes", "solid_mask",
]
