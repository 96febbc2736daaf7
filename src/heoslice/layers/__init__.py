"""Layers: where a mesh is cut (plane heights), the cut itself (Table 2), the cut's loops, and their pixels.

planes -> slicing (triangle-plane intersections, paper section IV.A-B) -> contours (segments chained
into oriented loops and profile families) -> rasterising (loops -> solid pixels, layer images); bits (packed pixels counted).

The names below are loaded on first use (PEP 562), not when the package is imported: a command that reads a
stack asks only :func:`~heoslice.layers.planes.layer_count`, not the slicing kernels.
"""

from __future__ import annotations

from heoslice.lazy import lazy_exports

#: Each module of this package -> the public names it defines.
_MODULES = {
    "planes": ("LAYER_COUNT_TOLERANCE", "layer_count", "plane_heights"),
    "slicing": ("Sections", "face_z_range", "interpolate_at", "plane_chunks", "segments_per_plane", "slice_mesh",
                "slice_planes"),
    "contours": ("Contours", "build_contours"),
    "rasterising": ("MM_PER_INCH", "Grid", "contour_pixels", "grid_for", "packed_mask",
                    "packed_mask_and_count", "paint_contour", "render_layer", "solid_mask"),
    "bits": ("count_solid",),
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, _MODULES)
