"""Materials of a model: distribution functions, reference features and distances, colouring, the materials table.

Modules, in the order a material distribution is built (paper section II.B, III.A):
``expressions`` (formulas in r, parsed, never eval'ed), ``functions`` (eq. 2-5 as one
table of kinds), ``triangles`` and ``surface`` (exact point-triangle and nearest-surface
distance), ``references`` (plane, point, axis, surface as one table of kinds, and r),
``materials`` (the TOML materials table, eq. 1's blend and the default roles of M1 and
M2), ``coloring`` (a mesh coloured by a function and written as PLY).

The names below are loaded on first use (PEP 562), not when the package is imported: slicing reads the
materials table and the distribution functions, never the colouring's modules.
"""

from __future__ import annotations

from heoslice.lazy import lazy_exports

#: Public name -> the module of this package that defines it.
_EXPORTS = {
    "MAX_SUBDIVIDED_TRIANGLES": "coloring", "ColoredMesh": "coloring", "ColorSpec": "coloring",
    "color_mesh": "coloring", "default_output": "coloring", "material_comment": "coloring",
    "ply_bytes": "coloring", "subdivide": "coloring", "write_ply": "coloring",
    "EXPRESSION_CONSTANTS": "expressions", "EXPRESSION_FUNCTIONS": "expressions",
    "compile_expression": "expressions", "evaluate_expression": "expressions",
    "FUNCTION_KINDS": "functions", "FUNCTIONS": "functions", "DistributionFunction": "functions",
    "FunctionKind": "functions", "evaluate": "functions", "make_function": "functions",
    "DEFAULT_MATERIALS": "materials", "MAX_CHANNEL": "materials", "Material": "materials",
    "MaterialRoles": "materials", "MaterialsFile": "materials", "PartSetting": "materials",
    "blend": "materials", "check_one_per_channel": "materials", "is_channel": "materials",
    "material_roles": "materials", "nearest_materials": "materials", "parse_color": "materials",
    "read_materials_file": "materials", "resolve_material": "materials", "shared_channel": "materials",
    "table_material": "materials", "to_rgb8": "materials", "with_table_channels": "materials",
    "REFERENCE_KINDS": "references", "REFERENCES": "references", "Reference": "references",
    "ReferenceKind": "references", "make_reference": "references", "material_fraction": "references",
    "normalise": "references", "reference_distance": "references", "reference_kinds_taking": "references",
    "SurfaceIndex": "surface", "build_surface_index": "surface", "surface_distance": "surface",
    "closest_points_on_triangles": "triangles", "point_triangle_distance": "triangles",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
