"""Materials of a model: distribution functions, reference features and distances, colouring, the materials table.

Modules, in the order a material distribution is built (paper section II.B, III.A):
``expressions`` (formulas in r, parsed, never eval'ed), ``functions`` (eq. 2-5 as one
table of kinds), ``triangles`` and ``surface`` (exact point-triangle and nearest-surface
distance), ``references`` (plane, point, axis, surface as one table of kinds, and r),
``materials`` (the TOML materials table, eq. 1's blend and the default roles of M1 and
M2), ``coloring`` (a mesh coloured by a function and written as PLY), ``design`` (what ``color`` did,
recorded in the PLY for ``slice``) and ``field`` (a design evaluated at every voxel, in 3D).

The names below are loaded on first use (PEP 562), not when the package is imported: slicing reads the
materials table and the distribution functions, never the colouring's modules.
"""

from __future__ import annotations

from heoslice.lazy import lazy_exports

#: Each module of this package -> the public names it defines.
_MODULES = {
    "coloring": ("MAX_SUBDIVIDED_TRIANGLES", "ColoredMesh", "ColorSpec", "color_mesh", "default_output",
                 "material_comment", "ply_bytes", "subdivide", "write_ply"),
    "design": ("DESIGN_VERSION", "INTERIORS", "Design", "ReferenceRecord", "design_of", "settle_materials",
               "surface_path"),
    "expressions": ("EXPRESSION_CONSTANTS", "EXPRESSION_FUNCTIONS", "compile_expression", "evaluate_expression"),
    "functions": ("FUNCTION_KINDS", "FUNCTIONS", "DistributionFunction", "FunctionKind", "evaluate", "make_function"),
    "materials": ("DEFAULT_MATERIALS", "MAX_CHANNEL", "Material", "MaterialRoles", "MaterialsFile", "PartSetting",
                  "blend", "check_one_per_channel", "is_channel", "material_identity", "material_roles",
                  "nearest_materials", "same_material",
                  "parse_color", "read_materials_file", "resolve_material", "shared_channel", "table_material",
                  "to_rgb8", "with_table_channels"),
    "references": ("REFERENCE_KINDS", "REFERENCES", "Reference", "ReferenceKind", "make_reference",
                   "material_fraction", "normalise", "reference_distance", "reference_kinds_taking"),
    "field": ("MaterialField", "depth_field", "material_field"),
    "surface": ("SurfaceIndex", "build_surface_index", "surface_distance"),
    "triangles": ("closest_points_on_triangles", "point_triangle_distance"),
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, _MODULES)
