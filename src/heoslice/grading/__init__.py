"""Graded interiors: eq. 8-10 sub-regions of each profile family, their materials and droplet masks.

In pipeline order: :mod:`.spec` (what is asked: nozzle, depth, direction, materials),
:mod:`.families` (outer rings with their holes, eq. 8's N_R), :mod:`.edges` (ring edges
without straight points), :mod:`.search` (exact nearest-edge search), :mod:`.lattice`
(distances at coarse cell centres), :mod:`.field` and :mod:`.refine` (the per-family
sub-region index), :mod:`.labels` (a layer's labels), :mod:`.materials`, :mod:`.render`
(the RGBA image), :mod:`.droplets` and :mod:`.halftone` (droplet masks), and
:mod:`.cache` (what one layer leaves to the next). Each ``*_kernels`` module holds the
compiled loops of the module it is named after; :mod:`.diffusion` the error-diffusion halftone.

The names below are loaded on first use (PEP 562), not when the package is imported: the halftoning
methods' names (:mod:`.halftone`) are read by the manifest's checks without the kernels loading.
"""

from __future__ import annotations

from heoslice.lazy import lazy_exports

#: Each module of this package -> the public names it defines.
_MODULES = {
    "cache": ("GradingCache",),
    "droplets": ("droplet_counts", "droplet_planes"),
    "families": ("Family", "FamilyLayout", "family_layout", "layer_families"),
    "field": ("FamilyField", "family_field"),
    "halftone": ("TILE", "METHODS", "DEFAULT_METHOD", "bayer_matrix", "blue_noise_ranks", "check_method", "halftone",
                 "layer_tile", "thresholds"),
    "diffusion": ("DiffusionCarry",),
    "labels": ("LayerRegions", "family_of", "label_fractions", "layer_regions"),
    "materials": ("contour_values",),
    "render": ("GradedLayer", "render_graded"),
    "spec": ("DEPTH_FROM", "DIRECTIONS", "GradeSpec", "RegionSpec", "band_count"),
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, _MODULES)
