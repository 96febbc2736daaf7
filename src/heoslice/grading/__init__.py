"""Graded interiors: eq. 8-10 sub-regions of each profile family, their materials and droplet masks.

In pipeline order: :mod:`.spec` (what is asked: nozzle, depth, direction, materials),
:mod:`.families` (outer rings with their holes, eq. 8's N_R), :mod:`.edges` (ring edges
without straight points), :mod:`.search` (exact nearest-edge search), :mod:`.lattice`
(distances at coarse cell centres), :mod:`.field` and :mod:`.refine` (the per-family
sub-region index), :mod:`.labels` (a layer's labels), :mod:`.materials`, :mod:`.render`
(the RGBA image), :mod:`.droplets` and :mod:`.halftone` (droplet masks), and
:mod:`.cache` (what one layer leaves to the next). Each ``*_kernels`` module holds the
compiled loops of the module it is named after.
"""

from heoslice.grading.cache import GradingCache
from heoslice.grading.droplets import droplet_counts, droplet_planes
from heoslice.grading.families import (
    Family,
    FamilyLayout,
    family_layout,
    layer_families,
)
from heoslice.grading.field import FamilyField, family_field
from heoslice.grading.halftone import TILE, bayer_matrix, layer_tile, thresholds
from heoslice.grading.labels import (
    LayerRegions,
    family_of,
    label_fractions,
    layer_regions,
)
from heoslice.grading.materials import contour_values
from heoslice.grading.render import GradedLayer, render_graded
from heoslice.grading.spec import DEPTH_FROM, DIRECTIONS, GradeSpec, RegionSpec, band_count

__all__ = [
    "DEPTH_FROM", "DIRECTIONS", "TILE", "Family", "FamilyField", "FamilyLayout", "GradeSpec", "GradedLayer", "GradingCache",
    "LayerRegions", "RegionSpec", "band_count", "bayer_matrix", "contour_values", "droplet_counts", "droplet_planes",
    "family_field", "family_layout", "family_of", "label_fractions", "layer_families", "layer_regions", "layer_tile",
    "render_graded", "thresholds",
]
